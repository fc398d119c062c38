#pragma once
// octoray-view: the application. One GLFW window with an OpenGL 4.5 core context (the same
// context the renderer's brick pool lives in), Dear ImGui for panels and overlays, and per
// frame:
//
//   input (GLFW callbacks, or a script's steps)  -> Controller::handle  -> Session (the model)
//   Session + Dataset                            -> View3d (GpuRenderer::renderFrame)
//                                                -> MprView x 3 (StoreSlicer over the same cache)
//   views' textures + overlays + panels          -> the window; screenshots read it back
//
// The session model (octoray/viewer/session.h) is all a saved session holds; everything here
// is derived from it and from the dataset.

#include <chrono>
#include <deque>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "octoray/core/error.h"
#include "octoray/gpu/gl_context.h"
#include "octoray/gpu/gpu_renderer.h"
#include "octoray/viewer/dataset.h"
#include "octoray/viewer/measure.h"
#include "octoray/viewer/mpr.h"
#include "octoray/viewer/presets.h"
#include "octoray/viewer/script.h"
#include "octoray/viewer/session.h"

struct ImFont;

namespace octoray::viewer {

class PacsPanel;

// The display cannot give the OpenGL 4.5 core context the renderer needs.
class GlUnavailable : public Error {
 public:
  explicit GlUnavailable(const std::string& reason) : Error("", reason) {}
};
// A window saying so (startup_error.cpp); returns the exit status (1).
int showStartupError(const std::string& message, const std::string& screenshot, bool exitAfter);

struct Rect {
  int x = 0, y = 0, w = 0, h = 0;
  bool contains(double px, double py) const {
    return px >= x && py >= y && px < x + w && py < y + h;
  }
};

struct AppOptions {
  std::string data;             // what to open at start (may be empty)
  std::string layout;           // four-up | one-up | 1+3
  std::string preset;           // TF preset
  std::string wlPreset;         // window/level preset
  std::string mode;             // dvr | iso | mip
  std::string camera, session, script, screenshot;
  int frames = 0;               // run this many frames (then screenshot / exit)
  bool exit = false;
  int width = 1280, height = 800;
  std::size_t poolMib = 512, cacheMib = 1024;
  std::filesystem::path cacheDir;
  std::string statsPath;        // per-frame figures (CSV) for measuring
  // Feedback that prunes the 3D working set (octoray-render --visibility): ray feedback by
  // default, as octoray-render's.
  std::string visibility = "rays";
  bool hidden = false;          // an invisible window (tests without a display use Xvfb anyway)
};

gpu::RaycastOptions::ClipBox clipOptions(const ClipBox& c);

// The 3D view: the working-set renderer drawing into a texture each frame it has work.
class View3d {
 public:
  View3d(const volume::StoreReader& store, const gpu::RendererConfig& config);
  ~View3d();
  // Renders when the inputs changed or the working set still refines. `interacting` asks for
  // interactive quality (half resolution, twice the LOD target).
  void update(const Session& session, int width, int height, bool interacting);
  // The session's full-quality options (the view's, movies' and EXR exports').
  gpu::RaycastOptions raycastOptions(const Session& session) const;
  bool converged() const { return converged_; }
  unsigned texture() const { return texture_; }
  int textureWidth() const { return texWidth_; }
  int textureHeight() const { return texHeight_; }
  const gpu::FrameStats& stats() const { return stats_; }
  double lastFrameMs() const { return lastFrameMs_; }
  gpu::GpuRenderer& renderer() { return *renderer_; }
  const gpu::Image& lastImage() const { return lastImage_; }
  std::vector<std::string> takeErrors();
  int64_t framesRendered() const { return frames_; }
  uint64_t bytesRead() const { return bytesRead_; }

 private:
  std::unique_ptr<gpu::GpuRenderer> renderer_;
  unsigned texture_ = 0;
  int texWidth_ = 0, texHeight_ = 0;
  std::string lastKey_, lastContent_;
  int changedFrames_ = 0;
  bool converged_ = false;
  bool lastInteractive_ = false;
  gpu::FrameStats stats_;
  gpu::Image lastImage_;
  double lastFrameMs_ = 0;
  int64_t frames_ = 0;
  uint64_t bytesRead_ = 0;
  std::vector<std::string> errors_;
};

// One MPR view: its plane, the slice sampled from the bricks (or the import's preview), and
// the grey texture the window/level maps it to.
class MprView {
 public:
  explicit MprView(ViewId id);
  ~MprView();
  ViewId id() const { return id_; }
  // Re-slices when the plane or slab changed, or when bricks arrived for an incomplete slice;
  // re-maps grey levels when the window/level changed.
  void update(const Session& session, const Grid& grid, int width, int height,
              StoreSlicer* slicer, const PreviewVolume* preview, bool bricksArrived,
              VoiFunction voi);
  const MprPlane& plane() const { return plane_; }
  const Slice& slice() const { return slice_; }
  unsigned texture() const { return texture_; }
  bool complete() const { return hasSlice_ && slice_.complete(); }
  bool fromPreview() const { return fromPreview_; }
  double lastSliceMs() const { return lastSliceMs_; }
  // The HU value under a view pixel (NaN outside or not sampled).
  double valueAt(int x, int y) const;

 private:
  ViewId id_;
  MprPlane plane_;
  Slice slice_;
  bool hasSlice_ = false, fromPreview_ = false;
  std::string sliceKey_;
  WindowLevel mappedWl_{-1, 0};
  VoiFunction mappedVoi_ = VoiFunction::Linear;
  unsigned texture_ = 0;
  int texWidth_ = 0, texHeight_ = 0;
  double lastSliceMs_ = 0;
};

enum class Tool { WindowLevel, Crosshair, Distance, Angle, Ellipse, Rectangle };
const char* toolName(Tool t);
Tool parseToolName(const std::string& name);

class App;

// Input handlers: events (real or replayed) to model changes.
class Controller {
 public:
  explicit Controller(App& app) : app_(app) {}
  void handle(const InputEvent& e);
  bool dragging() const { return drag_.has_value(); }
  bool dragging3d() const { return drag_ && drag_->view == ViewId::Volume; }
  // A measurement being drawn (shown before it is finished).
  const std::optional<Measurement>& pending() const { return pending_; }
  Tool tool = Tool::WindowLevel;

 private:
  struct Drag {
    ViewId view;
    MouseButton button;
    int mods;
    double startX, startY, lastX, lastY;
    WindowLevel startWl;
    gpu::Camera startCamera;
    MprPlane startPlane;
    Mat4 startRotation;
    std::optional<std::pair<int, int>> clipFace;  // dragging a clip-box face (axis, side)
  };
  void press(const InputEvent& e);
  void move(const InputEvent& e);
  void release(const InputEvent& e);
  void wheel(const InputEvent& e);
  void key(const InputEvent& e);
  void scrollSlices(ViewId view, double steps);

  App& app_;
  std::optional<Drag> drag_;
  std::optional<Measurement> pending_;
  int anglePoints_ = 0;
  ViewId activeView_ = ViewId::Axial;
  double lastX_ = 0, lastY_ = 0;
};

class App {
 public:
  explicit App(const AppOptions& options);
  ~App();
  int run();

  // ---- for the controller and the panels ----
  Session session;
  std::vector<WindowLevelPreset> wlPresets;
  std::vector<std::string> tfPresetNames;  // ours, then Slicer's
  std::vector<std::string> messages;       // errors shown in the window (each names a file)
  bool showHelp = false, showFileDialog = false, showPanel = true, showPacs = false;

  Rect viewRect(ViewId v) const;
  std::optional<ViewId> viewAt(double x, double y) const;
  const Grid* grid() const;
  const MprView* mprView(ViewId v) const;
  void markInteraction();  // a control moved: interactive quality for a few frames
  void open(const std::string& path);
  // A series still arriving from a PACS: its slices appear as they land (dataset.h).
  void openIncoming(std::shared_ptr<IncomingSeries> incoming);
  // Where imported stores and retrieved PACS series are kept.
  std::filesystem::path cacheDir() const;
  void applyWindowLevelPreset(const WindowLevelPreset& p);
  void applyWindowLevelKey(int key);  // 1-9: the table's presets; 0: auto
  // The reader chose a window by name (--wl, a script's wl-preset): "auto", "file", "file 2",
  // ... (the volume's own, applied once its headers are read; "file" where it names none
  // changes nothing), or the table's. Throws octoray::Error for a name that is none of them.
  void chooseWindowLevelPreset(const std::string& name);
  // The windows the open volume's file names, as presets (fileWindowLevelPresets); empty before
  // its headers are read and where it names none.
  const std::vector<WindowLevelPreset>& fileWindowPresets() const { return fileWlPresets_; }
  // The window/level "auto" (presets.h), chosen by the reader: from the store's histogram, or
  // while the volume is imported from its preview's and again once the store is ready. It stays
  // chosen for the volumes opened next, until the reader picks another window.
  void applyAutoWindowLevel();
  // The reader set a window (a preset, a drag, the panel, a script, --wl, a session): no
  // automatic one replaces it for this volume. `tablePreset`: one of the table's CT windows.
  void windowLevelChosen(bool tablePreset = false);
  // The reader set the isovalue (the panel, a script, a session): no automatic one replaces it
  // for this volume.
  void isoValueChosen();
  // The 3D mode changed: a generated default transfer function follows it.
  void modeChanged();
  // The unit of the volume's values: "HU" for CT, "" where they have none (MR, files without
  // units); empty before the source's headers are read. Every value label follows it.
  const std::string& valueUnit() const { return valueUnit_; }
  // How the MPR views map values to grey (viewer::voiFunction of mpr.h: the VOI LUT function
  // the volume's file declares, else by whether its values are integers). And the narrowest
  // window a drag or the panel may set (1 for integer values, else a millionth of their range).
  VoiFunction voiFunction() const;
  double minimumWindow() const;
  // Decimals of the value labels (window/level, the value under the cursor, ROI statistics,
  // the transfer function's points): none for integer values, else as many as their range needs.
  int labelDecimals() const;
  void selectTfPreset(const std::string& name);
  void resetCamera();
  void standardView(char letter);  // A P L R S I
  void resetMprViews();
  void resetClip();
  // The clip-box face (axis, 0 = lo / 1 = hi) under a view pixel, when close enough to grab.
  std::optional<std::pair<int, int>> clipFaceAt(ViewId v, double x, double y) const;
  // The clip box's cross-section with an MPR view's plane (patient points, in order).
  std::vector<Vec3> clipSection(const MprPlane& plane) const;
  void setLayout(Layout layout, std::optional<ViewId> main = {});
  void toggleMaximise(ViewId v);
  void action(const std::string& name, const nlohmann::json& value);
  void saveScreenshot(const std::string& path, std::optional<ViewId> view, bool patientInfo);
  void saveSessionTo(const std::string& path);
  void loadSessionFrom(const std::string& path);
  void dumpState(const std::string& path);
  void exportMovie(const std::string& folder, int frames, double degrees);
  void export3dExr(const std::string& path);
  RoiStats roiStatsOf(const Measurement& m);
  Controller& controller() { return controller_; }
  Dataset* dataset() { return dataset_.get(); }
  View3d* view3d() { return view3d_.get(); }
  StoreSlicer* slicer() { return slicer_.get(); }
  const std::vector<int>& histogram() const { return histogram_; }
  double histogramLo() const { return histLo_; }
  double histogramHi() const { return histHi_; }
  double fps() const { return fps_; }
  ImFont* overlayFont() const { return overlayFont_; }
  bool hidePatientInfo() const { return hidePatientInfo_; }
  bool converged() const;
  // The share of the open dataset's preview slices that are in (1 once the store is open; 0
  // before anything is).
  double previewFraction() const;
  nlohmann::json stateJson();

 private:
  void frame();
  void layoutViews();
  void onDatasetReady();
  // Forgets what was open and starts on `source` (recent files, timers, views).
  void resetForDataset(const std::string& source);
  void addRecent(const std::string& path);
  void runScript();
  std::optional<std::array<double, 2>> resolve(const ScriptPosition& p) const;
  void queue(const InputEvent& e) { events_.push_back(e); }
  void drawViews();
  void drawPanels();     // panels.cpp
  void drawStatusBar();  // panels.cpp
  void drawHelp();       // panels.cpp
  void drawFileDialog(); // panels.cpp
  void drawTfEditor();   // tf_editor.cpp
  void capture();
  void computeHistogram();
  void loadRecent();
  void saveRecent();
  void writeStats();

  friend void installCallbacks(App& app);
  friend class Controller;

  AppOptions options_;
  std::unique_ptr<gpu::WindowGlContext> context_;
  std::unique_ptr<Dataset> dataset_;
  std::unique_ptr<PacsPanel> pacs_;
  std::unique_ptr<View3d> view3d_;
  std::unique_ptr<StoreSlicer> slicer_;
  std::array<std::unique_ptr<MprView>, 3> mpr_;
  std::optional<Grid> grid_;
  Controller controller_{*this};
  std::deque<InputEvent> events_;
  std::array<Rect, kViewCount> rects_;
  // The texts drawn over each view in the last frame (drawViews), for the dumped state; never
  // the patient's identity.
  std::array<std::vector<std::string>, kViewCount> overlayText_;
  Rect viewArea_;
  int fbWidth_ = 0, fbHeight_ = 0;
  std::vector<int> histogram_;
  double histLo_ = -1024, histHi_ = 3071;
  double fps_ = 0;
  std::chrono::steady_clock::time_point lastFrame_;
  int interactionFrames_ = 0;
  ImFont* overlayFont_ = nullptr;
  bool hidePatientInfo_ = false;
  bool quit_ = false;
  int64_t frameIndex_ = 0;
  // script
  std::vector<ScriptStep> script_;
  std::size_t scriptStep_ = 0;
  int scriptWait_ = 0;
  int dragStep_ = -1;
  std::chrono::steady_clock::time_point waitStart_;
  bool waiting_ = false;
  struct PendingShot {
    std::string path;
    std::optional<ViewId> view;
    bool patientInfo = false;
  };
  std::optional<PendingShot> shot_;
  std::vector<std::string> recent_;
  std::string fileDialogPath_;
  std::FILE* stats_ = nullptr;
  std::chrono::steady_clock::time_point openedAt_;
  double firstMprMs_ = -1, first3dMs_ = -1;
  double frameMs_ = 0;
  bool sessionLoaded_ = false;       // the session being opened brings its own camera/crosshair
  std::string valueUnit_;
  // Automatic windows and transfer function. A volume whose file names a window opens with
  // it; else a volume without HU opens with the auto window/level, and a CT with the table's
  // first preset. A volume without HU gets the grey-ramp transfer function of
  // transfer/defaults.h (CT presets mean nothing for its values). None of these replaces what
  // a session, the command line or the reader chose for the volume; a CT opened after another
  // volume's automatic window gets the CT defaults back.
  bool wlChosenForDataset_ = false;  // the reader set a window for this volume
  bool tfChosenForDataset_ = false;  // the reader picked a transfer function preset for it
  bool autoWlChosen_ = false;        // the reader chose "auto" (key 0, --wl auto)
  bool integerValues_ = true;  // every value of the volume is an integer (judged with the unit)
  std::string declaredVoi_;    // the VOILUTFunction its file declares ("" where none): lookAtFileWindows
  bool isoChosenForDataset_ = false;  // the reader set the isovalue for this volume
  // The unit of the values the isovalue was set for ("HU": a CT's, kept for the next CT as a
  // table window is; "auto": transfer::automaticIsoValue of the volume open; "": chosen for a volume
  // without HU; "?": chosen before the volume's unit was known). A CT opened after any but
  // "HU" gets kDefaultCtIsoValueHu.
  std::string isoUnit_ = "HU";
  // The isovalue the volume opens with, unless the reader chose one: a CT keeps a CT's, else
  // transfer::kDefaultCtIsoValueHu; a volume without HU gets transfer::automaticIsoValue of its histogram.
  void applyAutomaticIsoValue();
  // The unit of the values the current window was set for ("HU": a CT window; "?": set before
  // the volume's unit was known; "file": a volume's own window, applied or chosen for it). A CT opened
  // after a window set for other values, or after another volume's own, gets the table's first
  // preset.
  std::string wlUnit_ = "HU";
  double autoWlPreviewFraction_ = 0; // the preview's fraction when auto was last taken from it
  // transfer/defaults.h's transfer function for the mode and the volume (CT or not), unless the
  // reader chose one for this volume: on a volume without HU, and where the preset is such a
  // generated default ("default-...").
  void applyDefaultTransferFunction();
  // Applies the automatic window/level where due: auto, the startup default for a CT after an
  // automatic auto, or nothing. From the store's histogram, or the preview's (counts, lo, hi).
  void applyAutomaticWindowLevel(const std::vector<int>& counts, double lo, double hi);
  // The unit from what the source says and the lowest value seen (holdsHounsfieldUnits).
  void judgeValueUnit(double minimum);
  // While a volume is imported or arrives: its slices so far judge the unit and give the
  // automatic window (windows.cpp).
  void lookAtPreview(const PreviewVolume& preview);
  // Once the volume's headers are read: the windows its file names, the first applied where
  // the reader chose none, or the one the reader asked for before they were known (windows.cpp).
  void lookAtFileWindows();
  // The reader chose one of the volume's own windows.
  void fileWindowChosen();
  std::vector<WindowLevelPreset> fileWlPresets_;
  bool fileWindowsFinal_ = false;  // fileWlPresets_ holds what the whole volume names
  std::string pendingFileWindow_;  // "file N" asked for before the volume's windows were known
  bool crosshairSet_ = false;        // the crosshair has been placed for this dataset
  bool datasetFailedOpen_ = false, datasetErrorShown_ = false;
  bool finalShotTaken_ = false;
  Layout restoreLayout_ = Layout::FourUp;
};

}  // namespace octoray::viewer
