#pragma once
// The raycasting pass (paper 003 §5): one full-screen fragment pass that walks the spatial
// index of the cut it is given (spatial_index.h) through the bricks of the BrickPool (see
// gpu/shaders/raycast.frag.glsl). It draws the cut; it does not choose it (working_set.h).
//
// The pass draws into its own framebuffer (colour RGBA32F premultiplied, an auxiliary
// RGBA32F target with the depth in mm of the first contribution and the MIP maximum or the
// isovalue, per-pixel counters when asked, and a 32-bit depth buffer holding the depth of the
// ray's last sample where it terminated, for the occlusion queries of the working set), so it
// runs the same in a GLFW window's context and headless (gl_context.h). Every call needs the
// GL context current on the calling thread.
//
// Optical model: the CPU reference's (reference_renderer.h), in single precision on the
// working set's bricks: the ray's chord through the domain is cut into n = ceil(length / step)
// equal steps sampled at their midpoints; a leaf of level l samples every 2^(L-1-l)-th of
// them, each sample standing for the steps it covers, with the opacity corrected to that
// length (§5.3); with pre-integration, the value runs linearly between consecutive samples
// and each such segment is classified whole (reference_renderer.h). Shader variants are compiled from the enabled effects: with shading off no
// gradient code exists, with MIP no shading or opacity code.
//
// Ray-guided feedback (GigaVoxels, paper 000): with a LeafFeedbackCounts to fill, the pass
// counts per leaf record the rays that reached the leaf with length (before terminating) and
// the rays that wanted finer data there than the leaf holds.

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "octoray/gpu/brick_pool.h"
#include "octoray/gpu/camera.h"
#include "octoray/gpu/image.h"
#include "octoray/gpu/occlusion.h"
#include "octoray/gpu/reference/reference_renderer.h"
#include "octoray/gpu/spatial_index.h"
#include "octoray/gpu/working_set.h"
#include "octoray/transfer/transfer_function.h"
#include "octoray/volume/store_reader.h"

namespace octoray::gpu {

class GlProgram;

struct Enhancement {
  bool enabled = false;
  double kC = 0.0, kS = 1.0, kE = 1.0;
};

// The error bound --image-adaptive on stands for: the loosest bound of the sweep that stays
// within 1 dB of every pixel cast against the truth on the head and 512^3 phantom DVR views,
// with 27-31 % of the rays (docs/accuracy.md, image-plane adaptive sampling).
constexpr double kImageAdaptiveDefaultThreshold = 0.005;
// The viewer's interactive frames, replaced by full quality when the camera stops: fewer rays
// (25-27 %), 3-4 dB below every pixel cast.
constexpr double kImageAdaptiveInteractiveThreshold = 0.02;

struct RaycastOptions {
  RaycastMode mode = RaycastMode::Dvr;
  double stepMm = 0;               // 0: 0.25 x the smallest spacing (the reference's default)
  double earlyTermination = 0.99;  // in (0, 1]
  enum class Shading { FromTransferFunction, On, Off } shading = Shading::FromTransferFunction;
  bool gradientOpacity = true;     // the TF's gradient-opacity points, if it has any
  Enhancement boundary;            // alpha *= kC + kS |grad|^kE
  Enhancement silhouette;          // view-dependent transparency: alpha *= kC + kS (1 - |n.v|)^kE
  double isoValue = 0;
  // MIP: Exact, the maximum of the trilinear interpolant along the whole chord (the
  // reference's; equal to it at 16 bits); Sampled, its maximum over the step's samples only
  // (faster, never higher; what other raycasters show).
  enum class MipMethod { Exact, Sampled } mip = MipMethod::Exact;
  double lodPixels = 1.0;          // working-set refinement target; 0: finest level everywhere
  bool stats = false;              // per-pixel counters (a separate variant)
  // DVR: skip the samples of 8^3-voxel cells of a brick whose values all map to zero opacity;
  // exact MIP: cross the 8^3 groups of trilinear cells whose largest texel cannot raise the
  // maximum in one step (exact: the picture is bit for bit the same; off only to measure
  // what it saves).
  bool cellSkipping = true;
  // DVR: pre-integrated classification (paper 003 §5.3): each step is a segment from the
  // previous sample's value to this one's, classified through transfer::SegmentExtinctionTable
  // (one table for every level's step: it holds extinction per unit distance); removes the
  // wood-grain rings a sharp TF shows at coarse steps. Cell skipping is off in this variant.
  bool preintegration = false;
  // DVR: ray-start jitter, each sample at a per-pixel fraction reference::rayJitter(x, y) of
  // its step instead of the midpoint (deterministic); the cheap alternative to the above.
  bool jitter = false;
  // Adaptive sampling in the image plane (paper 002; raycast.frag.glsl documents the rule):
  // 0 = off (every pixel cast; exact); > 0 = the error bound (largest difference of any
  // premultiplied channel between the four coarse rays a pixel would be interpolated from).
  // imageAdaptiveLevels levels above the image (rays every 2^levels pixels at the top).
  double imageAdaptive = 0;
  int imageAdaptiveLevels = 2;
  // A clipping box in the volume's index space (voxel centres at integers, the domain is
  // [-0.5, dim - 0.5] per axis): rays are cut to the chord inside the box, whose steps are
  // then cut as the whole chord's are. The viewer's crop box.
  struct ClipBox {
    bool enabled = false;
    std::array<double, 3> lo{0, 0, 0}, hi{0, 0, 0};
  } clip;
};

// The options the raycaster shares with the CPU reference (mode, step, early termination,
// shading, gradient opacity, boundary enhancement, iso value, pre-integration, jitter), in
// each direction; the others keep their defaults (the reference has no silhouette, clip box,
// image-plane adaptivity or level of detail). Tests render both through these, and
// octoray-render parses the shared options once.
reference::RenderOptions referenceOptions(const RaycastOptions& options);
RaycastOptions raycastOptions(const reference::RenderOptions& options);

struct FrameStats {
  double drawMs = 0;         // the raycasting pass, GPU finished
  double selectMs = 0;       // working-set update and index build (CPU)
  double uploadMs = 0;       // texture uploads from the CPU cache (never disk reads)
  int64_t bricksUploaded = 0;
  int64_t workingSetBricks = 0;  // data leaves of the cut
  int64_t emptyNodes = 0;
  int64_t poolSlots = 0, poolSlotsUsed = 0;
  std::size_t poolBytes = 0, poolBytesUsed = 0;
  // With RaycastOptions::stats only:
  double samplesPerPixel = 0;       // classified samples (MIP: trilinear cells visited) per covered pixel
  double contributingPerPixel = 0;  // samples with non-zero opacity (iso: hits)
  double leavesPerPixel = 0;        // leaves visited with non-zero length, empty ones included
  int64_t bricksTouched = 0;        // data leaves any ray sampled
  int64_t pixelsCovered = 0;        // pixels whose ray meets the domain
  // Rays cast over all levels of the image pyramid (every pixel without image-adaptive
  // sampling), and the samples they took (with RaycastOptions::stats; else -1).
  int64_t raysCast = 0;
  int64_t samplesTaken = -1;
  // The working set's frame (GpuRenderer fills these).
  WorkingSetStats workingSet;
  double feedbackMs = 0;            // planning queries, reading the feedback back, applying it
  int64_t queriesIssued = 0, queryTiles = 0;  // occlusion feedback
  int64_t feedbackDelayFrames = 0;  // frames between a view and the feedback the cut used
  int64_t frameIndex = 0;
  // The CPU cache and the loader after the frame.
  uint64_t cacheBytes = 0, cacheBudgetBytes = 0, cacheEvictions = 0;  // evictions: this frame
  int64_t cacheBricks = 0;
  int64_t loaderQueued = 0, loaderLoading = 0;
  uint64_t loaderLoaded = 0;         // bricks loaded this frame (by the background threads)
  uint64_t bytesRead = 0;            // compressed store bytes those bricks came from
  uint64_t poolEvictions = 0;        // this frame
  std::vector<std::string> errors;   // bricks that failed to load (each named once)
};

struct Frame {
  Image image;                // rgba premultiplied; depth: mm of the first contribution
  std::vector<float> value;   // MIP: maximum (NaN: missed, or none that shows); iso: isovalue at hits
  std::vector<float> leafCounts, samples;  // per pixel, with RaycastOptions::stats
  FrameStats stats;
};

struct LeafFeedbackCounts {
  std::vector<uint32_t> rays;   // per leaf record of the index: rays that sampled the leaf
  std::vector<uint32_t> finer;  // rays that wanted finer data in it
};

// Drawing the pass tile by tile (scissored), with work after each tile (occlusion.h).
struct TiledPass {
  std::vector<ScreenTile> tiles;  // a partition of the window
  std::function<void(std::size_t tile)> afterTile;
};

// Throws octoray::Error for a bad camera, TF or option.
void validateRaycast(const Camera& camera, const transfer::TransferFunction& tf,
                     const RaycastOptions& options);

class Raycaster {
 public:
  Raycaster(const volume::StoreReader& store, const BrickPool& pool);
  ~Raycaster();
  Raycaster(const Raycaster&) = delete;
  Raycaster& operator=(const Raycaster&) = delete;

  // Draws `index` (whose slots refer to the pool). Throws octoray::Error for bad cameras or
  // options and GL errors. FrameStats' working-set fields are left to the caller.
  Frame draw(const Camera& camera, const transfer::TransferFunction& tf,
             const RaycastOptions& options, const SpatialIndex& index,
             LeafFeedbackCounts* feedback = nullptr, const TiledPass* tiles = nullptr);
  // The depth mapping of the last-sample depth buffer for `camera`.
  DepthRange depthRange(const Camera& camera) const;

  std::vector<std::string> variantDefines(const transfer::TransferFunction& tf,
                                          const RaycastOptions& options,
                                          Projection projection = Projection::Perspective) const;
  const std::string& variantSource(const transfer::TransferFunction& tf,
                                   const RaycastOptions& options,
                                   Projection projection = Projection::Perspective);
  unsigned variantProgram(const transfer::TransferFunction& tf, const RaycastOptions& options,
                          Projection projection = Projection::Perspective);
  double defaultStepMm() const;
  OctreeRay pixelRay(const Camera& camera, int x, int y) const;
  std::array<float, 3> domainMax(const Camera& camera) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace octoray::gpu
