// octoray-view's frame loop: input, dataset, views, window (see app.h for the data flow).
#include "app.h"

#include <GLFW/glfw3.h>
#include <epoxy/gl.h>
#include <fmt/format.h>
#include <imgui.h>
#include <imgui_impl_glfw.h>
#include <imgui_impl_opengl3.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <thread>

#include "octoray/core/error.h"
#include "octoray/gpu/image_io.h"
#include "octoray/transfer/transfer_function_io.h"

namespace octoray::viewer {
namespace fs = std::filesystem;
namespace {

App* gApp = nullptr;  // GLFW callbacks have no closure; one App per process

double secondsSince(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

int modsOf(int glfwMods) {
  return ((glfwMods & GLFW_MOD_SHIFT) ? kShift : 0) | ((glfwMods & GLFW_MOD_CONTROL) ? kCtrl : 0) |
         ((glfwMods & GLFW_MOD_ALT) ? kAlt : 0);
}

std::string keyName(int key) {
  if (key >= GLFW_KEY_A && key <= GLFW_KEY_Z) return std::string(1, static_cast<char>('a' + (key - GLFW_KEY_A)));
  if (key >= GLFW_KEY_0 && key <= GLFW_KEY_9) return std::string(1, static_cast<char>('0' + (key - GLFW_KEY_0)));
  if (key >= GLFW_KEY_KP_0 && key <= GLFW_KEY_KP_9) return std::string(1, static_cast<char>('0' + (key - GLFW_KEY_KP_0)));
  switch (key) {
    case GLFW_KEY_UP: return "Up";
    case GLFW_KEY_DOWN: return "Down";
    case GLFW_KEY_LEFT: return "Left";
    case GLFW_KEY_RIGHT: return "Right";
    case GLFW_KEY_PAGE_UP: return "PageUp";
    case GLFW_KEY_PAGE_DOWN: return "PageDown";
    case GLFW_KEY_HOME: return "Home";
    case GLFW_KEY_END: return "End";
    case GLFW_KEY_ESCAPE: return "Escape";
    case GLFW_KEY_DELETE: return "Delete";
    case GLFW_KEY_BACKSPACE: return "Backspace";
    case GLFW_KEY_F1: return "F1";
    case GLFW_KEY_SPACE: return "Space";
    default: return {};
  }
}

fs::path configDir() {
  if (const char* env = std::getenv("OCTORAY_CONFIG"); env && *env) return env;
  if (const char* xdg = std::getenv("XDG_CONFIG_HOME"); xdg && *xdg) return fs::path(xdg) / "octoray";
  if (const char* home = std::getenv("HOME"); home && *home) return fs::path(home) / ".config" / "octoray";
  return fs::temp_directory_path() / "octoray-config";
}

double residentMib() {
  std::ifstream in("/proc/self/statm");
  long pages = 0, resident = 0;
  in >> pages >> resident;
  return static_cast<double>(resident) * 4096.0 / (1024.0 * 1024.0);
}

}  // namespace

// Real input: GLFW callbacks to InputEvents (ImGui's backend, installed after these, chains
// to them and sees the same events).
void installCallbacks(App& app) {
  gApp = &app;
  GLFWwindow* w = app.context_->window();
  glfwSetCursorPosCallback(w, [](GLFWwindow* win, double x, double y) {
    int ww = 1, fw = 1, wh = 1, fh = 1;
    glfwGetWindowSize(win, &ww, &wh);
    glfwGetFramebufferSize(win, &fw, &fh);
    InputEvent e;
    e.type = InputEvent::Type::Move;
    e.x = x * fw / std::max(1, ww);
    e.y = y * fh / std::max(1, wh);
    gApp->queue(e);
  });
  glfwSetMouseButtonCallback(w, [](GLFWwindow* win, int button, int action, int mods) {
    static double lastPress = -1, lastX = -100, lastY = -100;
    double x = 0, y = 0;
    glfwGetCursorPos(win, &x, &y);
    int ww = 1, fw = 1, wh = 1, fh = 1;
    glfwGetWindowSize(win, &ww, &wh);
    glfwGetFramebufferSize(win, &fw, &fh);
    InputEvent e;
    e.type = action == GLFW_PRESS ? InputEvent::Type::Press : InputEvent::Type::Release;
    e.x = x * fw / std::max(1, ww);
    e.y = y * fh / std::max(1, wh);
    e.button = button == GLFW_MOUSE_BUTTON_RIGHT    ? MouseButton::Right
               : button == GLFW_MOUSE_BUTTON_MIDDLE ? MouseButton::Middle
                                                    : MouseButton::Left;
    e.mods = modsOf(mods);
    if (action == GLFW_PRESS) {
      const double now = glfwGetTime();
      e.doubleClick = now - lastPress < 0.35 && std::abs(e.x - lastX) < 4 && std::abs(e.y - lastY) < 4;
      lastPress = e.doubleClick ? -1 : now;
      lastX = e.x;
      lastY = e.y;
    }
    if (action == GLFW_PRESS && ImGui::GetIO().WantCaptureMouse) return;  // a panel's click
    gApp->queue(e);
  });
  glfwSetScrollCallback(w, [](GLFWwindow* win, double, double dy) {
    if (ImGui::GetIO().WantCaptureMouse) return;
    double x = 0, y = 0;
    glfwGetCursorPos(win, &x, &y);
    int ww = 1, fw = 1, wh = 1, fh = 1;
    glfwGetWindowSize(win, &ww, &wh);
    glfwGetFramebufferSize(win, &fw, &fh);
    InputEvent e;
    e.type = InputEvent::Type::Wheel;
    e.x = x * fw / std::max(1, ww);
    e.y = y * fh / std::max(1, wh);
    e.wheel = dy;
    gApp->queue(e);
  });
  glfwSetKeyCallback(w, [](GLFWwindow*, int key, int, int action, int mods) {
    if (action == GLFW_RELEASE || ImGui::GetIO().WantCaptureKeyboard) return;
    if ((mods & GLFW_MOD_CONTROL) && key == GLFW_KEY_O) {
      gApp->showFileDialog = true;
      return;
    }
    InputEvent e;
    e.type = InputEvent::Type::Key;
    e.key = keyName(key);
    e.mods = modsOf(mods);
    if (!e.key.empty()) gApp->queue(e);
  });
  glfwSetDropCallback(w, [](GLFWwindow*, int count, const char** paths) {
    if (count > 0) gApp->open(paths[0]);
  });
}

App::App(const AppOptions& options) : options_(options) {
  gpu::GlContextOptions glOptions;
  glOptions.debug = false;
  context_ = gpu::createWindowContext(options.width, options.height, "octoray-view", glOptions,
                                      !options.hidden);
  glfwSwapInterval(0);
  IMGUI_CHECKVERSION();
  ImGui::CreateContext();
  ImGuiIO& io = ImGui::GetIO();
  io.IniFilename = nullptr;  // the layout is ours; nothing written beside the user's files
  ImGui::StyleColorsDark();
  ImGuiStyle& style = ImGui::GetStyle();
  style.WindowRounding = 0;
  style.FrameRounding = 2;
  style.WindowBorderSize = 0;
  style.Colors[ImGuiCol_WindowBg] = ImVec4(0.09f, 0.09f, 0.10f, 1.0f);
  style.Colors[ImGuiCol_MenuBarBg] = ImVec4(0.12f, 0.12f, 0.13f, 1.0f);
  const char* fontPath = "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf";
  if (fs::exists(fontPath)) {
    static const ImWchar ranges[] = {0x0020, 0x00FF, 0x00B0, 0x00B0, 0x00B2, 0x00B2, 0x2013, 0x2026, 0x25B8, 0x25B8, 0};
    io.Fonts->AddFontFromFileTTF(fontPath, 15.0f, nullptr, ranges);
    overlayFont_ = io.Fonts->AddFontFromFileTTF("/usr/share/fonts/truetype/dejavu/DejaVuSans-Bold.ttf", 16.0f,
                                                nullptr, ranges);
  } else {
    io.Fonts->AddFontDefault();
  }
  installCallbacks(*this);
  ImGui_ImplGlfw_InitForOpenGL(context_->window(), true);
  ImGui_ImplOpenGL3_Init("#version 450 core");

  try {
    wlPresets = loadWindowLevelPresets(defaultWindowLevelPresetsPath());
  } catch (const Error& e) {
    messages.push_back(e.what());
  }
  tfPresetNames = transfer::presetNames();
  const fs::path slicerXml = fs::path(OCTORAY_SHARED_DIR) / "data/presets/slicer/presets.xml";
  if (fs::exists(slicerXml)) {
    try {
      for (const auto& tf : transfer::loadTransferFunctions(slicerXml)) tfPresetNames.push_back(tf.name);
    } catch (const Error& e) {
      messages.push_back(e.what());
    }
  }
  session.tf = transfer::findPreset(session.preset);
  if (!wlPresets.empty()) applyWindowLevelPreset(wlPresets.front());
  loadRecent();
  fileDialogPath_ = fs::current_path().string();

  if (!options_.statsPath.empty()) {
    stats_ = std::fopen(options_.statsPath.c_str(), "w");
    if (!stats_) throw Error(options_.statsPath, "cannot write the stats file");
    std::fprintf(stats_, "frame,seconds,frame_ms,view3d_ms,interactive,rendered3d,converged3d,mpr_complete,"
                         "working_set_bricks,pool_used,cache_mib,loader_queued,bytes_read,rss_mib\n");
  }
  if (!options_.script.empty()) script_ = loadScript(options_.script);
  if (!options_.session.empty()) {
    loadSessionFrom(options_.session);
  } else if (!options_.data.empty()) {
    open(options_.data);
  }
  if (!options_.layout.empty()) setLayout(parseLayoutName(options_.layout));
  if (!options_.preset.empty()) selectTfPreset(options_.preset);
  if (!options_.mode.empty()) session.mode = parseModeName(options_.mode);
  if (!options_.wlPreset.empty()) {
    const auto it = std::find_if(wlPresets.begin(), wlPresets.end(),
                                 [&](const auto& p) { return p.name == options_.wlPreset; });
    if (it == wlPresets.end()) throw Error("", fmt::format("--wl \"{}\": no such window/level preset", options_.wlPreset));
    applyWindowLevelPreset(*it);
  }
  if (!options_.camera.empty()) {
    const gpu::Camera c = gpu::loadCamera(options_.camera);
    session.camera.eye = c.eye;
    session.camera.target = c.target;
    session.camera.up = c.up;
    session.camera.projection = c.projection;
    session.camera.fovYDegrees = c.fovYDegrees;
    session.camera.orthoHeightMm = c.orthoHeightMm;
  }
  lastFrame_ = std::chrono::steady_clock::now();
}

App::~App() {
  if (stats_) std::fclose(stats_);
  context_->makeCurrent();
  mpr_ = {};
  view3d_.reset();
  slicer_.reset();
  ImGui_ImplOpenGL3_Shutdown();
  ImGui_ImplGlfw_Shutdown();
  ImGui::DestroyContext();
  gApp = nullptr;
}

// ---- opening data --------------------------------------------------------------------------

void App::open(const std::string& path) {
  mpr_ = {};
  view3d_.reset();
  slicer_.reset();
  grid_.reset();
  dataset_.reset();
  histogram_.clear();
  crosshairSet_ = datasetFailedOpen_ = datasetErrorShown_ = false;
  session.source = path;
  session.measurements.clear();
  openedAt_ = std::chrono::steady_clock::now();
  firstMprMs_ = first3dMs_ = -1;
  try {
    const fs::path cache = options_.cacheDir.empty() ? defaultCacheDir() : options_.cacheDir;
    dataset_ = std::make_unique<Dataset>(path, cache);
  } catch (const std::exception& e) {
    messages.push_back(e.what());
    return;
  }
  recent_.erase(std::remove(recent_.begin(), recent_.end(), path), recent_.end());
  recent_.insert(recent_.begin(), path);
  if (recent_.size() > 10) recent_.resize(10);
  saveRecent();
}

void App::onDatasetReady() {
  const volume::StoreReader* store = dataset_->store();
  if (!store) return;
  grid_ = Grid::of(*store);
  gpu::RendererConfig config;
  config.poolBytes = options_.poolMib << 20;
  config.cacheBytes = options_.cacheMib << 20;
  config.visibility = gpu::parseVisibility(options_.visibility);
  try {
    view3d_ = std::make_unique<View3d>(*store, config);
    slicer_ = std::make_unique<StoreSlicer>(*store, const_cast<volume::BrickCache&>(view3d_->renderer().cache()));
  } catch (const std::exception& e) {
    messages.push_back(fmt::format("{}: {}", dataset_->storePath(), e.what()));
    view3d_.reset();
    slicer_.reset();
    return;
  }
  for (int v = 0; v < 3; ++v) {
    if (!mpr_[static_cast<std::size_t>(v)]) mpr_[static_cast<std::size_t>(v)] = std::make_unique<MprView>(static_cast<ViewId>(v));
  }
  computeHistogram();
  // A fresh dataset starts centred; a session's own crosshair and camera are kept.
  if (!sessionLoaded_) {
    if (!crosshairSet_) session.crosshair = grid_->centre();
    resetCamera();
    resetClip();
  }
  crosshairSet_ = true;
  sessionLoaded_ = false;
}

void App::computeHistogram() {
  const volume::StoreReader* store = dataset_ ? dataset_->store() : nullptr;
  if (!store) return;
  const auto& layout = store->layout();
  int level = 0;
  while (level < layout.leafLevel()) {
    const auto& d = layout.levelDims(level);
    if (std::max({d[0], d[1], d[2]}) >= 96) break;
    ++level;
  }
  histLo_ = store->node(0).minValue;
  histHi_ = std::max(histLo_ + 1, static_cast<double>(store->node(0).maxValue));
  histogram_.assign(256, 0);
  const int B = layout.brickSize(), A = layout.border(), E = layout.storedEdge();
  const int64_t first = layout.levelNodeOffset(level), last = layout.levelNodeOffset(level + 1);
  for (int64_t id = first; id < last; ++id) {
    try {
      const volume::Brick b = store->readBrick(id);
      const auto key = layout.nodeKey(id);
      const auto& dims = layout.levelDims(level);
      for (int z = 0; z < B; ++z) {
        if (key.brick[2] * B + z >= dims[2]) break;
        for (int y = 0; y < B; ++y) {
          if (key.brick[1] * B + y >= dims[1]) break;
          for (int x = 0; x < B; ++x) {
            if (key.brick[0] * B + x >= dims[0]) break;
            const std::size_t i = (static_cast<std::size_t>(z + A) * E + (y + A)) * E + (x + A);
            const double v = store->physical(b.format == volume::SampleFormat::UInt16 ? b.u16[i] : b.f32[i]);
            const int bin = std::clamp(static_cast<int>((v - histLo_) / (histHi_ - histLo_) * 256), 0, 255);
            ++histogram_[static_cast<std::size_t>(bin)];
          }
        }
      }
    } catch (const Error& e) {
      messages.push_back(e.what());
      break;
    }
  }
}

// ---- model operations ----------------------------------------------------------------------

const Grid* App::grid() const { return grid_ ? &*grid_ : nullptr; }

const MprView* App::mprView(ViewId v) const {
  return isMpr(v) ? mpr_[static_cast<std::size_t>(v)].get() : nullptr;
}

void App::markInteraction() { interactionFrames_ = 3; }

void App::applyWindowLevelPreset(const WindowLevelPreset& p) {
  session.wl = {p.window, p.level};
  session.wlPreset = p.name;
}

void App::applyWindowLevelKey(int key) {
  for (const auto& p : wlPresets) {
    if (p.key == key) {
      applyWindowLevelPreset(p);
      return;
    }
  }
}

void App::selectTfPreset(const std::string& name) {
  try {
    transfer::TransferFunction tf;
    const auto ours = transfer::presetNames();
    if (std::find(ours.begin(), ours.end(), name) != ours.end()) {
      tf = transfer::findPreset(name);
    } else {
      const fs::path slicerXml = fs::path(OCTORAY_SHARED_DIR) / "data/presets/slicer/presets.xml";
      tf = transfer::selectTransferFunction(transfer::loadTransferFunctions(slicerXml), name,
                                            slicerXml.string());
    }
    session.tf = tf;
    session.preset = name;
  } catch (const Error& e) {
    messages.push_back(e.what());
  }
}

void App::resetCamera() {
  if (!grid_) return;
  gpu::VolumeDomain domain;
  domain.dims = grid_->dims;
  domain.patientFromIndex = grid_->patientFromIndex;
  gpu::OrbitParameters orbit;
  const Rect r = viewRect(ViewId::Volume);
  orbit.width = std::max(8, r.w);
  orbit.height = std::max(8, r.h);
  session.camera = gpu::orbitCamera(domain, orbit);
}

void App::standardView(char letter) {
  if (!grid_) return;
  gpu::VolumeDomain domain;
  domain.dims = grid_->dims;
  domain.patientFromIndex = grid_->patientFromIndex;
  gpu::OrbitParameters orbit;
  switch (letter) {
    case 'A': break;
    case 'P': orbit.azimuthDegrees = 180; break;
    case 'L': orbit.azimuthDegrees = 90; break;
    case 'R': orbit.azimuthDegrees = -90; break;
    case 'S': orbit.elevationDegrees = 90; break;
    case 'I': orbit.elevationDegrees = -90; break;
    default: return;
  }
  const Rect r = viewRect(ViewId::Volume);
  orbit.width = std::max(8, r.w);
  orbit.height = std::max(8, r.h);
  session.camera = gpu::orbitCamera(domain, orbit);
}

void App::resetMprViews() { session.mprViews = {}; }

void App::resetClip() {
  if (!grid_) return;
  session.clip.lo = {-0.5, -0.5, -0.5};
  session.clip.hi = {static_cast<double>(grid_->dims[0]) - 0.5, static_cast<double>(grid_->dims[1]) - 0.5,
                     static_cast<double>(grid_->dims[2]) - 0.5};
}

std::optional<std::pair<int, int>> App::clipFaceAt(ViewId v, double x, double y) const {
  const MprView* mv = mprView(v);
  if (!session.clip.enabled || !grid_ || !mv) return std::nullopt;
  const Rect r = viewRect(v);
  const MprPlane& plane = mv->plane();
  const Vec3 q = grid_->indexFromPatient.transformPoint(plane.at(x - r.x, y - r.y));
  const double grabMm = 6.0 * plane.mmPerPixel;
  std::optional<std::pair<int, int>> best;
  double bestMm = grabMm;
  for (int a = 0; a < 3; ++a) {
    const double spacing = length(grid_->patientFromIndex.column(a));
    bool within = true;
    for (int b = 0; b < 3; ++b) {
      if (b == a) continue;
      const double tol = grabMm / length(grid_->patientFromIndex.column(b));
      if (q[b] < session.clip.lo[b] - tol || q[b] > session.clip.hi[b] + tol) within = false;
    }
    if (!within) continue;
    for (int side = 0; side < 2; ++side) {
      const double bound = side == 0 ? session.clip.lo[a] : session.clip.hi[a];
      const double mm = std::abs(q[a] - bound) * spacing;
      if (mm < bestMm) {
        bestMm = mm;
        best = std::make_pair(a, side);
      }
    }
  }
  return best;
}

std::vector<Vec3> App::clipSection(const MprPlane& plane) const {
  std::vector<Vec3> points;
  if (!grid_) return points;
  const ClipBox& c = session.clip;
  auto corner = [&](int bits) {
    return grid_->patientFromIndex.transformPoint({(bits & 1) ? c.hi.x : c.lo.x, (bits & 2) ? c.hi.y : c.lo.y,
                                                   (bits & 4) ? c.hi.z : c.lo.z});
  };
  for (int from = 0; from < 8; ++from) {
    for (int axis = 0; axis < 3; ++axis) {
      if (from & (1 << axis)) continue;
      const Vec3 a = corner(from), b = corner(from | (1 << axis));
      const double da = dot(a - plane.origin, plane.normal), db = dot(b - plane.origin, plane.normal);
      if ((da < 0) == (db < 0) || da == db) continue;
      points.push_back(a + (da / (da - db)) * (b - a));
    }
  }
  if (points.size() < 3) return {};
  Vec3 centre;
  for (const Vec3& p : points) centre = centre + (1.0 / static_cast<double>(points.size())) * p;
  std::sort(points.begin(), points.end(), [&](const Vec3& p, const Vec3& q) {
    return std::atan2(dot(p - centre, plane.down), dot(p - centre, plane.right)) <
           std::atan2(dot(q - centre, plane.down), dot(q - centre, plane.right));
  });
  return points;
}

void App::setLayout(Layout layout, std::optional<ViewId> main) {
  session.layout = layout;
  if (main) session.mainView = *main;
}

void App::toggleMaximise(ViewId v) {
  if (session.layout == Layout::OneUp && session.mainView == v) {
    session.layout = restoreLayout_;
  } else {
    if (session.layout != Layout::OneUp) restoreLayout_ = session.layout;
    session.layout = Layout::OneUp;
    session.mainView = v;
  }
}

RoiStats App::roiStatsOf(const Measurement& m) {
  if (!slicer_ || !grid_) return {};
  const auto positions = roiSamplePositions(m, grid_->minSpacingMm());
  try {
    return roiStats(m, slicer_->sampleLeaf(positions));
  } catch (const Error& e) {
    messages.push_back(e.what());
    return {};
  }
}

bool App::converged() const {
  if (!dataset_) return true;
  if (dataset_->state() == Dataset::State::Importing) return false;
  if (dataset_->state() == Dataset::State::Failed) return true;
  if (!view3d_ || !slicer_) return true;  // nothing more will come
  for (ViewId v : {ViewId::Axial, ViewId::Coronal, ViewId::Sagittal, ViewId::Volume}) {
    if (viewRect(v).w < 8 || viewRect(v).h < 8) continue;
    if (v == ViewId::Volume) {
      if (!view3d_->converged()) return false;
    } else if (!mpr_[static_cast<std::size_t>(v)] || !mpr_[static_cast<std::size_t>(v)]->complete()) {
      return false;
    }
  }
  return interactionFrames_ == 0 && !controller_.dragging();
}

// ---- layout --------------------------------------------------------------------------------

Rect App::viewRect(ViewId v) const { return rects_[static_cast<std::size_t>(v)]; }

std::optional<ViewId> App::viewAt(double x, double y) const {
  for (int v = 0; v < kViewCount; ++v) {
    if (rects_[static_cast<std::size_t>(v)].w > 0 && rects_[static_cast<std::size_t>(v)].contains(x, y)) {
      return static_cast<ViewId>(v);
    }
  }
  return std::nullopt;
}

void App::layoutViews() {
  glfwGetFramebufferSize(context_->window(), &fbWidth_, &fbHeight_);
  const int menuH = static_cast<int>(std::ceil(ImGui::GetFrameHeight()));
  const int statusH = static_cast<int>(std::ceil(ImGui::GetFrameHeight())) + 6;
  const int panelW = showPanel ? 340 : 0;
  viewArea_ = {0, menuH, std::max(0, fbWidth_ - panelW), std::max(0, fbHeight_ - menuH - statusH)};
  rects_ = {};
  const int gap = 2;
  const Rect& a = viewArea_;
  auto cell = [&](int col, int row, int cols, int rows) {
    const int w = (a.w - gap * (cols - 1)) / cols, h = (a.h - gap * (rows - 1)) / rows;
    return Rect{a.x + col * (w + gap), a.y + row * (h + gap), w, h};
  };
  switch (session.layout) {
    case Layout::FourUp:  // OHIF's fourUp: axial | 3D / coronal | sagittal
      rects_[static_cast<std::size_t>(ViewId::Axial)] = cell(0, 0, 2, 2);
      rects_[static_cast<std::size_t>(ViewId::Volume)] = cell(1, 0, 2, 2);
      rects_[static_cast<std::size_t>(ViewId::Coronal)] = cell(0, 1, 2, 2);
      rects_[static_cast<std::size_t>(ViewId::Sagittal)] = cell(1, 1, 2, 2);
      break;
    case Layout::OneUp:
      rects_[static_cast<std::size_t>(session.mainView)] = a;
      break;
    case Layout::OnePlusThree: {
      const int bigW = (a.w - gap) * 2 / 3, smallW = a.w - gap - bigW;
      rects_[static_cast<std::size_t>(session.mainView)] = {a.x, a.y, bigW, a.h};
      const int smallH = (a.h - 2 * gap) / 3;
      int row = 0;
      for (ViewId v : {ViewId::Axial, ViewId::Coronal, ViewId::Sagittal, ViewId::Volume}) {
        if (v == session.mainView) continue;
        rects_[static_cast<std::size_t>(v)] = {a.x + bigW + gap, a.y + row * (smallH + gap), smallW, smallH};
        ++row;
      }
      break;
    }
  }
}

// ---- script --------------------------------------------------------------------------------

std::optional<std::array<double, 2>> App::resolve(const ScriptPosition& p) const {
  if (p.window) return *p.window;
  const Rect r = viewRect(*p.view);
  if (r.w <= 0) return std::nullopt;
  if (p.pixel) return std::array<double, 2>{r.x + (*p.pixel)[0], r.y + (*p.pixel)[1]};
  if (p.fraction) return std::array<double, 2>{r.x + (*p.fraction)[0] * r.w, r.y + (*p.fraction)[1] * r.h};
  const MprView* mv = mprView(*p.view);
  if (!mv) return std::nullopt;
  const auto px = mv->plane().pixelOf(*p.patient);
  return std::array<double, 2>{r.x + px[0], r.y + px[1]};
}

void App::runScript() {
  while (scriptStep_ < script_.size()) {
    const ScriptStep& s = script_[scriptStep_];
    if (waiting_) {
      if (!converged()) {
        if (secondsSince(waitStart_) > s.timeoutSeconds) {
          throw Error(options_.script, fmt::format("script step {}: not converged after {} s", scriptStep_, s.timeoutSeconds));
        }
        return;
      }
      waiting_ = false;
      ++scriptStep_;
      continue;
    }
    if (dragStep_ < 0 && scriptWait_ < s.wait) {
      ++scriptWait_;
      return;
    }
    auto at = [&](const ScriptPosition& p) {
      const auto xy = resolve(p);
      if (!xy) throw Error(options_.script, fmt::format("script step {}: the view is not on screen", scriptStep_));
      return *xy;
    };
    InputEvent e;
    e.mods = s.mods;
    e.button = s.button;
    switch (s.type) {
      case ScriptStep::Type::Move:
      case ScriptStep::Type::Press:
      case ScriptStep::Type::Release:
      case ScriptStep::Type::Wheel: {
        const auto xy = at(s.at);
        e.x = xy[0];
        e.y = xy[1];
        e.type = s.type == ScriptStep::Type::Move    ? InputEvent::Type::Move
                 : s.type == ScriptStep::Type::Press ? InputEvent::Type::Press
                 : s.type == ScriptStep::Type::Wheel ? InputEvent::Type::Wheel
                                                     : InputEvent::Type::Release;
        e.wheel = s.wheel;
        e.doubleClick = s.doubleClick;
        queue(e);
        break;
      }
      case ScriptStep::Type::Click: {
        const auto xy = at(s.at);
        e.x = xy[0];
        e.y = xy[1];
        e.type = InputEvent::Type::Move;
        queue(e);
        e.type = InputEvent::Type::Press;
        e.doubleClick = s.doubleClick;
        queue(e);
        e.type = InputEvent::Type::Release;
        e.doubleClick = false;
        queue(e);
        break;
      }
      case ScriptStep::Type::Drag: {
        // One frame per step: press, `steps` moves, release (interactive quality meanwhile).
        const auto from = at(s.at), to = at(s.to);
        if (dragStep_ < 0) {
          e.type = InputEvent::Type::Move;
          e.x = from[0];
          e.y = from[1];
          queue(e);
          e.type = InputEvent::Type::Press;
          queue(e);
          dragStep_ = 1;
          return;
        }
        const double t = static_cast<double>(dragStep_) / s.steps;
        e.type = InputEvent::Type::Move;
        e.x = from[0] + t * (to[0] - from[0]);
        e.y = from[1] + t * (to[1] - from[1]);
        queue(e);
        if (dragStep_ < s.steps) {
          ++dragStep_;
          return;
        }
        e.type = InputEvent::Type::Release;
        queue(e);
        dragStep_ = -1;
        break;
      }
      case ScriptStep::Type::Key:
        e.type = InputEvent::Type::Key;
        e.key = s.key;
        queue(e);
        break;
      case ScriptStep::Type::Action: action(s.name, s.value); break;
      case ScriptStep::Type::WaitConverged:
        waiting_ = true;
        waitStart_ = std::chrono::steady_clock::now();
        return;
      case ScriptStep::Type::Screenshot: shot_ = PendingShot{s.path, s.view, s.patientInfo}; break;
      case ScriptStep::Type::SaveSession: saveSessionTo(s.path); break;
      case ScriptStep::Type::LoadSession: loadSessionFrom(s.path); break;
      case ScriptStep::Type::DumpState: dumpState(s.path); break;
      case ScriptStep::Type::Quit: quit_ = true; break;
    }
    ++scriptStep_;
    scriptWait_ = 0;
    return;  // one step per frame
  }
  if (options_.exit && script_.size() > 0 && scriptStep_ >= script_.size() && options_.screenshot.empty()) {
    quit_ = true;
  }
}

void App::action(const std::string& name, const nlohmann::json& value) {
  auto text = [&]() {
    if (!value.is_string()) throw Error(options_.script, fmt::format("action {}: expected a string value", name));
    return value.get<std::string>();
  };
  auto number = [&]() {
    if (!value.is_number()) throw Error(options_.script, fmt::format("action {}: expected a number", name));
    return value.get<double>();
  };
  if (name == "layout") setLayout(parseLayoutName(text()));
  else if (name == "maximise") toggleMaximise(parseViewName(text()));
  else if (name == "tool") controller_.tool = parseToolName(text());
  else if (name == "preset") selectTfPreset(text());
  else if (name == "wl-preset") {
    const std::string n = text();
    const auto it = std::find_if(wlPresets.begin(), wlPresets.end(), [&](const auto& p) { return p.name == n; });
    if (it == wlPresets.end()) throw Error("", fmt::format("no window/level preset \"{}\"", n));
    applyWindowLevelPreset(*it);
  } else if (name == "window-level") {
    if (!value.is_array() || value.size() != 2) throw Error("", "action window-level: expected [window, level]");
    session.wl = {value[0].get<double>(), value[1].get<double>()};
    session.wlPreset.clear();
  } else if (name == "mode") session.mode = parseModeName(text());
  else if (name == "iso") session.isoValue = number();
  else if (name == "lod-pixels") session.lodPixels = number();
  else if (name == "step-factor") session.stepFactor = number();
  else if (name == "slab") session.slab = parseSlabMode(text());
  else if (name == "slab-mm") session.slabMm = number();
  else if (name == "overlays") session.overlays = value.get<bool>();
  else if (name == "clip") {
    // true / false, or {"lo": [i, j, k], "hi": [i, j, k]} in index space (enables it).
    if (value.is_boolean()) {
      session.clip.enabled = value.get<bool>();
    } else {
      const auto lo = value.at("lo"), hi = value.at("hi");
      session.clip = {true, {lo[0].get<double>(), lo[1].get<double>(), lo[2].get<double>()},
                      {hi[0].get<double>(), hi[1].get<double>(), hi[2].get<double>()}};
    }
  }
  else if (name == "patient-info") session.patientInfo = value.get<bool>();
  else if (name == "interactive-quality") session.interactiveQuality = value.get<bool>();
  else if (name == "crosshair") {
    if (!value.is_array() || value.size() != 3) throw Error("", "action crosshair: expected [x, y, z]");
    session.crosshair = {value[0].get<double>(), value[1].get<double>(), value[2].get<double>()};
  } else if (name == "rotate-planes") {
    // {"view": "axial", "degrees": 30}: what a Ctrl+drag does, by an exact angle.
    Vec3 r, d, n;
    viewAxes(parseViewName(value.at("view").get<std::string>()), session.mprRotation, r, d, n);
    const double a = value.at("degrees").get<double>() * 3.14159265358979323846 / 180.0;
    const double c = std::cos(a), s = std::sin(a), t = 1 - c;
    Mat4 rot;
    rot.m[0] = {t * n.x * n.x + c, t * n.x * n.y - s * n.z, t * n.x * n.z + s * n.y, 0};
    rot.m[1] = {t * n.x * n.y + s * n.z, t * n.y * n.y + c, t * n.y * n.z - s * n.x, 0};
    rot.m[2] = {t * n.x * n.z - s * n.y, t * n.y * n.z + s * n.x, t * n.z * n.z + c, 0};
    session.mprRotation = rot * session.mprRotation;
  } else if (name == "reset-planes") session.mprRotation = Mat4::identity();
  else if (name == "standard-view") standardView(text().empty() ? 'A' : text()[0]);
  else if (name == "reset-camera") resetCamera();
  else if (name == "open") open(text());
  else if (name == "movie") exportMovie(value.at("folder").get<std::string>(), value.value("frames", 36), value.value("degrees", 360.0));
  else if (name == "exr") export3dExr(text());
  else if (name == "save-camera") gpu::saveCamera(session.camera, text());
  else if (name == "help") showHelp = value.is_boolean() ? value.get<bool>() : !showHelp;
  else if (name == "panel") showPanel = value.get<bool>();
  else if (name == "clear-measurements") session.measurements.clear();
  else throw Error(options_.script, fmt::format("unknown action \"{}\"", name));
}

// ---- output --------------------------------------------------------------------------------

void App::saveSessionTo(const std::string& path) {
  try {
    saveSession(session, path);
  } catch (const Error& e) {
    messages.push_back(e.what());
  }
}

void App::loadSessionFrom(const std::string& path) {
  try {
    Session loaded = loadSession(path);
    const bool reopen = !dataset_ || loaded.source != dataset_->path();
    session = loaded;
    if (reopen) {
      sessionLoaded_ = true;
      const Session keep = session;
      open(session.source);
      session = keep;
    }
  } catch (const Error& e) {
    messages.push_back(e.what());
  }
}

nlohmann::json App::stateJson() {
  nlohmann::json j;
  j["session"] = sessionToJson(session);
  j["tool"] = toolName(controller_.tool);
  j["window"] = {fbWidth_, fbHeight_};
  j["messages"] = messages;
  j["converged"] = converged();
  if (dataset_) {
    j["dataset"] = {{"path", dataset_->path()},
                    {"state", dataset_->state() == Dataset::State::Ready     ? "ready"
                              : dataset_->state() == Dataset::State::Failed ? "failed"
                                                                             : "importing"},
                    {"store", dataset_->storePath()},
                    {"reusedCache", dataset_->reusedCache()},
                    {"progress", dataset_->progress()}};
  }
  nlohmann::json views = nlohmann::json::object();
  for (int v = 0; v < kViewCount; ++v) {
    const ViewId id = static_cast<ViewId>(v);
    const Rect r = viewRect(id);
    nlohmann::json view{{"rect", {r.x, r.y, r.w, r.h}}};
    if (isMpr(id) && mpr_[static_cast<std::size_t>(v)]) {
      const MprView& m = *mpr_[static_cast<std::size_t>(v)];
      const MprPlane& p = m.plane();
      auto vec = [](Vec3 a) { return nlohmann::json::array({a.x, a.y, a.z}); };
      view["plane"] = {{"origin", vec(p.origin)}, {"right", vec(p.right)}, {"down", vec(p.down)},
                       {"normal", vec(p.normal)}, {"mmPerPixel", p.mmPerPixel},
                       {"width", p.width}, {"height", p.height}};
      view["level"] = m.slice().level;
      view["coarsestLevelUsed"] = m.slice().coarsestLevelUsed;
      view["complete"] = m.complete();
      view["fromPreview"] = m.fromPreview();
      view["slabSamples"] = m.slice().slabSamples;
      view["labels"] = {{"left", orientationLabel(-1.0 * p.right)}, {"right", orientationLabel(p.right)},
                        {"top", orientationLabel(-1.0 * p.down)}, {"bottom", orientationLabel(p.down)}};
    }
    if (id == ViewId::Volume && view3d_) {
      gpu::Camera c = session.camera;
      c.width = r.w;
      c.height = r.h;
      view["camera"] = gpu::cameraToJson(c);
      view["converged"] = view3d_->converged();
      const gpu::FrameStats& st = view3d_->stats();
      view["workingSet"] = {{"leaves", st.workingSet.leaves}, {"bricks", st.workingSet.bricks},
                            {"proxyLeaves", st.workingSet.proxyLeaves}, {"poolSlotsUsed", st.poolSlotsUsed},
                            {"framesRendered", view3d_->framesRendered()}, {"lastFrameMs", view3d_->lastFrameMs()}};
    }
    views[viewName(id)] = view;
  }
  j["views"] = views;
  nlohmann::json results = nlohmann::json::array();
  for (const Measurement& m : session.measurements) {
    nlohmann::json r{{"kind", measureKindName(m.kind)}};
    if (m.kind == MeasureKind::Distance) r["mm"] = distanceMm(m);
    else if (m.kind == MeasureKind::Angle) r["degrees"] = angleDegrees(m);
    else {
      const RoiStats st = roiStatsOf(m);
      r["samples"] = st.samples;
      r["mean"] = st.mean;
      r["sd"] = st.sd;
      r["min"] = st.min;
      r["max"] = st.max;
      r["areaMm2"] = st.areaMm2;
    }
    results.push_back(r);
  }
  j["measurements"] = results;
  if (grid_) {
    const Vec3 sp{length(grid_->patientFromIndex.column(0)), length(grid_->patientFromIndex.column(1)),
                  length(grid_->patientFromIndex.column(2))};
    j["volume"] = {{"dims", grid_->dims}, {"spacingMm", {sp.x, sp.y, sp.z}}};
  }
  j["timing"] = {{"firstMprMs", firstMprMs_}, {"first3dMs", first3dMs_}};
  return j;
}

void App::dumpState(const std::string& path) {
  std::ofstream out(path);
  out << stateJson().dump(2) << "\n";
  if (!out) messages.push_back(path + ": cannot write the state file");
}

void App::capture() {
  if (!shot_) return;
  std::vector<uint8_t> pixels(static_cast<std::size_t>(fbWidth_ * fbHeight_) * 4);
  glPixelStorei(GL_PACK_ALIGNMENT, 1);
  glReadBuffer(GL_BACK);
  glReadPixels(0, 0, fbWidth_, fbHeight_, GL_RGBA, GL_UNSIGNED_BYTE, pixels.data());
  Rect r{0, 0, fbWidth_, fbHeight_};
  if (shot_->view) r = viewRect(*shot_->view);
  gpu::Image image(r.w, r.h);
  image.hasAlpha = false;
  for (int y = 0; y < r.h; ++y) {
    const int srcY = fbHeight_ - 1 - (r.y + y);
    for (int x = 0; x < r.w; ++x) {
      const uint8_t* p = &pixels[static_cast<std::size_t>((srcY * fbWidth_ + r.x + x) * 4)];
      float* q = image.pixel(x, y);
      q[0] = p[0] / 255.0f;
      q[1] = p[1] / 255.0f;
      q[2] = p[2] / 255.0f;
      q[3] = 1.0f;
    }
  }
  try {
    gpu::writePng(image, shot_->path);
    std::ofstream(shot_->path + ".json") << stateJson().dump(2) << "\n";
  } catch (const Error& e) {
    messages.push_back(e.what());
  }
  shot_.reset();
}

void App::exportMovie(const std::string& folder, int frames, double degrees) {
  if (!view3d_ || !grid_) {
    messages.push_back("movie: no volume open");
    return;
  }
  fs::create_directories(folder);
  const Rect r = viewRect(ViewId::Volume);
  gpu::Camera camera = session.camera;
  camera.width = std::max(8, r.w) & ~1;  // even sizes for H.264
  camera.height = std::max(8, r.h) & ~1;
  gpu::RaycastOptions o;
  o.mode = session.mode;
  o.isoValue = session.isoValue;
  o.lodPixels = session.lodPixels;
  o.clip = clipOptions(session.clip);
  for (int i = 0; i < frames; ++i) {
    const gpu::Camera c = gpu::turnAboutCentre(camera, grid_->centre(), degrees * i / frames);
    const gpu::Frame f = view3d_->renderer().render(c, session.tf, o);
    gpu::writePng(f.image, fs::path(folder) / fmt::format("frame_{:04d}.png", i));
  }
  if (std::system("command -v ffmpeg >/dev/null 2>&1") == 0) {
    const std::string cmd = fmt::format(
        "ffmpeg -y -loglevel error -framerate 30 -i '{}/frame_%04d.png' -pix_fmt yuv420p '{}/rotation.mp4'",
        folder, folder);
    if (std::system(cmd.c_str()) != 0) messages.push_back(folder + ": ffmpeg failed to write rotation.mp4");
  }
}

void App::export3dExr(const std::string& path) {
  if (!view3d_) return;
  gpu::Camera c = session.camera;
  const Rect r = viewRect(ViewId::Volume);
  c.width = std::max(8, r.w);
  c.height = std::max(8, r.h);
  gpu::RaycastOptions o;
  o.mode = session.mode;
  o.isoValue = session.isoValue;
  o.lodPixels = session.lodPixels;
  o.clip = clipOptions(session.clip);
  gpu::writeExr(view3d_->renderer().render(c, session.tf, o).image, path);
}

void App::loadRecent() {
  std::ifstream in(configDir() / "recent.json");
  if (!in) return;
  const auto j = nlohmann::json::parse(in, nullptr, false);
  if (!j.is_array()) return;
  for (const auto& p : j) {
    if (p.is_string()) recent_.push_back(p.get<std::string>());
  }
}

void App::saveRecent() {
  std::error_code ec;
  fs::create_directories(configDir(), ec);
  std::ofstream out(configDir() / "recent.json");
  out << nlohmann::json(recent_).dump(2) << "\n";
}

void App::writeStats() {
  if (!stats_) return;
  const gpu::FrameStats* s = view3d_ ? &view3d_->stats() : nullptr;
  bool mprComplete = true;
  for (const auto& m : mpr_) mprComplete = mprComplete && m && m->complete();
  std::fprintf(stats_, "%lld,%.3f,%.2f,%.2f,%d,%lld,%d,%d,%lld,%lld,%.1f,%lld,%llu,%.1f\n",
               static_cast<long long>(frameIndex_), secondsSince(openedAt_), frameMs_,
               view3d_ ? view3d_->lastFrameMs() : 0.0, interactionFrames_ > 0 ? 1 : 0,
               static_cast<long long>(view3d_ ? view3d_->framesRendered() : 0),
               view3d_ && view3d_->converged() ? 1 : 0, mprComplete ? 1 : 0,
               static_cast<long long>(s ? s->workingSet.bricks : 0),
               static_cast<long long>(s ? s->poolSlotsUsed : 0),
               s ? static_cast<double>(s->cacheBytes) / (1 << 20) : 0.0,
               static_cast<long long>(s ? s->loaderQueued : 0),
               static_cast<unsigned long long>((view3d_ ? view3d_->bytesRead() : 0) + (slicer_ ? slicer_->stats().bytesRead : 0)),
               residentMib());
  std::fflush(stats_);
}

// ---- the loop ------------------------------------------------------------------------------

int App::run() {
  while (!glfwWindowShouldClose(context_->window()) && !quit_) {
    frame();
  }
  return 0;
}

void App::frame() {
  const auto frameStart = std::chrono::steady_clock::now();
  const bool idle = script_.empty() && converged() && events_.empty() && options_.frames == 0;
  if (idle) glfwWaitEventsTimeout(0.25);
  else glfwPollEvents();
  ImGui_ImplOpenGL3_NewFrame();
  ImGui_ImplGlfw_NewFrame();
  ImGui::NewFrame();
  layoutViews();
  if (!script_.empty()) runScript();  // after the layout: positions in views resolve

  while (!events_.empty()) {
    const InputEvent e = events_.front();
    events_.pop_front();
    try {
      controller_.handle(e);
    } catch (const std::exception& ex) {
      messages.push_back(ex.what());
    }
  }
  if (interactionFrames_ > 0 && !controller_.dragging()) --interactionFrames_;
  const bool interacting = controller_.dragging3d() || (controller_.dragging() && interactionFrames_ > 0) ||
                           interactionFrames_ > 0;

  if (dataset_ && dataset_->state() == Dataset::State::Ready && !view3d_ && !slicer_ && !datasetFailedOpen_) {
    onDatasetReady();
    if (!view3d_) datasetFailedOpen_ = true;
  }
  if (dataset_ && dataset_->state() == Dataset::State::Failed && !datasetErrorShown_) {
    messages.push_back(dataset_->error());
    datasetErrorShown_ = true;
  }
  // Before the store exists, the preview's grid drives the MPR views.
  const PreviewVolume* preview = dataset_ && !slicer_ ? dataset_->preview() : nullptr;
  if (preview && !grid_) {
    grid_ = preview->grid();
    if (!sessionLoaded_ && !crosshairSet_) session.crosshair = grid_->centre();
    crosshairSet_ = true;
  }
  if (preview) {
    for (int v = 0; v < 3; ++v) {
      if (!mpr_[static_cast<std::size_t>(v)]) mpr_[static_cast<std::size_t>(v)] = std::make_unique<MprView>(static_cast<ViewId>(v));
    }
  }

  try {
    if (grid_ && (slicer_ || preview)) {
      bool arrived = false;
      if (slicer_) {
        arrived = slicer_->bricksArrived();
        for (auto& e : slicer_->takeErrors()) messages.push_back(e);
        slicer_->beginFrame();
      }
      for (int v = 0; v < 3; ++v) {
        const Rect r = viewRect(static_cast<ViewId>(v));
        if (r.w < 8 || r.h < 8 || !mpr_[static_cast<std::size_t>(v)]) continue;
        mpr_[static_cast<std::size_t>(v)]->update(session, *grid_, r.w, r.h, slicer_.get(), preview, arrived);
      }
      if (slicer_) slicer_->endFrame();
      if (firstMprMs_ < 0 && mpr_[0] && mpr_[0]->complete() == false && mpr_[0]->texture()) {
        firstMprMs_ = secondsSince(openedAt_) * 1000;
      } else if (firstMprMs_ < 0 && mpr_[0] && mpr_[0]->texture()) {
        firstMprMs_ = secondsSince(openedAt_) * 1000;
      }
    }
    if (view3d_) {
      const Rect r = viewRect(ViewId::Volume);
      session.camera.width = std::max(8, r.w);
      session.camera.height = std::max(8, r.h);
      if (r.w >= 8 && r.h >= 8) {
        view3d_->update(session, r.w, r.h, interacting);
        for (auto& e : view3d_->takeErrors()) messages.push_back(e);
        if (first3dMs_ < 0 && view3d_->texture()) first3dMs_ = secondsSince(openedAt_) * 1000;
      }
    }
  } catch (const std::exception& e) {
    messages.push_back(e.what());
  }
  // Each message once (a damaged brick reports once per node).
  std::sort(messages.begin(), messages.end());
  messages.erase(std::unique(messages.begin(), messages.end()), messages.end());

  hidePatientInfo_ = shot_ && !shot_->patientInfo;
  drawViews();
  drawPanels();
  drawStatusBar();
  if (showHelp) drawHelp();
  if (showFileDialog) drawFileDialog();

  ImGui::Render();
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
  glViewport(0, 0, fbWidth_, fbHeight_);
  glClearColor(0.02f, 0.02f, 0.02f, 1.0f);
  glClear(GL_COLOR_BUFFER_BIT);
  ImGui_ImplOpenGL3_RenderDrawData(ImGui::GetDrawData());
  capture();
  glfwSwapBuffers(context_->window());

  ++frameIndex_;
  frameMs_ = secondsSince(frameStart) * 1000;
  const double dt = secondsSince(lastFrame_);
  lastFrame_ = std::chrono::steady_clock::now();
  fps_ = fps_ == 0 ? 1.0 / std::max(1e-6, dt) : 0.9 * fps_ + 0.1 / std::max(1e-6, dt);
  writeStats();

  if (options_.frames > 0 && frameIndex_ >= options_.frames && scriptStep_ >= script_.size()) {
    if (!options_.screenshot.empty() && !finalShotTaken_) {
      if (converged() || secondsSince(openedAt_) > 120) {
        shot_ = PendingShot{options_.screenshot, std::nullopt, false};
        finalShotTaken_ = true;
      }
    } else if (options_.exit && (options_.screenshot.empty() || (finalShotTaken_ && !shot_))) {
      quit_ = true;
    }
  } else if (options_.frames == 0 && options_.exit && scriptStep_ >= script_.size()) {
    if (!options_.screenshot.empty() && !finalShotTaken_) {
      if (converged()) {
        shot_ = PendingShot{options_.screenshot, std::nullopt, false};
        finalShotTaken_ = true;
      }
    } else if (!shot_) {
      quit_ = true;
    }
  }
}

}  // namespace octoray::viewer
