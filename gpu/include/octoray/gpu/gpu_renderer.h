#pragma once
// The GPU raycaster (paper 003 §5): a brick pool in one 3D texture, the spatial index of the
// working set in shader storage buffers, and a full-screen fragment pass that walks it (see
// spatial_index.h for the traversal and gpu/shaders/raycast.frag.glsl for the shader).
//
// The renderer draws into its own framebuffer (colour RGBA32F premultiplied, an auxiliary
// RGBA32F target with the depth in mm of the first contribution and the MIP maximum or the
// isovalue, per-pixel counters when asked, and a 32-bit depth buffer holding the depth of the
// ray's last sample where it terminated, for the occlusion queries of the dynamic working
// set), so it runs the same in a GLFW window's context and headless (gl_context.h). Every call
// needs the renderer's GL context current on the calling thread.
//
// Optical model: the CPU reference's (reference_renderer.h), in single precision on the
// working set's bricks: the ray's chord through the domain is cut into n = ceil(length / step)
// equal steps sampled at their midpoints; a leaf of level l samples every 2^(L-1-l)-th of
// them, each sample standing for the steps it covers, with the opacity corrected to that
// length (§5.3). Shader variants are compiled from the enabled effects: with shading off no
// gradient code exists, with MIP no shading or opacity code.

#include <cstddef>
#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <unordered_map>
#include <vector>

#include "octoray/gpu/camera.h"
#include "octoray/gpu/image.h"
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
  // DVR: skip the samples of 8^3-voxel cells of a brick whose values all map to zero opacity
  // (exact: the picture is bit for bit the same; off only to measure what it saves).
  bool cellSkipping = true;
};

struct RendererConfig {
  std::size_t poolBytes = std::size_t{1} << 30;  // brick pool budget (values)
  bool gradientPool = false;  // also keep the store's RGBA8 gradients (needs a store built
                              // with --gradients) and shade from them
};

struct FrameStats {
  double drawMs = 0;         // the raycasting pass, GPU finished
  double selectMs = 0;       // working-set selection and index build (CPU)
  double uploadMs = 0;       // brick reads and texture uploads
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
};

struct Frame {
  Image image;                // rgba premultiplied; depth: mm of the first contribution
  std::vector<float> value;   // MIP: maximum per pixel (NaN: missed); iso: isovalue at hits
  std::vector<float> leafCounts, samples;  // per pixel, with RaycastOptions::stats
  FrameStats stats;
};

class GpuRenderer {
 public:
  // Allocates the pool (capacity = poolBytes / brick bytes, at least one slot) and compiles
  // nothing yet. Throws octoray::Error when the GL context lacks what is needed.
  GpuRenderer(const volume::StoreReader& store, const RendererConfig& config = {});
  ~GpuRenderer();
  GpuRenderer(const GpuRenderer&) = delete;
  GpuRenderer& operator=(const GpuRenderer&) = delete;

  // Selects the working set for this view, uploads missing bricks (evicting the least
  // recently used unused ones), rebuilds the index and draws. Throws octoray::Error for bad
  // cameras or options, store read failures, and GL errors.
  Frame render(const Camera& camera, const transfer::TransferFunction& tf,
               const RaycastOptions& options);

  // The defines of the variant `options` with `tf` compile to (for tests and reports).
  std::vector<std::string> variantDefines(const transfer::TransferFunction& tf,
                                          const RaycastOptions& options,
                                          Projection projection = Projection::Perspective) const;
  // The fragment source of that variant, defines applied (compiles it if needed).
  const std::string& variantSource(const transfer::TransferFunction& tf,
                                   const RaycastOptions& options,
                                   Projection projection = Projection::Perspective);
  // The GL program of that variant (compiles it if needed): tests ask GL which uniforms the
  // compiled variant still uses, i.e. which code survived the preprocessor and the compiler.
  unsigned variantProgram(const transfer::TransferFunction& tf, const RaycastOptions& options,
                          Projection projection = Projection::Perspective);

  int64_t poolSlots() const;
  double defaultStepMm() const;

  // For the traversal mirror test: the spatial index of the last frame, and the octree-space
  // ray and domain of pixel (x, y) (row 0 at the top) as the shader computes them in single
  // precision (its normalize and matrix product may round differently in the last bit).
  const SpatialIndex& lastIndex() const;
  OctreeRay pixelRay(const Camera& camera, int x, int y) const;
  std::array<float, 3> domainMax(const Camera& camera) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace octoray::gpu
