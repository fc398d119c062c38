// octoray-view's frame loop: input, dataset, views, window (see app.h for the data flow).
#include "app.h"
#include "pacs_panel.h"
#include "util.h"

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
#include "octoray/transfer/defaults.h"
#include "octoray/transfer/transfer_function_io.h"

namespace octoray::viewer {
namespace fs = std::filesystem;
namespace {

App* gApp = nullptr;  // GLFW callbacks have no closure; one App per process


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



}  // namespace

// A pointer event at the cursor position (x, y) in window coordinates, in framebuffer pixels.
InputEvent pointerEvent(GLFWwindow* win, InputEvent::Type type, double x, double y) {
  int ww = 1, fw = 1, wh = 1, fh = 1;
  glfwGetWindowSize(win, &ww, &wh);
  glfwGetFramebufferSize(win, &fw, &fh);
  InputEvent e;
  e.type = type;
  e.x = x * fw / std::max(1, ww);
  e.y = y * fh / std::max(1, wh);
  return e;
}

// Real input: GLFW callbacks to InputEvents (ImGui's backend, installed after these, chains
// to them and sees the same events).
void installCallbacks(App& app) {
  gApp = &app;
  GLFWwindow* w = app.context_->window();
  glfwSetCursorPosCallback(w, [](GLFWwindow* win, double x, double y) {
    gApp->queue(pointerEvent(win, InputEvent::Type::Move, x, y));
  });
  glfwSetMouseButtonCallback(w, [](GLFWwindow* win, int button, int action, int mods) {
    static double lastPress = -1, lastX = -100, lastY = -100;
    double x = 0, y = 0;
    glfwGetCursorPos(win, &x, &y);
    InputEvent e = pointerEvent(win, action == GLFW_PRESS ? InputEvent::Type::Press : InputEvent::Type::Release, x, y);
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
    InputEvent e = pointerEvent(win, InputEvent::Type::Wheel, x, y);
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
  try {
    context_ = gpu::createWindowContext(options.width, options.height, "octoray-view", glOptions,
                                        !options.hidden);
  } catch (const Error& e) {
    throw GlUnavailable(e.what());
  }
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
    static const ImWchar ranges[] = {0x0020, 0x00FF, 0x2013, 0x2026, 0x2502, 0x2502, 0x25B8, 0x25B8, 0};
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
  if (!options_.mode.empty()) {
    session.mode = parseModeName(options_.mode);
    modeChanged();
  }
  if (!options_.wlPreset.empty()) {
    try {
      chooseWindowLevelPreset(options_.wlPreset);
    } catch (const Error& e) {
      throw Error("", fmt::format("--wl: {}", e.what()));
    }
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
  pacs_ = std::make_unique<PacsPanel>();
  lastFrame_ = std::chrono::steady_clock::now();
}

App::~App() {
  pacs_.reset();  // waits for a running search or retrieval
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

std::filesystem::path App::cacheDir() const {
  return options_.cacheDir.empty() ? defaultCacheDir() : options_.cacheDir;
}

void App::resetForDataset(const std::string& source) {
  mpr_ = {};
  view3d_.reset();
  slicer_.reset();
  grid_.reset();
  dataset_.reset();
  histogram_.clear();
  histLo_ = -1024;  // until the preview's or the store's histogram gives the volume's range
  histHi_ = 3071;
  crosshairSet_ = datasetFailedOpen_ = datasetErrorShown_ = false;
  session.source = source;
  session.measurements.clear();
  valueUnit_.clear();
  integerValues_ = true;
  declaredVoi_.clear();
  sessionLoaded_ = false;  // loadSessionFrom sets it again after open()
  wlChosenForDataset_ = tfChosenForDataset_ = isoChosenForDataset_ = false;
  fileWlPresets_.clear();
  fileWindowsFinal_ = false;
  pendingFileWindow_.clear();
  autoWlPreviewFraction_ = 0;
  openedAt_ = std::chrono::steady_clock::now();
  firstMprMs_ = first3dMs_ = -1;
}

void App::open(const std::string& path) {
  resetForDataset(path);
  try {
    dataset_ = std::make_unique<Dataset>(path, cacheDir());
  } catch (const std::exception& e) {
    messages.push_back(e.what());
    return;
  }
  lookAtFileWindows();  // a store's are known now: --wl and a script's next step may name them
  addRecent(path);
}

void App::openIncoming(std::shared_ptr<IncomingSeries> incoming) {
  const std::string folder = incoming->folder.string();
  resetForDataset(folder);
  dataset_ = std::make_unique<Dataset>(std::move(incoming), cacheDir());
  addRecent(folder);
}

void App::addRecent(const std::string& path) {
  recent_.erase(std::remove(recent_.begin(), recent_.end(), path), recent_.end());
  recent_.insert(recent_.begin(), path);
  if (recent_.size() > 10) recent_.resize(10);
  saveRecent();
}

double App::previewFraction() const {
  if (!dataset_) return 0;
  if (slicer_) return 1;
  const PreviewVolume* preview = dataset_->preview();
  return preview ? preview->fraction() : 0;
}

void App::onDatasetReady() {
  const volume::StoreReader* store = dataset_->store();
  if (!store) return;
  grid_ = Grid::of(*store);
  gpu::RendererConfig config;
  config.poolBytes = options_.poolMib << 20;
  config.cacheBytes = options_.cacheMib << 20;
  config.visibility = gpu::parseVisibility(options_.visibility);
  config.repackWhenSettled = true;  // a converged view, reloaded, is the same picture
  try {
    view3d_ = std::make_unique<View3d>(*store, config);
    slicer_ = std::make_unique<StoreSlicer>(*store, view3d_->renderer().sharedCache());
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
  valueUnit_ = volume::storeHoldsHounsfieldUnits(*store) ? "HU" : "";
  integerValues_ = volume::storeHoldsIntegerValues(*store);
  // The store's histogram replaces the preview's auto window; a volume without HU gets the
  // grey ramp for its values in 3D (as octoray-render's default), a CT after one the CT default.
  if (wlUnit_ == "?") wlUnit_ = valueUnit_;
  if (isoUnit_ == "?") isoUnit_ = valueUnit_;
  applyAutomaticWindowLevel(histogram_, histLo_, histHi_);
  applyAutomaticIsoValue();
  if (valueUnit_ != "HU" || session.preset.starts_with("default-")) applyDefaultTransferFunction();
  // A fresh dataset starts centred; a session's own crosshair and camera are kept.
  if (!sessionLoaded_) {
    if (!crosshairSet_) session.crosshair = grid_->centre();
    resetCamera();
    resetClip();
  }
  crosshairSet_ = true;
  sessionLoaded_ = false;
}

const Grid* App::grid() const { return grid_ ? &*grid_ : nullptr; }

const MprView* App::mprView(ViewId v) const {
  return isMpr(v) ? mpr_[static_cast<std::size_t>(v)].get() : nullptr;
}

void App::markInteraction() { interactionFrames_ = 3; }

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
  if (pacs_ && pacs_->pending()) return false;  // a PACS job runs, or its result is not taken yet
  if (!dataset_) return true;
  if (dataset_->state() == Dataset::State::Importing) return false;
  if (dataset_->state() == Dataset::State::Failed) return true;
  // Ready but not opened yet (the next frame opens it), or it failed to open (nothing more
  // will come).
  if (!view3d_ || !slicer_) return datasetFailedOpen_;
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
  if (pacs_) pacs_->poll(*this);
  if (interactionFrames_ > 0 && !controller_.dragging()) --interactionFrames_;
  const bool interacting = controller_.dragging3d() || (controller_.dragging() && interactionFrames_ > 0) ||
                           interactionFrames_ > 0;

  lookAtFileWindows();
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
    judgeValueUnit(std::numeric_limits<double>::quiet_NaN());  // what the source says, for now
    if (!sessionLoaded_ && !crosshairSet_) session.crosshair = grid_->centre();
    crosshairSet_ = true;
  }
  if (preview && grid_) lookAtPreview(*preview);
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
        mpr_[static_cast<std::size_t>(v)]->update(session, *grid_, r.w, r.h, slicer_.get(), preview, arrived, voiFunction());
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
  if (showPacs && pacs_) pacs_->draw(*this, &showPacs);

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
