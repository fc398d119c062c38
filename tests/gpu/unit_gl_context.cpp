// GL contexts (headless EGL, GLFW windows), programs from embedded shaders with #define
// variants, and the GL error log. Exact answers: an RGBA32F target stores the constant
// colours written, and the full-screen triangle's vNdc is the pixel centre's position.

#include <epoxy/gl.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cstdlib>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "octoray/core/error.h"
#include "octoray/gpu/gl_context.h"
#include "octoray/gpu/gl_program.h"
#include "octoray/gpu/shader_sources.h"
#include "gl_test_support.h"

namespace octoray::gpu {
namespace {

// Writes uColor, inverted with INVERT, scaled by SCALE when defined.
constexpr const char* kColourShader = R"(#version 450 core
in vec2 vNdc;
out vec4 fragColor;
uniform vec4 uColor;
void main() {
#ifdef INVERT
  fragColor = vec4(1.0) - uColor;
#else
  fragColor = uColor;
#endif
#ifdef SCALE
  fragColor *= SCALE;
#endif
}
)";

// Writes the interpolated normalised device position.
constexpr const char* kNdcShader = R"(#version 450 core
in vec2 vNdc;
out vec4 fragColor;
void main() { fragColor = vec4(vNdc, 0.0, 1.0); }
)";

constexpr int kWidth = 7;
constexpr int kHeight = 5;


// Draws the full-screen triangle with `program` into a fresh kWidth x kHeight RGBA32F target
// and reads it back (row 0 at the bottom).
std::vector<std::array<float, 4>> renderToFloatTarget(const GlProgram& program) {
  GlTexture colour(GL_TEXTURE_2D);
  glTextureStorage2D(colour.id(), 1, GL_RGBA32F, kWidth, kHeight);
  GlFramebuffer framebuffer;
  glNamedFramebufferTexture(framebuffer.id(), GL_COLOR_ATTACHMENT0, colour.id(), 0);
  EXPECT_EQ(glCheckNamedFramebufferStatus(framebuffer.id(), GL_FRAMEBUFFER),
            static_cast<GLenum>(GL_FRAMEBUFFER_COMPLETE));
  GlVertexArray empty;

  glBindFramebuffer(GL_FRAMEBUFFER, framebuffer.id());
  glViewport(0, 0, kWidth, kHeight);
  glUseProgram(program.id());
  glBindVertexArray(empty.id());
  glDrawArrays(GL_TRIANGLES, 0, 3);

  std::vector<std::array<float, 4>> pixels(kWidth * kHeight);
  glPixelStorei(GL_PACK_ALIGNMENT, 4);
  glReadPixels(0, 0, kWidth, kHeight, GL_RGBA, GL_FLOAT, pixels.data());
  glBindVertexArray(0);
  glUseProgram(0);
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
  return pixels;
}

GlProgram colourProgram(const std::vector<std::string>& defines, std::array<float, 4> colour) {
  GlProgram program = GlProgram::fromSources(shaderSource("fullscreen.vert.glsl"), kColourShader,
                                             defines, "colour_test");
  glProgramUniform4f(program.id(), program.uniform("uColor"), colour[0], colour[1], colour[2],
                     colour[3]);
  return program;
}

void expectEveryPixel(const std::vector<std::array<float, 4>>& pixels,
                      std::array<float, 4> expected) {
  for (std::size_t i = 0; i < pixels.size(); ++i) {
    for (int c = 0; c < 4; ++c) {
      ASSERT_EQ(pixels[i][c], expected[c])
          << "pixel " << i % kWidth << "," << i / kWidth << " channel " << c;
    }
  }
}

TEST(ShaderSources, EmbedsTheShaderFolderByFileName) {
  const std::vector<std::string_view> names = shaderNames();
  EXPECT_TRUE(std::is_sorted(names.begin(), names.end()));
  EXPECT_NE(std::find(names.begin(), names.end(), "fullscreen.vert.glsl"), names.end());
  const std::string_view source = shaderSource("fullscreen.vert.glsl");
  EXPECT_EQ(source.substr(0, 18), "#version 450 core\n");
  EXPECT_NE(source.find("gl_VertexID"), std::string_view::npos);
  try {
    shaderSource("absent.frag.glsl");
    FAIL() << "no error for an absent shader";
  } catch (const Error& error) {
    EXPECT_STREQ(error.what(), "no embedded shader absent.frag.glsl");
  }
}

TEST(ShaderSources, DefinesFollowTheVersionLineAndKeepLineNumbers) {
  const std::string source = "// header\n#version 450 core\nvoid main() {}\n";
  EXPECT_EQ(withDefines(source, {"SHADING", "BRICK_EDGE 34"}, "a.glsl"),
            "// header\n#version 450 core\n#define SHADING\n#define BRICK_EDGE 34\n#line 3\n"
            "void main() {}\n");
  EXPECT_EQ(withDefines(source, {}, "a.glsl"), source);
  EXPECT_THROW(withDefines("void main() {}\n", {"X"}, "a.glsl"), Error);
  EXPECT_THROW(withDefines(source, {"A\nB"}, "a.glsl"), Error);
  EXPECT_THROW(withDefines(source, {" "}, "a.glsl"), Error);
}

TEST(ShaderSources, IncludedPartsArePastedWithTheirOwnLineNumbers) {
  const std::map<std::string, std::string, std::less<>> files = {
      {"a.glsl", "float a() { return 1.0; }\n#include \"b.glsl\"\n"},
      {"b.glsl", "float b() { return 2.0; }\n"},
      {"self.glsl", "  #include \"self.glsl\"\n"},
      {"bad.glsl", "#include b.glsl\n"}};
  const auto lookup = [&](std::string_view name) -> std::string_view {
    const auto it = files.find(name);
    if (it == files.end()) throw Error(std::string(name), "no such part");
    return it->second;
  };
  std::vector<std::string> parts;
  const std::string source = "#version 450 core\n#include \"a.glsl\"\nvoid main() {}\n";
  EXPECT_EQ(withIncludes(source, "main.glsl", lookup, parts),
            "#version 450 core\n#line 10001\nfloat a() { return 1.0; }\n#line 20001\n"
            "float b() { return 2.0; }\n#line 10003\n#line 3\nvoid main() {}\n");
  EXPECT_EQ(parts, (std::vector<std::string>{"a.glsl", "b.glsl"}));
  // The defines go after #version and leave the parts' numbering alone.
  EXPECT_EQ(withDefines(withIncludes(source, "main.glsl", lookup, parts), {"X"}, "main.glsl"),
            "#version 450 core\n#define X\n#line 2\n#line 10001\nfloat a() { return 1.0; }\n"
            "#line 20001\nfloat b() { return 2.0; }\n#line 10003\n#line 3\nvoid main() {}\n");
  const std::string plain = "#version 450 core\nvoid main() {}";
  EXPECT_EQ(withIncludes(plain, "main.glsl", lookup, parts), plain);
  EXPECT_TRUE(parts.empty());

  const auto errorOf = [&](const std::string& text) {
    try {
      withIncludes(text, "main.glsl", lookup, parts);
    } catch (const Error& error) {
      return std::string(error.what());
    }
    return std::string("no error");
  };
  EXPECT_EQ(errorOf("#version 450 core\n\n#include \"absent.glsl\"\n"),
            "main.glsl line 3: included part: absent.glsl: no such part");
  EXPECT_EQ(errorOf("#include \"self.glsl\"\n"),
            "self.glsl line 1: self.glsl includes itself (through main.glsl -> self.glsl)");
  EXPECT_EQ(errorOf("#include \"b.glsl\"\n#include \"a.glsl\"\n"),
            "a.glsl line 2: b.glsl is included a second time");
  EXPECT_EQ(errorOf("#include \"bad.glsl\"\n"),
            "bad.glsl line 1: malformed include \"#include b.glsl\" (expected #include \"part.glsl\")");
  EXPECT_EQ(errorOf("#include \"b.glsl\" x\n"),
            "main.glsl line 1: malformed include \"#include \"b.glsl\" x\" (expected #include "
            "\"part.glsl\")");
}

// A compile error inside an included part is reported at 10000 x N + its line in part N, and
// the message says which part N is.
TEST_F(GlTest, CompileErrorInAnIncludedPartNamesThePart) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  // raycast_shading.glsl with SHADING but without the raycaster's interface: phong's use of
  // uMaterial (its line 11) does not compile.
  const char* source =
      "#version 450 core\n#include \"raycast_shading.glsl\"\nout vec4 c;\nvoid main() { c = vec4(0); }\n";
  try {
    GlProgram::fromSources(shaderSource("fullscreen.vert.glsl"), source, {"SHADING"}, "part_test");
    FAIL() << "an undeclared uniform compiled";
  } catch (const Error& error) {
    const std::string message = error.what();
    EXPECT_NE(message.find("included: raycast_shading.glsl from line 10001"), std::string::npos)
        << message;
    EXPECT_NE(message.find(":10011("), std::string::npos) << message;
  }
  // Without SHADING the part is empty and the program builds.
  EXPECT_NO_THROW(
      GlProgram::fromSources(shaderSource("fullscreen.vert.glsl"), source, {}, "part_test"));
  EXPECT_EQ(context_->takeErrors(), std::vector<std::string>{});
}

TEST_F(GlTest, HeadlessContextIsOpenGl45Core) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  GLint major = 0;
  GLint minor = 0;
  GLint profile = 0;
  glGetIntegerv(GL_MAJOR_VERSION, &major);
  glGetIntegerv(GL_MINOR_VERSION, &minor);
  glGetIntegerv(GL_CONTEXT_PROFILE_MASK, &profile);
  EXPECT_GE(major * 10 + minor, 45) << context_->version();
  EXPECT_NE(profile & GL_CONTEXT_CORE_PROFILE_BIT, 0);
  EXPECT_EQ(context_->version().rfind(std::to_string(major) + "." + std::to_string(minor), 0), 0u)
      << context_->version();
  EXPECT_FALSE(context_->renderer().empty());
  std::cout << "GL_RENDERER: " << context_->renderer() << "\nGL_VERSION: " << context_->version()
            << "\n";
#ifdef NDEBUG
  EXPECT_FALSE(context_->debug());
#else
  EXPECT_TRUE(context_->debug());
#endif
}

TEST_F(GlTest, DebugOptionGivesADebugContext) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  context_.reset();
  for (const bool debug : {true, false}) {
    const auto context = headless({.debug = debug});
    ASSERT_TRUE(context);
    EXPECT_EQ(context->debug(), debug);
    GLint flags = 0;
    glGetIntegerv(GL_CONTEXT_FLAGS, &flags);
    if (debug) {
      EXPECT_NE(flags & GL_CONTEXT_FLAG_DEBUG_BIT, 0);
    }
    EXPECT_EQ(glIsEnabled(GL_DEBUG_OUTPUT) == GL_TRUE, debug);
  }
}

TEST_F(GlTest, ContextsOnOneDisplayOutliveEachOther) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  auto second = headless({});
  ASSERT_TRUE(second);
  context_.reset();  // the display stays initialised for the second context
  second->makeCurrent();
  {
    const GlProgram program = colourProgram({}, {0.5f, 0.25f, 0.125f, 1.0f});
    expectEveryPixel(renderToFloatTarget(program), {0.5f, 0.25f, 0.125f, 1.0f});
  }  // GL objects go with their context current
  EXPECT_EQ(second->takeErrors(), std::vector<std::string>{});
  // And a third after the first is gone.
  const auto third = headless({});
  ASSERT_TRUE(third);
  EXPECT_EQ(third->takeErrors(), std::vector<std::string>{});
}

TEST_F(GlTest, ConstantColourFillsEveryPixelExactly) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const std::array<float, 4> colour = {0.25f, 0.5f, 0.75f, 0.125f};
  const GlProgram program = colourProgram({}, colour);
  expectEveryPixel(renderToFloatTarget(program), colour);
  EXPECT_EQ(context_->takeErrors(), std::vector<std::string>{});
}

TEST_F(GlTest, FullScreenTriangleGivesPixelCentreNdc) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const GlProgram program =
      GlProgram::fromSources(shaderSource("fullscreen.vert.glsl"), kNdcShader, {}, "ndc_test");
  const auto pixels = renderToFloatTarget(program);
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      const auto& pixel = pixels[static_cast<std::size_t>(y * kWidth + x)];
      EXPECT_NEAR(pixel[0], (x + 0.5) / kWidth * 2 - 1, 1e-5) << x << "," << y;
      EXPECT_NEAR(pixel[1], (y + 0.5) / kHeight * 2 - 1, 1e-5) << x << "," << y;
    }
  }
  EXPECT_EQ(context_->takeErrors(), std::vector<std::string>{});
}

TEST_F(GlTest, DefinesSelectTheVariant) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const std::array<float, 4> colour = {0.25f, 0.5f, 0.75f, 1.0f};
  const GlProgram plain = colourProgram({}, colour);
  const GlProgram inverted = colourProgram({"INVERT"}, colour);
  const GlProgram scaled = colourProgram({"INVERT", "SCALE 2.0"}, colour);
  expectEveryPixel(renderToFloatTarget(plain), colour);
  expectEveryPixel(renderToFloatTarget(inverted), {0.75f, 0.5f, 0.25f, 0.0f});
  expectEveryPixel(renderToFloatTarget(scaled), {1.5f, 1.0f, 0.5f, 0.0f});
  EXPECT_EQ(plain.fragmentSourceWithDefines(), kColourShader);
  EXPECT_EQ(scaled.fragmentSourceWithDefines().rfind(
                "#version 450 core\n#define INVERT\n#define SCALE 2.0\n#line 2\nin vec2 vNdc;", 0),
            0u);
  EXPECT_EQ(context_->takeErrors(), std::vector<std::string>{});
}

TEST_F(GlTest, UniformLocationsAreCachedAndMayBeAbsent) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const GlProgram program = colourProgram({}, {0, 0, 0, 0});
  const GLint location = program.uniform("uColor");
  EXPECT_GE(location, 0);
  EXPECT_EQ(program.uniform("uColor"), location);
  EXPECT_EQ(program.uniform("uAbsent"), -1);
  EXPECT_EQ(context_->takeErrors(), std::vector<std::string>{});
}

TEST_F(GlTest, ProgramsAndObjectsMoveWithoutDoubleDeletion) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  GlProgram first = colourProgram({}, {1, 0, 0, 1});
  const GLuint id = first.id();
  GlProgram second = std::move(first);
  EXPECT_EQ(second.id(), id);
  EXPECT_EQ(first.id(), 0u);  // NOLINT(bugprone-use-after-move): the moved-from state is defined
  EXPECT_EQ(glIsProgram(id), GL_TRUE);
  GlBuffer buffer;
  GlBuffer other = std::move(buffer);
  EXPECT_NE(other.id(), 0u);
  EXPECT_EQ(buffer.id(), 0u);  // NOLINT(bugprone-use-after-move)
  GlTexture texture(GL_TEXTURE_3D);
  EXPECT_EQ(texture.target(), static_cast<GLenum>(GL_TEXTURE_3D));
  const GLuint bufferId = other.id();
  { const GlBuffer moved = std::move(other); }
  EXPECT_EQ(glIsBuffer(bufferId), GL_FALSE);
  EXPECT_EQ(context_->takeErrors(), std::vector<std::string>{});
}

TEST_F(GlTest, CompileErrorNamesTheShaderAndGivesTheLog) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const char* broken = "#version 450 core\nout vec4 fragColor;\nvoid main() { fragColor = ; }\n";
  try {
    GlProgram::fromSources(shaderSource("fullscreen.vert.glsl"), broken, {"SHADING"},
                           "broken_test");
    FAIL() << "a syntax error compiled";
  } catch (const Error& error) {
    const std::string message = error.what();
    EXPECT_NE(message.find("broken_test (fragment shader)"), std::string::npos) << message;
    EXPECT_NE(message.find("error"), std::string::npos) << message;
    EXPECT_NE(message.find("SHADING"), std::string::npos) << message;
    // The #line directive keeps the file's numbering: the error is on line 3.
    EXPECT_NE(message.find("0:3("), std::string::npos) << message;
  }
  EXPECT_THROW(GlProgram::build("fullscreen.vert.glsl", "absent.frag.glsl", {}), Error);
  // Compile failures are reported by the program, not as GL errors.
  EXPECT_EQ(context_->takeErrors(), std::vector<std::string>{});
}

TEST_F(GlTest, GlErrorsAppearInTheDebugLogOnce) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  context_.reset();
  const auto context = headless({.debug = true});
  ASSERT_TRUE(context);
  glBindTexture(GL_TEXTURE_3D, 12345678);  // a name never generated: GL_INVALID_OPERATION
  const std::vector<std::string> errors = context->takeErrors();
  ASSERT_EQ(errors.size(), 2u) << ::testing::PrintToString(errors);
  EXPECT_NE(errors[0].find("GL debug error"), std::string::npos) << errors[0];
  EXPECT_NE(errors[0].find("GL_INVALID_OPERATION"), std::string::npos) << errors[0];
  EXPECT_EQ(errors[1], "GL_INVALID_OPERATION");
  EXPECT_EQ(context->takeErrors(), std::vector<std::string>{});

  glEnable(0x12345);  // not an enum glEnable knows: GL_INVALID_ENUM
  try {
    throwOnGlErrors(*context, "enabling nonsense");
    FAIL() << "no error thrown";
  } catch (const Error& error) {
    const std::string message = error.what();
    EXPECT_EQ(message.rfind("GL errors at enabling nonsense: ", 0), 0u) << message;
    EXPECT_NE(message.find("GL_INVALID_ENUM"), std::string::npos) << message;
  }
  EXPECT_NO_THROW(throwOnGlErrors(*context, "nothing"));
}

TEST_F(GlTest, WithoutDebugGlGetErrorStillReports) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  context_.reset();
  const auto context = headless({.debug = false});
  ASSERT_TRUE(context);
  glBindTexture(GL_TEXTURE_3D, 12345678);
  EXPECT_EQ(context->takeErrors(), std::vector<std::string>{"GL_INVALID_OPERATION"});
}

TEST_F(GlTest, TakeErrorsNeedsTheContextCurrent) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  auto second = headless({});
  ASSERT_TRUE(second);  // now current
  EXPECT_THROW(context_->takeErrors(), Error);
  context_->makeCurrent();
  EXPECT_EQ(context_->takeErrors(), std::vector<std::string>{});
}

// Runs under `xvfb-run` in ctest (gpu_gl_window_xvfb); skips where there is no X display.
TEST(GlWindowContext, WindowHasA45CoreContextAndRenders) {
  if (std::getenv("DISPLAY") == nullptr) {
    GTEST_SKIP() << "skipped: DISPLAY is unset (ctest runs this under xvfb-run as "
                    "gpu_gl_window_xvfb)";
  }
  std::unique_ptr<WindowGlContext> window;
  try {
    window = createWindowContext(64, 48, "octoray test", {.debug = true}, false);
  } catch (const Error& error) {
    FAIL() << error.what();
  }
  ASSERT_NE(window->window(), nullptr);
  EXPECT_TRUE(window->debug());
  GLint major = 0;
  GLint minor = 0;
  glGetIntegerv(GL_MAJOR_VERSION, &major);
  glGetIntegerv(GL_MINOR_VERSION, &minor);
  EXPECT_GE(major * 10 + minor, 45) << window->version();
  {
    // A second window keeps GLFW initialised when the first goes.
    auto second = createWindowContext(32, 32, "second", {}, false);
    EXPECT_NE(second->window(), window->window());
  }
  window->makeCurrent();
  const std::array<float, 4> colour = {0.125f, 0.25f, 1.0f, 0.5f};
  const GlProgram program = colourProgram({}, colour);
  expectEveryPixel(renderToFloatTarget(program), colour);
  EXPECT_EQ(window->takeErrors(), std::vector<std::string>{});
  EXPECT_THROW(createWindowContext(0, 10, "empty"), Error);
}

}  // namespace
}  // namespace octoray::gpu
