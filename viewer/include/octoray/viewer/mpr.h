#pragma once
// Multiplanar reformatting: the planes of the axial, coronal and sagittal views (radiological
// convention: the patient's left on the screen's right in axial and coronal views, anterior on
// the left in the sagittal view), and slices sampled from the octree store's bricks — the same
// bricks, in the same CPU cache, the 3D view streams from.
//
// A slice is sampled at the level whose voxels are no larger than the view's pixels (the
// leaf level when zoomed in), trilinearly, in exact patient geometry (a gantry tilt's shear is
// in the store's index-to-patient affine). Where a brick of that level is not in the cache it
// is requested from a background loader and the slice uses the nearest cached ancestor for
// now: coarser while loading, never blank. The root brick is held for the slicer's lifetime.

#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include "octoray/core/geometry.h"
#include "octoray/viewer/session.h"
#include "octoray/volume/brick_cache.h"
#include "octoray/volume/brick_loader.h"
#include "octoray/volume/store_reader.h"

namespace octoray::viewer {

// A view's plane on screen: pixel (x, y) (centre at x + 0.5, y + 0.5; y = 0 the top row) lies
// at origin + (x + 0.5) * mmPerPixel * right + (y + 0.5) * mmPerPixel * down.
struct MprPlane {
  Vec3 origin;   // patient position of the view's top-left corner (not a pixel centre)
  Vec3 right;    // unit: screen right
  Vec3 down;     // unit: screen down
  Vec3 normal;   // right x down: the direction slices scroll towards with a positive step
  double mmPerPixel = 1;
  int width = 1, height = 1;

  Vec3 at(double x, double y) const {  // window-relative pixel coordinates (fractional)
    return origin + (x * mmPerPixel) * right + (y * mmPerPixel) * down;
  }
  // Where a patient position projects in the view (fractional pixel coordinates).
  std::array<double, 2> pixelOf(Vec3 p) const {
    const Vec3 d = p - origin;
    return {dot(d, right) / mmPerPixel, dot(d, down) / mmPerPixel};
  }
};

// The volume's grid in patient space.
struct Grid {
  std::array<int64_t, 3> dims{1, 1, 1};
  Mat4 patientFromIndex;
  Mat4 indexFromPatient;
  static Grid of(const volume::StoreReader& store);
  Grid() = default;
  Grid(std::array<int64_t, 3> d, const Mat4& patientFromIndexMatrix);
  Vec3 centre() const;
  // Extent of the domain [-0.5, dim - 0.5]^3 projected onto a unit direction, in mm.
  double extentAlong(Vec3 direction) const;
  // The distance between neighbouring slices along `normal`: the patient-space step of the
  // index axis most aligned with it, projected onto it.
  double sliceStepMm(Vec3 normal) const;
  double minSpacingMm() const;
};

// Rotation by `radians` about the unit direction `axis` (right-handed), as an affine without
// translation: what turning the MPR planes applies to Session::mprRotation.
Mat4 rotationAbout(Vec3 axis, double radians);

// The screen axes of view `v` under the shared rotation (identity: standard planes).
// The right axis is the view's standard right axis projected onto its rotated plane, so a
// view's picture does not spin when the other planes are rotated about its normal.
void viewAxes(ViewId v, const Mat4& rotation, Vec3& right, Vec3& down, Vec3& normal);

// The plane of MPR view `v` in a width x height pixel view: through the crosshair, centred on
// the domain's centre projected onto the plane (plus the view's pan), zoom 1 fitting the
// domain's extent.
MprPlane mprPlane(ViewId v, const Session& session, const Grid& grid, int width, int height);

// Orientation letters of a screen direction: "L", "R", "A", "P", "S", "I", or two letters
// for an oblique direction ("LA": mostly left, noticeably anterior).
std::string orientationLabel(Vec3 direction);

struct SliceRequest {
  MprPlane plane;
  SlabMode slab = SlabMode::None;
  double slabMm = 0;
  // Octree level to sample (leaf = store.layout().leafLevel()); see targetLevel().
  int level = 0;
};

struct Slice {
  int width = 0, height = 0;
  std::vector<float> hu;   // physical values (HU for CT), row by row; NaN outside the volume
  int level = 0;           // level asked for
  int coarsestLevelUsed = 0;  // smaller than level while bricks are loading
  int64_t missingBricks = 0;  // bricks of `level` not yet cached (requested)
  int slabSamples = 1;
  bool complete() const { return missingBricks == 0; }
};

struct SlicerStats {
  int64_t requested = 0;   // bricks asked of the loader by the last frame's slices
  std::size_t queued = 0, loading = 0;
  uint64_t loaded = 0;     // total
  uint64_t bytesRead = 0;  // total compressed bytes read by the slicer's loader
};

class StoreSlicer {
 public:
  // `cache` is shared with the 3D view's renderer (thread-safe); the slicer's loader keeps its
  // own request queue.
  StoreSlicer(const volume::StoreReader& store, volume::BrickCache& cache, int loaderThreads = 1);
  ~StoreSlicer();
  StoreSlicer(const StoreSlicer&) = delete;
  StoreSlicer& operator=(const StoreSlicer&) = delete;

  const Grid& grid() const { return grid_; }
  // The coarsest level whose voxels are no larger than `mmPerPixel` (the leaf level at most).
  int targetLevel(double mmPerPixel) const;

  // One frame's slices: beginFrame(), slice() per view, endFrame() hands the frame's missing
  // bricks to the loader (stale requests from earlier frames are dropped).
  void beginFrame();
  Slice slice(const SliceRequest& request);
  void endFrame();
  // Whether bricks arrived since the last call (incomplete slices are worth redoing).
  bool bricksArrived();
  // Brick load errors since the last call ("<store>: node N: ..."), each node once; the node's
  // ancestors stand in for it.
  std::vector<std::string> takeErrors();
  SlicerStats stats() const;

  // Exact leaf-level values at patient positions (NaN outside): missing bricks are read on
  // the calling thread. For measurements, not for drawing.
  std::vector<double> sampleLeaf(const std::vector<Vec3>& positions);

 private:
  struct Resolved {
    std::shared_ptr<const volume::Brick> brick;
    int level = 0;
    volume::Index3 brickIndex{0, 0, 0};
  };
  Resolved resolve(int64_t id, int level, const volume::Index3& brick, bool& missing);
  double sampleAt(const Resolved& r, Vec3 index) const;

  const volume::StoreReader& store_;
  volume::BrickCache& cache_;
  Grid grid_;
  std::shared_ptr<const volume::Brick> root_;
  std::unique_ptr<volume::BrickLoader> loader_;
  std::mutex mutex_;  // guards the per-frame tables below during a parallel slice
  std::unordered_map<int64_t, Resolved> frameResolved_;
  std::unordered_map<int64_t, float> frameRequests_;
  std::unordered_map<int64_t, std::string> failed_;
  std::vector<std::string> newErrors_;
  std::atomic<uint64_t> bytesRead_{0};
  int64_t lastRequested_ = 0;
};

// DICOM's VOI LUT functions (PS3.3 C.11.2.1.2-3). LINEAR, the default, is defined for integer
// values and a window of at least 1 (its -0.5 and window - 1 place integers on the grey
// ramp): what CT and MR viewers show. LINEAR_EXACT maps level +- window/2 linearly, for any
// window above 0: for a volume whose values are not integers (a float NIfTI or MHD, values in
// [0, 1]), where LINEAR would show a window narrower than 1 as a step. SIGMOID maps
// 1 / (1 + exp(-4 (value - level) / window)): level mid-grey, a soft roll-off instead of clipping
// (C.11.2.1.3.1), as some modalities' files ask with VOILUTFunction.
enum class VoiFunction { Linear, LinearExact, Sigmoid };
// DICOM's defined term: "LINEAR", "LINEAR_EXACT", "SIGMOID".
const char* voiFunctionName(VoiFunction function);
// The function a volume's slices are shown with: the one its file declares for its windows
// (SourceWindow::function: "LINEAR_EXACT" or "SIGMOID"), applied to every window on it as
// DICOM viewers do; where it declares none or LINEAR, LINEAR for integer values and
// LINEAR_EXACT for others (LINEAR would show their narrow windows as a step).
VoiFunction voiFunction(const std::string& declared, bool integerValues);

// Maps physical values to grey levels with a window/level: for the linear functions values at
// level - window/2 and below black, level + window/2 and above white. LINEAR takes a window
// below 1 as 1. NaN (outside the volume) maps to black.
uint8_t windowGrey(double value, const WindowLevel& wl, VoiFunction function = VoiFunction::Linear);

}  // namespace octoray::viewer
