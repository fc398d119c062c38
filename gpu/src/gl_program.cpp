// Programs from embedded shaders with #define variants, and the RAII GL object wrappers.

#include "octoray/gpu/gl_program.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <functional>
#include <utility>

#include "octoray/core/error.h"
#include "octoray/gpu/shader_sources.h"

namespace octoray::gpu {
namespace {

std::string shaderInfoLog(GLuint shader) {
  GLint length = 0;
  glGetShaderiv(shader, GL_INFO_LOG_LENGTH, &length);
  std::string log(static_cast<std::size_t>(std::max(length, 0)), '\0');
  GLsizei written = 0;
  if (length > 0) glGetShaderInfoLog(shader, length, &written, log.data());
  log.resize(static_cast<std::size_t>(written));
  return log;
}

std::string programInfoLog(GLuint program) {
  GLint length = 0;
  glGetProgramiv(program, GL_INFO_LOG_LENGTH, &length);
  std::string log(static_cast<std::size_t>(std::max(length, 0)), '\0');
  GLsizei written = 0;
  if (length > 0) glGetProgramInfoLog(program, length, &written, log.data());
  log.resize(static_cast<std::size_t>(written));
  return log;
}

std::string describeDefines(const std::vector<std::string>& defines) {
  if (defines.empty()) return "no defines";
  std::string text = "defines:";
  for (const std::string& define : defines) text += " " + define + ";";
  text.pop_back();
  return text;
}

// A shader object deleted at scope exit (it is flagged for deletion while still attached).
class ShaderObject {
 public:
  explicit ShaderObject(GLenum stage) : id_(glCreateShader(stage)) {}
  ShaderObject(ShaderObject&& other) noexcept : id_(std::exchange(other.id_, 0)) {}
  ShaderObject& operator=(ShaderObject&&) = delete;
  ~ShaderObject() {
    if (id_ != 0) glDeleteShader(id_);
  }
  GLuint id() const { return id_; }

 private:
  GLuint id_;
};

// Included part N is numbered from line N * kPartLines + 1: #line's source-string number would
// say it better, but Mesa's compiler does not report it.
constexpr std::size_t kPartLines = 10000;

// "; included: a.glsl from line 10001, b.glsl from line 20001" for a stage with parts.
std::string describeParts(const std::vector<std::string>& parts) {
  std::string text;
  for (std::size_t i = 0; i < parts.size(); ++i) {
    text += fmt::format("{} {} from line {}", i == 0 ? "; included:" : ",", parts[i],
                        (i + 1) * kPartLines + 1);
  }
  return text;
}

struct IncludeState {
  const std::function<std::string_view(std::string_view)>& partSource;
  std::vector<std::string>& parts;
  std::vector<std::string> stack;  // the includers, outermost first
};

// Appends `source` (called `name`, its first line numbered `firstLine`) to `out` with its
// include lines expanded.
void expandIncludes(std::string_view source, std::string_view name, std::size_t firstLine,
                    IncludeState& state, std::string& out) {
  std::size_t lineNumber = 0;
  std::size_t lineStart = 0;
  while (lineStart < source.size()) {
    const std::size_t lineEnd = std::min(source.find('\n', lineStart), source.size());
    const std::string_view line = source.substr(lineStart, lineEnd - lineStart);
    ++lineNumber;
    lineStart = lineEnd + 1;
    const std::size_t text = line.find_first_not_of(" \t");
    if (text == std::string_view::npos || line.compare(text, 8, "#include") != 0) {
      out.append(line);
      out += '\n';
      continue;
    }
    const std::string where = fmt::format("{} line {}", name, lineNumber);
    const std::size_t open = line.find('"', text + 8);
    const std::size_t close = open == std::string_view::npos ? open : line.find('"', open + 1);
    if (close == std::string_view::npos || close == open + 1 ||
        line.find_first_not_of(" \t", text + 8) != open ||
        line.find_first_not_of(" \t", close + 1) != std::string_view::npos) {
      throw Error(where, fmt::format("malformed include \"{}\" (expected #include \"part.glsl\")",
                                     std::string(line.substr(text))));
    }
    const std::string part(line.substr(open + 1, close - open - 1));
    if (std::find(state.stack.begin(), state.stack.end(), part) != state.stack.end()) {
      throw Error(where, fmt::format("{} includes itself (through {})", part,
                                     fmt::join(state.stack, " -> ")));
    }
    if (std::find(state.parts.begin(), state.parts.end(), part) != state.parts.end()) {
      throw Error(where, fmt::format("{} is included a second time", part));
    }
    std::string_view partText;
    try {
      partText = state.partSource(part);
    } catch (const Error& error) {
      throw Error(where, fmt::format("included part: {}", error.what()));
    }
    if (static_cast<std::size_t>(std::count(partText.begin(), partText.end(), '\n')) >= kPartLines) {
      throw Error(part, fmt::format("an included part must be shorter than {} lines", kPartLines));
    }
    state.parts.push_back(part);
    const std::size_t partFirstLine = state.parts.size() * kPartLines + 1;
    out += fmt::format("#line {}\n", partFirstLine);
    state.stack.push_back(part);
    expandIncludes(partText, part, partFirstLine, state, out);
    state.stack.pop_back();
    out += fmt::format("#line {}\n", firstLine + lineNumber);
  }
}

ShaderObject compile(GLenum stage, const std::string& source, std::string_view name,
                     const std::vector<std::string>& defines,
                     const std::vector<std::string>& parts) {
  ShaderObject shader(stage);
  if (shader.id() == 0) throw Error(std::string(name), "glCreateShader failed");
  const GLchar* text = source.data();
  const auto length = static_cast<GLint>(source.size());
  glShaderSource(shader.id(), 1, &text, &length);
  glCompileShader(shader.id());
  GLint compiled = GL_FALSE;
  glGetShaderiv(shader.id(), GL_COMPILE_STATUS, &compiled);
  if (compiled != GL_TRUE) {
    throw Error(std::string(name),
                fmt::format("GLSL compile failed ({}{}):\n{}", describeDefines(defines),
                            describeParts(parts), shaderInfoLog(shader.id())));
  }
  return shader;
}

}  // namespace

std::string withIncludes(std::string_view source, std::string_view name,
                         const std::function<std::string_view(std::string_view)>& partSource,
                         std::vector<std::string>& parts) {
  parts.clear();
  IncludeState state{partSource, parts, {std::string(name)}};
  std::string out;
  out.reserve(source.size());
  expandIncludes(source, name, 1, state, out);
  if (!source.empty() && source.back() != '\n') out.pop_back();
  return out;
}

std::string withDefines(std::string_view source, const std::vector<std::string>& defines,
                        std::string_view name) {
  // The #version line: the first line whose first non-blank text is #version.
  std::size_t lineStart = 0;
  int lineNumber = 1;
  while (lineStart < source.size()) {
    const std::size_t textStart = source.find_first_not_of(" \t", lineStart);
    if (textStart != std::string_view::npos && source.compare(textStart, 8, "#version") == 0) {
      break;
    }
    const std::size_t lineEnd = source.find('\n', lineStart);
    lineStart = lineEnd == std::string_view::npos ? source.size() : lineEnd + 1;
    ++lineNumber;
  }
  if (lineStart >= source.size()) throw Error(std::string(name), "no #version line");
  const std::size_t versionEnd = source.find('\n', lineStart);
  const std::size_t insertAt =
      versionEnd == std::string_view::npos ? source.size() : versionEnd + 1;

  std::string result(source.substr(0, insertAt));
  if (versionEnd == std::string_view::npos) result += '\n';
  for (const std::string& define : defines) {
    if (define.find_first_not_of(" \t") == std::string::npos ||
        define.find_first_of("\r\n") != std::string::npos) {
      throw Error(std::string(name),
                  fmt::format("bad define \"{}\" (empty or several lines)", define));
    }
    result += "#define " + define + "\n";
  }
  if (!defines.empty()) result += fmt::format("#line {}\n", lineNumber + 1);
  result += source.substr(insertAt);
  return result;
}

// Compiles both stages and links them; errors name the stage's file or label.
GlProgram GlProgram::link(std::string_view vertexSource, std::string_view fragmentSource,
                          const std::vector<std::string>& defines, std::string_view vertexName,
                          std::string_view fragmentName, const std::string& programName) {
  // Parts come from the embedded shaders; the defines follow #version, in the main file.
  std::vector<std::string> vertexParts, fragmentParts;
  const std::string vertex = withDefines(
      withIncludes(vertexSource, vertexName, shaderSource, vertexParts), defines, vertexName);
  std::string fragment = withDefines(
      withIncludes(fragmentSource, fragmentName, shaderSource, fragmentParts), defines, fragmentName);
  const ShaderObject vertexShader =
      compile(GL_VERTEX_SHADER, vertex, vertexName, defines, vertexParts);
  const ShaderObject fragmentShader =
      compile(GL_FRAGMENT_SHADER, fragment, fragmentName, defines, fragmentParts);

  const GLuint program = glCreateProgram();
  if (program == 0) throw Error(programName, "glCreateProgram failed");
  glAttachShader(program, vertexShader.id());
  glAttachShader(program, fragmentShader.id());
  glLinkProgram(program);
  glDetachShader(program, vertexShader.id());
  glDetachShader(program, fragmentShader.id());
  GLint linked = GL_FALSE;
  glGetProgramiv(program, GL_LINK_STATUS, &linked);
  if (linked != GL_TRUE) {
    const std::string log = programInfoLog(program);
    glDeleteProgram(program);
    throw Error(programName,
                fmt::format("GLSL link failed ({}):\n{}", describeDefines(defines), log));
  }
  return GlProgram(program, std::move(fragment));
}

GlProgram GlProgram::build(std::string_view vertexName, std::string_view fragmentName,
                           const std::vector<std::string>& defines) {
  return link(shaderSource(vertexName), shaderSource(fragmentName), defines, vertexName,
              fragmentName, fmt::format("{} + {}", vertexName, fragmentName));
}

GlProgram GlProgram::fromSources(std::string_view vertexSource, std::string_view fragmentSource,
                                 const std::vector<std::string>& defines,
                                 std::string_view nameForErrors) {
  return link(vertexSource, fragmentSource, defines,
              fmt::format("{} (vertex shader)", nameForErrors),
              fmt::format("{} (fragment shader)", nameForErrors), std::string(nameForErrors));
}

GlProgram::GlProgram(GLuint id, std::string fragmentSource)
    : id_(id), fragmentSource_(std::move(fragmentSource)) {}

GlProgram::GlProgram(GlProgram&& other) noexcept
    : id_(std::exchange(other.id_, 0)),
      fragmentSource_(std::move(other.fragmentSource_)),
      uniforms_(std::move(other.uniforms_)) {}

GlProgram& GlProgram::operator=(GlProgram&& other) noexcept {
  if (this != &other) {
    if (id_ != 0) glDeleteProgram(id_);
    id_ = std::exchange(other.id_, 0);
    fragmentSource_ = std::move(other.fragmentSource_);
    uniforms_ = std::move(other.uniforms_);
  }
  return *this;
}

GlProgram::~GlProgram() {
  if (id_ != 0) glDeleteProgram(id_);
}

GLint GlProgram::uniform(const char* name) const {
  const auto [entry, inserted] = uniforms_.try_emplace(name, -1);
  if (inserted) entry->second = glGetUniformLocation(id_, name);
  return entry->second;
}

namespace detail {

void GlTextureTraits::destroy(GLuint id) { glDeleteTextures(1, &id); }
void GlBufferTraits::destroy(GLuint id) { glDeleteBuffers(1, &id); }
void GlFramebufferTraits::destroy(GLuint id) { glDeleteFramebuffers(1, &id); }
void GlVertexArrayTraits::destroy(GLuint id) { glDeleteVertexArrays(1, &id); }

}  // namespace detail

namespace {

GLuint createdName(PFNGLCREATEBUFFERSPROC create, const char* what) {
  GLuint id = 0;
  create(1, &id);
  if (id == 0) throw Error("", fmt::format("{} failed", what));
  return id;
}

GLuint createdTexture(GLenum target) {
  GLuint id = 0;
  glCreateTextures(target, 1, &id);
  if (id == 0) throw Error("", fmt::format("glCreateTextures(0x{:04x}) failed", target));
  return id;
}

}  // namespace

GlTexture::GlTexture(GLenum target) : GlObject(createdTexture(target)), target_(target) {}
GlBuffer::GlBuffer() : GlObject(createdName(glCreateBuffers, "glCreateBuffers")) {}
GlFramebuffer::GlFramebuffer()
    : GlObject(createdName(glCreateFramebuffers, "glCreateFramebuffers")) {}
GlVertexArray::GlVertexArray()
    : GlObject(createdName(glCreateVertexArrays, "glCreateVertexArrays")) {}

}  // namespace octoray::gpu
