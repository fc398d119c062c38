#pragma once
// OpenGL 4.5 core contexts: headless through EGL (Mesa's surfaceless platform, an EGL device,
// or the default display; llvmpipe where there is no GPU) or in a GLFW window. GL entry points
// are loaded by libepoxy. Rendering goes into the caller's own framebuffer objects; a
// headless context has no default framebuffer.
//
// A context is created current on the calling thread. GL calls need the context current
// (makeCurrent); one context is used by one thread at a time. Window contexts, like GLFW, are
// for the main thread only.
//
// Errors: with `debug`, GL debug output is synchronous and every message of type
// GL_DEBUG_TYPE_ERROR or of high severity is kept in the context's log (except the shader
// compiler's: GlProgram throws those with the log); takeErrors() returns them with the codes
// glGetError() still holds. GL objects (gl_program.h) must be destroyed while their context is
// current: with no current context, libepoxy aborts the process on the first GL call. Creation
// failures throw octoray::Error naming the step that failed; no EGL display or GL driver is an
// Error, never a crash.

#include <memory>
#include <string>
#include <string_view>
#include <vector>

struct GLFWwindow;

namespace octoray::gpu {

namespace detail {
struct GlDebugLog;  // gl_context.cpp
}

struct GlContextOptions {
  // GL debug context and debug-output log; on in debug builds of the caller.
#ifdef NDEBUG
  bool debug = false;
#else
  bool debug = true;
#endif
};

class GlContext {
 public:
  GlContext(const GlContext&) = delete;
  GlContext& operator=(const GlContext&) = delete;
  virtual ~GlContext();

  // Makes this context current on the calling thread.
  virtual void makeCurrent() = 0;

  // GL_RENDERER and GL_VERSION, read when the context was created.
  const std::string& renderer() const { return renderer_; }
  const std::string& version() const { return version_; }
  // Whether debug output is on (GlContextOptions::debug).
  bool debug() const { return debug_; }

  // The debug messages recorded since the last call, then every code glGetError() returns
  // (as "GL_INVALID_OPERATION", ...); clears both. The context must be current on the calling
  // thread (checked: Error otherwise). Empty after clean GL work.
  std::vector<std::string> takeErrors();

 protected:
  explicit GlContext(bool debug);
  // For the subclass once its context is current: checks for 4.5 core, reads the strings and
  // installs the debug-output callback. Throws Error (reason prefixed by `api`) on failure.
  void initialise(std::string_view api);
  virtual bool isCurrent() const = 0;

 private:
  bool debug_;
  std::string renderer_;
  std::string version_;
  std::unique_ptr<detail::GlDebugLog> log_;  // address passed to the GL debug callback
};

class WindowGlContext;

// A headless 4.5 core context (EGL): Mesa's surfaceless platform when the client supports it,
// then each EGL device, then the default display; made current without a surface
// (EGL_KHR_surfaceless_context) or with a 1x1 pbuffer.
std::unique_ptr<GlContext> createHeadlessContext(const GlContextOptions& options = {});

// A GLFW window of width x height screen coordinates with a 4.5 core, forward-compatible
// context. GLFW is initialised with the first window and terminated with the last. Throws
// Error with GLFW's description when there is no display or no 4.5 core context.
std::unique_ptr<WindowGlContext> createWindowContext(int width, int height,
                                                     const std::string& title,
                                                     const GlContextOptions& options = {},
                                                     bool visible = true);

class WindowGlContext final : public GlContext {
 public:
  ~WindowGlContext() override;
  void makeCurrent() override;
  // The window, for the caller's event loop and swapping (glfwSwapBuffers).
  GLFWwindow* window() const { return window_; }

 private:
  friend std::unique_ptr<WindowGlContext> createWindowContext(int, int, const std::string&,
                                                              const GlContextOptions&, bool);
  WindowGlContext(int width, int height, const std::string& title, const GlContextOptions& options,
                  bool visible);
  bool isCurrent() const override;

  GLFWwindow* window_;
};

// Keeps the GL drivers loaded so far (Mesa's *_dri.so) resident until the process exits, so
// terminating GLFW or EGL does not unload a driver with its static state still allocated
// (which LeakSanitizer would report from an unnamed module). Contexts made here do it
// themselves; code that makes its own GLFW context (the viewer's start-up error window)
// calls it.
void keepGlDriversResident();

// Throws octoray::Error("", "GL errors at <where>: ...") when ctx.takeErrors() is not empty.
void throwOnGlErrors(GlContext& ctx, std::string_view where);

// The codes glGetError() reports on the calling thread's current context (as
// "GL_INVALID_OPERATION", ...; at most 16: a lost context may keep reporting); clears them.
// For code that draws without holding its GlContext (the renderers).
std::vector<std::string> takeGlErrorCodes();
// Throws octoray::Error("<codes> while <where>") when takeGlErrorCodes() is not empty.
void throwOnGlError(std::string_view where);

}  // namespace octoray::gpu
