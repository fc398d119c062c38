// GL contexts: headless through EGL, windowed through GLFW, with a debug-output error log.

#include "octoray/gpu/gl_context.h"

#include <dlfcn.h>
#include <epoxy/egl.h>
#include <link.h>
#include <epoxy/gl.h>
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>
#include <fmt/format.h>

#include <cstddef>
#include <map>
#include <string_view>
#include <mutex>
#include <utility>

#include "octoray/core/error.h"

namespace octoray::gpu {
namespace {

// Whether the space-separated extension list `list` (may be null) names `extension` exactly.
bool hasExtension(const char* list, std::string_view extension) {
  if (list == nullptr) return false;
  std::string_view rest(list);
  while (!rest.empty()) {
    const std::size_t end = rest.find(' ');
    if (rest.substr(0, end) == extension) return true;
    if (end == std::string_view::npos) break;
    rest.remove_prefix(end + 1);
  }
  return false;
}

std::string eglErrorName(EGLint code) {
  switch (code) {
    case EGL_SUCCESS:
      return "EGL_SUCCESS";
    case EGL_NOT_INITIALIZED:
      return "EGL_NOT_INITIALIZED";
    case EGL_BAD_ACCESS:
      return "EGL_BAD_ACCESS";
    case EGL_BAD_ALLOC:
      return "EGL_BAD_ALLOC";
    case EGL_BAD_ATTRIBUTE:
      return "EGL_BAD_ATTRIBUTE";
    case EGL_BAD_CONFIG:
      return "EGL_BAD_CONFIG";
    case EGL_BAD_CONTEXT:
      return "EGL_BAD_CONTEXT";
    case EGL_BAD_CURRENT_SURFACE:
      return "EGL_BAD_CURRENT_SURFACE";
    case EGL_BAD_DISPLAY:
      return "EGL_BAD_DISPLAY";
    case EGL_BAD_MATCH:
      return "EGL_BAD_MATCH";
    case EGL_BAD_NATIVE_PIXMAP:
      return "EGL_BAD_NATIVE_PIXMAP";
    case EGL_BAD_NATIVE_WINDOW:
      return "EGL_BAD_NATIVE_WINDOW";
    case EGL_BAD_PARAMETER:
      return "EGL_BAD_PARAMETER";
    case EGL_BAD_SURFACE:
      return "EGL_BAD_SURFACE";
    case EGL_CONTEXT_LOST:
      return "EGL_CONTEXT_LOST";
    default:
      return fmt::format("EGL error 0x{:04x}", code);
  }
}

// "<what> failed (EGL_BAD_MATCH)", with the calling thread's last EGL error.
Error eglFailure(std::string_view what) {
  return Error("", fmt::format("{} failed ({})", what, eglErrorName(eglGetError())));
}

std::string glErrorName(GLenum code) {
  switch (code) {
    case GL_INVALID_ENUM:
      return "GL_INVALID_ENUM";
    case GL_INVALID_VALUE:
      return "GL_INVALID_VALUE";
    case GL_INVALID_OPERATION:
      return "GL_INVALID_OPERATION";
    case GL_STACK_OVERFLOW:
      return "GL_STACK_OVERFLOW";
    case GL_STACK_UNDERFLOW:
      return "GL_STACK_UNDERFLOW";
    case GL_OUT_OF_MEMORY:
      return "GL_OUT_OF_MEMORY";
    case GL_INVALID_FRAMEBUFFER_OPERATION:
      return "GL_INVALID_FRAMEBUFFER_OPERATION";
    case GL_CONTEXT_LOST:
      return "GL_CONTEXT_LOST";
    default:
      return fmt::format("GL error 0x{:04x}", code);
  }
}

std::string_view debugSourceName(GLenum source) {
  switch (source) {
    case GL_DEBUG_SOURCE_API:
      return "API";
    case GL_DEBUG_SOURCE_WINDOW_SYSTEM:
      return "window system";
    case GL_DEBUG_SOURCE_SHADER_COMPILER:
      return "shader compiler";
    case GL_DEBUG_SOURCE_THIRD_PARTY:
      return "third party";
    case GL_DEBUG_SOURCE_APPLICATION:
      return "application";
    default:
      return "other source";
  }
}

std::string_view debugTypeName(GLenum type) {
  switch (type) {
    case GL_DEBUG_TYPE_ERROR:
      return "error";
    case GL_DEBUG_TYPE_DEPRECATED_BEHAVIOR:
      return "deprecated behaviour";
    case GL_DEBUG_TYPE_UNDEFINED_BEHAVIOR:
      return "undefined behaviour";
    case GL_DEBUG_TYPE_PORTABILITY:
      return "portability";
    case GL_DEBUG_TYPE_PERFORMANCE:
      return "performance";
    default:
      return "message";
  }
}

std::string_view debugSeverityName(GLenum severity) {
  switch (severity) {
    case GL_DEBUG_SEVERITY_HIGH:
      return "high";
    case GL_DEBUG_SEVERITY_MEDIUM:
      return "medium";
    case GL_DEBUG_SEVERITY_LOW:
      return "low";
    default:
      return "notification";
  }
}

// EGL display initialisation is per display, not per caller: eglInitialize on an initialised
// display does nothing and eglTerminate ends it for every context on it. Contexts therefore
// share a count per display, and the last one terminates it.
std::mutex eglDisplayMutex;
std::map<EGLDisplay, int> eglDisplayUsers;

// Returns the display's EGL version as major * 10 + minor.
int initialiseDisplay(EGLDisplay display) {
  const std::lock_guard lock(eglDisplayMutex);
  EGLint major = 0;
  EGLint minor = 0;
  if (eglInitialize(display, &major, &minor) != EGL_TRUE) throw eglFailure("eglInitialize");
  ++eglDisplayUsers[display];
  return major * 10 + minor;
}

void releaseDisplay(EGLDisplay display) {
  const std::lock_guard lock(eglDisplayMutex);
  const auto user = eglDisplayUsers.find(display);
  if (user == eglDisplayUsers.end()) return;
  if (--user->second == 0) {
    eglDisplayUsers.erase(user);
    eglTerminate(display);
  }
}

// GLFW is initialised with the first window and terminated with the last.
std::mutex glfwMutex;
int glfwUsers = 0;

std::string glfwErrorText() {
  const char* description = nullptr;
  const int code = glfwGetError(&description);
  if (description != nullptr) return description;
  return code == GLFW_NO_ERROR ? "no error reported" : fmt::format("GLFW error 0x{:x}", code);
}

void acquireGlfw() {
  const std::lock_guard lock(glfwMutex);
  if (glfwUsers == 0) {
    glfwGetError(nullptr);  // an earlier failure must not be reported as this one's
    if (glfwInit() != GLFW_TRUE) throw Error("", "GLFW: glfwInit failed: " + glfwErrorText());
  }
  ++glfwUsers;
}

void releaseGlfw() {
  const std::lock_guard lock(glfwMutex);
  if (--glfwUsers == 0) glfwTerminate();
}

class EglContext final : public GlContext {
 public:
  // Owns one initialisation of `display` from here on.
  EglContext(EGLDisplay display, bool debug) : GlContext(debug), display_(display) {
    eglVersion_ = initialiseDisplay(display_);
    displayInitialised_ = true;
  }

  ~EglContext() override {
    if (context_ != EGL_NO_CONTEXT) {
      if (eglGetCurrentContext() == context_) {
        eglMakeCurrent(display_, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
      }
      eglDestroyContext(display_, context_);
    }
    if (surface_ != EGL_NO_SURFACE) eglDestroySurface(display_, surface_);
    if (displayInitialised_) releaseDisplay(display_);
  }

  // Creates the 4.5 core context, makes it current and checks it.
  void create(bool debug) {
    const char* extensions = eglQueryString(display_, EGL_EXTENSIONS);
    const bool egl15 = eglVersion_ >= 15;
    if (!egl15 && !hasExtension(extensions, "EGL_KHR_create_context")) {
      throw Error("", "neither EGL 1.5 nor EGL_KHR_create_context (no GL version request)");
    }
    const bool surfaceless = hasExtension(extensions, "EGL_KHR_surfaceless_context");
    if (eglBindAPI(EGL_OPENGL_API) != EGL_TRUE) throw eglFailure("eglBindAPI(EGL_OPENGL_API)");

    // A pbuffer-capable config when there is one; Mesa's surfaceless platform may offer only
    // configs without surface types, usable with EGL_KHR_surfaceless_context.
    EGLConfig config = nullptr;
    EGLint count = 0;
    const EGLint pbufferConfig[] = {EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT, EGL_SURFACE_TYPE,
                                    EGL_PBUFFER_BIT, EGL_NONE};
    const bool hasPbufferConfig =
        eglChooseConfig(display_, pbufferConfig, &config, 1, &count) == EGL_TRUE && count > 0;
    if (!hasPbufferConfig) {
      if (!surfaceless) {
        throw Error("", "no config with OpenGL and pbuffers, and no EGL_KHR_surfaceless_context");
      }
      const EGLint anyConfig[] = {EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT, EGL_SURFACE_TYPE, 0,
                                  EGL_NONE};
      if (eglChooseConfig(display_, anyConfig, &config, 1, &count) != EGL_TRUE || count == 0) {
        throw Error("", "no EGL config renders OpenGL");
      }
    }

    std::vector<EGLint> attributes = {
        EGL_CONTEXT_MAJOR_VERSION,       4,
        EGL_CONTEXT_MINOR_VERSION,       5,
        EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT};
    if (debug) {
      if (egl15) {
        attributes.insert(attributes.end(), {EGL_CONTEXT_OPENGL_DEBUG, EGL_TRUE});
      } else {
        attributes.insert(attributes.end(),
                          {EGL_CONTEXT_FLAGS_KHR, EGL_CONTEXT_OPENGL_DEBUG_BIT_KHR});
      }
    }
    attributes.push_back(EGL_NONE);
    context_ = eglCreateContext(display_, config, EGL_NO_CONTEXT, attributes.data());
    if (context_ == EGL_NO_CONTEXT) throw eglFailure("eglCreateContext(OpenGL 4.5 core)");

    if (!surfaceless) {
      const EGLint size[] = {EGL_WIDTH, 1, EGL_HEIGHT, 1, EGL_NONE};
      surface_ = eglCreatePbufferSurface(display_, config, size);
      if (surface_ == EGL_NO_SURFACE) throw eglFailure("eglCreatePbufferSurface(1x1)");
    }
    makeCurrent();
    initialise("EGL");
  }

  void makeCurrent() override {
    // eglMakeCurrent binds for the thread's current API, which starts as OpenGL ES.
    if (eglBindAPI(EGL_OPENGL_API) != EGL_TRUE) throw eglFailure("EGL: eglBindAPI");
    if (eglMakeCurrent(display_, surface_, surface_, context_) != EGL_TRUE) {
      throw eglFailure("EGL: eglMakeCurrent");
    }
  }

 private:
  bool isCurrent() const override {
    return eglQueryAPI() == EGL_OPENGL_API && eglGetCurrentContext() == context_;
  }

  EGLDisplay display_;
  bool displayInitialised_ = false;
  int eglVersion_ = 0;  // major * 10 + minor
  EGLContext context_ = EGL_NO_CONTEXT;
  EGLSurface surface_ = EGL_NO_SURFACE;
};

// The headless displays to try, in order, with a label each for the error message.
std::vector<std::pair<std::string, EGLDisplay>> headlessDisplays(std::vector<std::string>& tried) {
  std::vector<std::pair<std::string, EGLDisplay>> displays;
  // Null (EGL_BAD_DISPLAY) where the client has no client extensions at all.
  const char* client = eglQueryString(EGL_NO_DISPLAY, EGL_EXTENSIONS);
  const bool platforms = hasExtension(client, "EGL_EXT_platform_base");
  if (platforms && hasExtension(client, "EGL_MESA_platform_surfaceless")) {
    displays.emplace_back("surfaceless", eglGetPlatformDisplayEXT(EGL_PLATFORM_SURFACELESS_MESA,
                                                                  EGL_DEFAULT_DISPLAY, nullptr));
  } else {
    tried.emplace_back("surfaceless: EGL_MESA_platform_surfaceless not supported");
  }
  if (platforms && hasExtension(client, "EGL_EXT_platform_device") &&
      (hasExtension(client, "EGL_EXT_device_enumeration") ||
       hasExtension(client, "EGL_EXT_device_base"))) {
    EGLint count = 0;
    if (eglQueryDevicesEXT(0, nullptr, &count) == EGL_TRUE && count > 0) {
      std::vector<EGLDeviceEXT> devices(static_cast<std::size_t>(count));
      eglQueryDevicesEXT(count, devices.data(), &count);
      devices.resize(static_cast<std::size_t>(count));
      for (std::size_t i = 0; i < devices.size(); ++i) {
        displays.emplace_back(
            fmt::format("device {}", i),
            eglGetPlatformDisplayEXT(EGL_PLATFORM_DEVICE_EXT, devices[i], nullptr));
      }
    } else {
      tried.emplace_back("devices: none enumerated");
    }
  } else {
    tried.emplace_back("devices: EGL_EXT_platform_device not supported");
  }
  displays.emplace_back("default", eglGetDisplay(EGL_DEFAULT_DISPLAY));
  return displays;
}

}  // namespace

namespace detail {

struct GlDebugLog {
  static constexpr std::size_t kMaxMessages = 256;
  std::vector<std::string> messages;
  std::size_t dropped = 0;
};

}  // namespace detail

namespace {

// Keeps the GL drivers the context loaded (Mesa's *_dri.so) resident until the process exits.
// Mesa unloads its driver at eglTerminate / glfwTerminate without freeing the driver's static
// state; LeakSanitizer then reports that memory from an "<unknown module>" that no
// suppression can name, which would fail every sanitised run of a GL tool. Resident, the
// memory stays reachable and nothing is reported; a process that rendered once would keep
// the driver anyway when it renders again.
void keepDriversResidentImpl() {
  dl_iterate_phdr(
      [](dl_phdr_info* info, std::size_t, void*) {
        const std::string_view name = info->dlpi_name != nullptr ? info->dlpi_name : "";
        if (name.ends_with("_dri.so")) dlopen(info->dlpi_name, RTLD_NOW | RTLD_NOLOAD | RTLD_NODELETE);
        return 0;
      },
      nullptr);
}

}  // namespace

namespace {

// Keeps errors and high-severity messages of any type; debug output is synchronous, so this
// runs on the thread of the failing GL call. The shader compiler's messages are left out:
// GlProgram reports a failed compile with its log as an exception.
void GLAPIENTRY recordDebugMessage(GLenum source, GLenum type, GLuint id, GLenum severity,
                                   GLsizei length, const GLchar* message,
                                   const void* userParam) noexcept {
  if (type != GL_DEBUG_TYPE_ERROR && severity != GL_DEBUG_SEVERITY_HIGH) return;
  if (source == GL_DEBUG_SOURCE_SHADER_COMPILER) return;
  auto* log = static_cast<detail::GlDebugLog*>(const_cast<void*>(userParam));
  try {
    if (log->messages.size() >= detail::GlDebugLog::kMaxMessages) {
      ++log->dropped;
      return;
    }
    std::string text =
        length >= 0 ? std::string(message, static_cast<std::size_t>(length)) : std::string(message);
    while (!text.empty() && (text.back() == '\n' || text.back() == '\0')) text.pop_back();
    log->messages.push_back(fmt::format("GL debug {} ({}, {} severity, id {}): {}",
                                        debugTypeName(type), debugSourceName(source),
                                        debugSeverityName(severity), id, text));
  } catch (...) {
    ++log->dropped;  // out of memory while formatting: counted, never thrown into the driver
  }
}

}  // namespace

GlContext::GlContext(bool debug) : debug_(debug), log_(std::make_unique<detail::GlDebugLog>()) {}

GlContext::~GlContext() = default;

void GlContext::initialise(std::string_view api) {
  keepDriversResidentImpl();
  GLint major = 0;
  GLint minor = 0;
  GLint profile = 0;
  glGetIntegerv(GL_MAJOR_VERSION, &major);
  glGetIntegerv(GL_MINOR_VERSION, &minor);
  glGetIntegerv(GL_CONTEXT_PROFILE_MASK, &profile);
  const auto* version = reinterpret_cast<const char*>(glGetString(GL_VERSION));
  const auto* renderer = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
  version_ = version != nullptr ? version : "";
  renderer_ = renderer != nullptr ? renderer : "";
  if (major * 10 + minor < 45 || (profile & GL_CONTEXT_CORE_PROFILE_BIT) == 0) {
    throw Error("", fmt::format("{}: got OpenGL {}.{} (\"{}\", {}), not 4.5 core", api, major,
                                minor, version_, renderer_));
  }
  if (debug_) {
    glEnable(GL_DEBUG_OUTPUT);
    glEnable(GL_DEBUG_OUTPUT_SYNCHRONOUS);
    glDebugMessageCallback(&recordDebugMessage, log_.get());
    // Notifications are never kept; the driver need not format them.
    glDebugMessageControl(GL_DONT_CARE, GL_DONT_CARE, GL_DEBUG_SEVERITY_NOTIFICATION, 0, nullptr,
                          GL_FALSE);
  }
  takeErrors();  // start clean
}

std::vector<std::string> GlContext::takeErrors() {
  if (!isCurrent()) {
    throw Error("", "GlContext::takeErrors: the context is not current on this thread");
  }
  std::vector<std::string> errors = std::exchange(log_->messages, {});
  if (log_->dropped > 0) {
    errors.push_back(fmt::format("{} more GL debug messages dropped", log_->dropped));
    log_->dropped = 0;
  }
  for (std::string& code : takeGlErrorCodes()) errors.push_back(std::move(code));
  return errors;
}

std::vector<std::string> takeGlErrorCodes() {
  std::vector<std::string> codes;
  // glGetError returns one recorded flag per call; a lost context may keep reporting.
  for (int i = 0; i < 16; ++i) {
    const GLenum code = glGetError();
    if (code == GL_NO_ERROR) break;
    codes.push_back(glErrorName(code));
  }
  return codes;
}

void throwOnGlError(std::string_view where) {
  const std::vector<std::string> codes = takeGlErrorCodes();
  if (codes.empty()) return;
  std::string list;
  for (const std::string& code : codes) list += (list.empty() ? "" : ", ") + code;
  throw Error("", fmt::format("{} while {}", list, where));
}

std::unique_ptr<GlContext> createHeadlessContext(const GlContextOptions& options) {
  std::vector<std::string> tried;
  for (auto& [label, display] : headlessDisplays(tried)) {
    if (display == EGL_NO_DISPLAY) {
      tried.push_back(fmt::format("{}: no display ({})", label, eglErrorName(eglGetError())));
      continue;
    }
    try {
      auto context = std::make_unique<EglContext>(display, options.debug);
      context->create(options.debug);
      return context;
    } catch (const Error& error) {
      tried.push_back(label + ": " + error.reason());
    }
  }
  std::string list;
  for (const std::string& attempt : tried) list += (list.empty() ? "" : "; ") + attempt;
  throw Error("", "EGL: no display supports OpenGL 4.5 core (tried " + list + ")");
}

WindowGlContext::WindowGlContext(int width, int height, const std::string& title,
                                 const GlContextOptions& options, bool visible)
    : GlContext(options.debug), window_(nullptr) {
  if (width <= 0 || height <= 0) {
    throw Error("", fmt::format("GLFW: window size {}x{} is not positive", width, height));
  }
  acquireGlfw();
  glfwDefaultWindowHints();
  glfwWindowHint(GLFW_CLIENT_API, GLFW_OPENGL_API);
  glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, 4);
  glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, 5);
  glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
  glfwWindowHint(GLFW_OPENGL_FORWARD_COMPAT, GLFW_TRUE);
  glfwWindowHint(GLFW_OPENGL_DEBUG_CONTEXT, options.debug ? GLFW_TRUE : GLFW_FALSE);
  glfwWindowHint(GLFW_VISIBLE, visible ? GLFW_TRUE : GLFW_FALSE);
  window_ = glfwCreateWindow(width, height, title.c_str(), nullptr, nullptr);
  if (window_ == nullptr) {
    std::string reason = glfwErrorText();
    keepDriversResidentImpl();  // the failed attempt may have loaded the driver
    releaseGlfw();
    throw Error("", "GLFW: no window with an OpenGL 4.5 core context: " + reason);
  }
  glfwMakeContextCurrent(window_);
}

void keepGlDriversResident() { keepDriversResidentImpl(); }

WindowGlContext::~WindowGlContext() {
  if (glfwGetCurrentContext() == window_) glfwMakeContextCurrent(nullptr);
  glfwDestroyWindow(window_);
  releaseGlfw();
}

void WindowGlContext::makeCurrent() { glfwMakeContextCurrent(window_); }

bool WindowGlContext::isCurrent() const { return glfwGetCurrentContext() == window_; }

std::unique_ptr<WindowGlContext> createWindowContext(int width, int height,
                                                     const std::string& title,
                                                     const GlContextOptions& options,
                                                     bool visible) {
  std::unique_ptr<WindowGlContext> context(
      new WindowGlContext(width, height, title, options, visible));
  context->initialise("GLFW");
  return context;
}

void throwOnGlErrors(GlContext& ctx, std::string_view where) {
  const std::vector<std::string> errors = ctx.takeErrors();
  if (errors.empty()) return;
  std::string list;
  for (const std::string& error : errors) list += (list.empty() ? "" : "; ") + error;
  throw Error("", fmt::format("GL errors at {}: {}", where, list));
}

}  // namespace octoray::gpu
