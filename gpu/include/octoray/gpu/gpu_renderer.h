#pragma once
// The GPU renderer: what a viewer or a tool holds to draw one store frame after frame. It
// wires the out-of-core pipeline of paper 003 together, in data-flow order:
//
//   BrickLoader (background threads: read, verify, decompress)  -> BrickCache (CPU, LRU)
//   WorkingSet (per frame: cover, merge, refine, request)       -> BrickPool (GPU slots)
//   SpatialIndex::build(cut)                                    -> Raycaster::draw
//   ray feedback (which leaves rays reached / wanted finer)     -> WorkingSet, next frame
//
// renderFrame() is one interactive frame: it never waits for the disk; what is missing is
// drawn from coarser resident data and arrives over the next frames. render() repeats frames,
// waiting for the loader between them, until the working set wants nothing more (a still
// camera's converged picture; what single-image tools and tests use).

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "octoray/gpu/raycaster.h"

namespace octoray::gpu {

struct RendererConfig {
  std::size_t poolBytes = std::size_t{1} << 30;   // GPU brick pool budget
  bool gradientPool = false;  // also keep the store's RGBA8 gradients (needs a store built
                              // with --gradients) and shade from them
  std::size_t cacheBytes = std::size_t{2} << 30;  // CPU brick cache budget
  std::size_t uploadBytesPerFrame = std::size_t{64} << 20;  // renderFrame(); 0: unlimited
  // Feedback that prunes the working set. Off by default for the library (a single converged
  // image looks the same either way); camera paths and the viewer turn it on.
  Visibility visibility = Visibility::None;
  int visibilityThreshold = 4;  // pixels (rays) a leaf needs to count as seen
  int loaderThreads = 2;
  // When the working set settles, put the cut's bricks in the pool's first slots in node
  // order (WorkingSet::repack): a converged view then gives the same pixels whatever the
  // history (the viewer, for screenshots a reloaded session reproduces). One copy of the
  // cut from the CPU cache per settled cut.
  bool repackWhenSettled = false;
};

class GpuRenderer {
 public:
  // Allocates the pool, starts the loader and reads the root brick. Throws octoray::Error when
  // the GL context lacks what is needed or the root cannot be read.
  GpuRenderer(const volume::StoreReader& store, const RendererConfig& config = {});
  ~GpuRenderer();
  GpuRenderer(const GpuRenderer&) = delete;
  GpuRenderer& operator=(const GpuRenderer&) = delete;

  // One frame of the interactive loop (see above). Load errors are reported in
  // Frame::stats.errors, never thrown; bad cameras or options and GL errors throw.
  Frame renderFrame(const Camera& camera, const transfer::TransferFunction& tf,
                    const RaycastOptions& options);
  // The converged picture for a still camera; throws octoray::Error naming the store and the
  // brick when a brick the view needs cannot be read.
  Frame render(const Camera& camera, const transfer::TransferFunction& tf,
               const RaycastOptions& options);

  std::vector<std::string> variantDefines(const transfer::TransferFunction& tf,
                                          const RaycastOptions& options,
                                          Projection projection = Projection::Perspective) const;
  const std::string& variantSource(const transfer::TransferFunction& tf,
                                   const RaycastOptions& options,
                                   Projection projection = Projection::Perspective);
  unsigned variantProgram(const transfer::TransferFunction& tf, const RaycastOptions& options,
                          Projection projection = Projection::Perspective);

  int64_t poolSlots() const;
  double defaultStepMm() const;
  const RendererConfig& config() const;
  // Changes the upload budget, visibility and threshold (the pool and cache keep their size).
  void setStreaming(std::size_t uploadBytesPerFrame, Visibility visibility, int threshold);

  // For the traversal mirror test: the spatial index of the last frame, and the octree-space
  // ray and domain of pixel (x, y) (row 0 at the top) as the shader computes them in single
  // precision (its normalize and matrix product may round differently in the last bit).
  const SpatialIndex& lastIndex() const;
  OctreeRay pixelRay(const Camera& camera, int x, int y) const;
  std::array<float, 3> domainMax(const Camera& camera) const;

  // The parts, for tests and the viewer's status bar.
  const WorkingSet& workingSet() const;
  const BrickPool& pool() const;
  const volume::BrickCache& cache() const;
  // The CPU cache, for readers that share it (the viewer's MPR slicer; it is thread-safe).
  volume::BrickCache& sharedCache();
  const volume::BrickLoader& loader() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace octoray::gpu
