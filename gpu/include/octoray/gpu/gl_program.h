#pragma once
// GL objects owned by move-only RAII types: linked programs built from the embedded .glsl
// files (shader_sources.h) with a #define prelude per variant, textures, buffers,
// framebuffers and vertex arrays. Each is created in, and must be destroyed with, the
// current context (gl_context.h).

#include <epoxy/gl.h>

#include <functional>
#include <string>
#include <string_view>
#include <unordered_map>
#include <utility>
#include <vector>

namespace octoray::gpu {

// A linked vertex + fragment program. A variant is the list of defines: each entry
// ("SHADING", "MODE_DVR", "BRICK_EDGE 34") becomes "#define <entry>" on its own line right
// after the #version line of both stages; a #line directive after them keeps the compiler's
// line numbers those of the file. Include lines are expanded first (withIncludes).
class GlProgram {
 public:
  // From embedded shaders (gpu/shaders/<name>). Throws octoray::Error naming the file with
  // the compiler's or linker's log when a stage does not compile or the program does not link.
  static GlProgram build(std::string_view vertexName, std::string_view fragmentName,
                         const std::vector<std::string>& defines);
  // From source text; errors name "<nameForErrors> (vertex shader)" or "(fragment shader)".
  static GlProgram fromSources(std::string_view vertexSource, std::string_view fragmentSource,
                               const std::vector<std::string>& defines,
                               std::string_view nameForErrors);

  GlProgram(GlProgram&& other) noexcept;
  GlProgram& operator=(GlProgram&& other) noexcept;
  GlProgram(const GlProgram&) = delete;
  GlProgram& operator=(const GlProgram&) = delete;
  ~GlProgram();

  GLuint id() const { return id_; }
  // The location of uniform `name`, -1 when the program has no such active uniform; cached.
  GLint uniform(const char* name) const;
  // The exact fragment text compiled (defines inserted), so tests can see which code a
  // variant contains.
  const std::string& fragmentSourceWithDefines() const { return fragmentSource_; }

 private:
  GlProgram(GLuint id, std::string fragmentSource);
  static GlProgram link(std::string_view vertexSource, std::string_view fragmentSource,
                        const std::vector<std::string>& defines, std::string_view vertexName,
                        std::string_view fragmentName, const std::string& programName);

  GLuint id_ = 0;
  std::string fragmentSource_;
  mutable std::unordered_map<std::string, GLint> uniforms_;
};

// `source` (the shader `name`) with each line `#include "part.glsl"` replaced by the text of
// partSource("part.glsl") (the embedded shaders for programs), itself expanded. #line
// directives number the N-th part pasted (parts[N - 1]) from line N * 10000 + 1, which compile
// errors list, and resume the includer's numbering after it. Throws octoray::Error naming the
// includer and line for a malformed include, an absent part, a part included twice or
// including itself, and a part of 10000 lines or more.
std::string withIncludes(std::string_view source, std::string_view name,
                         const std::function<std::string_view(std::string_view)>& partSource,
                         std::vector<std::string>& parts);

// `source` with "#define <entry>" lines inserted after its #version line (then a #line
// directive). Throws octoray::Error(name, ...) when there is no #version line or an entry is
// empty or spans lines.
std::string withDefines(std::string_view source, const std::vector<std::string>& defines,
                        std::string_view name);

namespace detail {

// One GL object name and its deletion; Traits::destroy(GLuint) deletes it.
template <typename Traits>
class GlObject {
 public:
  GlObject(GlObject&& other) noexcept : id_(std::exchange(other.id_, 0)) {}
  GlObject& operator=(GlObject&& other) noexcept {
    if (this != &other) {
      reset();
      id_ = std::exchange(other.id_, 0);
    }
    return *this;
  }
  GlObject(const GlObject&) = delete;
  GlObject& operator=(const GlObject&) = delete;
  ~GlObject() { reset(); }

  GLuint id() const { return id_; }

 protected:
  explicit GlObject(GLuint id) : id_(id) {}

 private:
  void reset() {
    if (id_ != 0) Traits::destroy(id_);
    id_ = 0;
  }

  GLuint id_ = 0;
};

struct GlTextureTraits {
  static void destroy(GLuint id);
};
struct GlBufferTraits {
  static void destroy(GLuint id);
};
struct GlFramebufferTraits {
  static void destroy(GLuint id);
};
struct GlVertexArrayTraits {
  static void destroy(GLuint id);
};

}  // namespace detail

// glCreateTextures(target): storage is the caller's (glTextureStorage*).
class GlTexture : public detail::GlObject<detail::GlTextureTraits> {
 public:
  explicit GlTexture(GLenum target);
  GLenum target() const { return target_; }

 private:
  GLenum target_;
};

// glCreateBuffers.
class GlBuffer : public detail::GlObject<detail::GlBufferTraits> {
 public:
  GlBuffer();
};

// glCreateFramebuffers.
class GlFramebuffer : public detail::GlObject<detail::GlFramebufferTraits> {
 public:
  GlFramebuffer();
};

// glCreateVertexArrays (an empty one draws the full-screen triangle).
class GlVertexArray : public detail::GlObject<detail::GlVertexArrayTraits> {
 public:
  GlVertexArray();
};

}  // namespace octoray::gpu
