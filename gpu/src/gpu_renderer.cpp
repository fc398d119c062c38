#include "octoray/gpu/gpu_renderer.h"

#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <optional>

#include "octoray/core/elapsed.h"
#include "octoray/core/error.h"

namespace octoray::gpu {
namespace {

WorkingSetConfig workingSetConfig(const RendererConfig& c) {
  WorkingSetConfig w;
  w.uploadBytesPerFrame = c.uploadBytesPerFrame;
  w.visibility = c.visibility;
  return w;
}

WorkingSetOptions workingSetOptions(const RaycastOptions& o) {
  WorkingSetOptions w;
  w.mode = o.mode;
  w.lodPixels = o.lodPixels;
  w.isoValue = o.isoValue;
  return w;
}

volume::BrickLoaderOptions loaderOptions(const RendererConfig& c) {
  volume::BrickLoaderOptions o;
  o.threads = std::max(1, c.loaderThreads);
  return o;
}

}  // namespace

struct GpuRenderer::Impl {
  const volume::StoreReader& store;
  RendererConfig config;
  // Declaration order is destruction order reversed: the loader stops before the cache goes.
  volume::BrickCache cache;
  BrickPool pool;
  volume::BrickLoader loader;
  WorkingSet workingSet;
  Raycaster raycaster;
  std::optional<OcclusionQueries> occlusion;  // made on first use
  SpatialIndex index;
  int64_t frames = 0;

  Impl(const volume::StoreReader& s, const RendererConfig& c)
      : store(s),
        config(c),
        cache(c.cacheBytes),
        pool(s, c.poolBytes, c.gradientPool),
        loader(s, cache, loaderOptions(c)),
        workingSet(s, pool, cache, loader, workingSetConfig(c)),
        raycaster(s, pool) {
    if (c.visibilityThreshold < 1) {
      throw Error("", fmt::format("visibility threshold {} must be at least 1 pixel", c.visibilityThreshold));
    }
  }
};

GpuRenderer::GpuRenderer(const volume::StoreReader& store, const RendererConfig& config)
    : impl_(std::make_unique<Impl>(store, config)) {}

GpuRenderer::~GpuRenderer() = default;

Frame GpuRenderer::renderFrame(const Camera& camera, const transfer::TransferFunction& tf,
                               const RaycastOptions& options) {
  Impl& im = *impl_;
  validateRaycast(camera, tf, options);
  const uint64_t cacheEvictions = im.cache.stats().evictions;
  const uint64_t poolEvictions = im.pool.stats().evictions;

  const WorkingSetOptions wso = workingSetOptions(options);
  const std::vector<CutLeaf>& cut = im.workingSet.update(camera, tf, wso);
  if (im.config.repackWhenSettled && im.workingSet.settled()) im.workingSet.repack();
  const auto indexStart = std::chrono::steady_clock::now();
  im.index = SpatialIndex::build(im.store.layout(), cut);
  const double indexMs = millisecondsSince(indexStart);

  const Visibility visibility = im.config.visibility;
  const bool rays = visibility == Visibility::Rays || visibility == Visibility::Both;
  const bool occlusion = visibility == Visibility::Occlusion || visibility == Visibility::Both;
  LeafFeedbackCounts counts;
  // Occlusion queries: the cut's leaf boxes, tiles planned from their projections.
  double queryMs = 0;
  std::optional<TiledPass> tiled;
  if (occlusion) {
    const auto start = std::chrono::steady_clock::now();
    if (!im.occlusion) im.occlusion.emplace();
    std::vector<std::array<Vec3, 8>> boxes;
    boxes.reserve(cut.size());
    const Mat4 patientFromIndex = im.store.patientFromIndex();
    for (const CutLeaf& leaf : cut) boxes.push_back(nodeBoxCorners(im.store.layout(), patientFromIndex, leaf.key));
    tiled.emplace();
    tiled->tiles = im.occlusion->plan(camera, im.raycaster.depthRange(camera), boxes);
    tiled->afterTile = [&im](std::size_t tile) { im.occlusion->issue(tile); };
    queryMs += millisecondsSince(start);
  }
  Frame frame = im.raycaster.draw(camera, tf, options, im.index, rays ? &counts : nullptr,
                                  tiled ? &*tiled : nullptr);
  FrameStats& stats = frame.stats;
  if (visibility != Visibility::None) {
    const auto start = std::chrono::steady_clock::now();
    const auto threshold = static_cast<uint32_t>(im.config.visibilityThreshold);
    const std::vector<int64_t>& cutNodes = im.workingSet.cutNodes();
    std::vector<WorkingSet::LeafFeedback> leaves(cutNodes.size());
    for (std::size_t c = 0; c < cutNodes.size(); ++c) {
      leaves[c].node = cutNodes[c];
      leaves[c].seen = true;
      leaves[c].wantsFiner = true;
    }
    if (rays) {
      std::vector<bool> reached(cutNodes.size(), false);
      for (std::size_t r = 0; r < counts.rays.size(); ++r) {
        const int32_t c = im.index.cutIndex[r];
        if (c < 0) continue;
        reached[static_cast<std::size_t>(c)] = counts.rays[r] >= threshold;
        leaves[static_cast<std::size_t>(c)].wantsFiner = counts.finer[r] >= threshold;
      }
      for (std::size_t c = 0; c < cutNodes.size(); ++c) leaves[c].seen = reached[c];
    }
    if (occlusion) {
      const std::vector<uint32_t> samples = im.occlusion->results();
      for (std::size_t c = 0; c < cutNodes.size(); ++c) {
        leaves[c].seen = leaves[c].seen && samples[c] >= threshold;
      }
      stats.queriesIssued = static_cast<int64_t>(cutNodes.size());
      stats.queryTiles = static_cast<int64_t>(tiled->tiles.size());
    }
    im.workingSet.applyFeedback(leaves);
    stats.feedbackMs = millisecondsSince(start) + queryMs;
    stats.feedbackDelayFrames = 1;  // read back after the draw, used by the next update
  }

  const WorkingSetStats& ws = im.workingSet.stats();
  stats.workingSet = ws;
  stats.workingSetBricks = ws.bricks;
  stats.poolBytesUsed = static_cast<std::size_t>(ws.bricks) * im.pool.stats().slotBytes;
  stats.frameIndex = im.frames++;
  stats.selectMs = ws.selectMs + indexMs;
  stats.uploadMs = ws.uploadMs;
  stats.bricksUploaded = ws.uploaded;
  stats.emptyNodes = ws.emptyNodes;
  const volume::BrickCacheStats cs = im.cache.stats();
  stats.cacheBytes = cs.bytes;
  stats.cacheBudgetBytes = cs.budgetBytes;
  stats.cacheBricks = static_cast<int64_t>(cs.count);
  stats.cacheEvictions = cs.evictions - cacheEvictions;
  const volume::BrickLoaderStats ls = im.loader.stats();
  stats.loaderQueued = static_cast<int64_t>(ls.queued);
  stats.loaderLoading = static_cast<int64_t>(ls.loading);
  stats.loaderLoaded = static_cast<uint64_t>(ws.loaded);
  stats.bytesRead = ws.bytesRead;
  stats.poolEvictions = im.pool.stats().evictions - poolEvictions;
  for (const volume::LoadError& e : im.workingSet.takeErrors()) stats.errors.push_back(e.message);
  return frame;
}

Frame GpuRenderer::render(const Camera& camera, const transfer::TransferFunction& tf,
                          const RaycastOptions& options) {
  Impl& im = *impl_;
  validateRaycast(camera, tf, options);
  // A still camera: no upload budget, and the loader is waited for between frames.
  WorkingSetConfig wsc = im.workingSet.config();
  const WorkingSetConfig saved = wsc;
  wsc.uploadBytesPerFrame = 0;
  im.workingSet.setConfig(wsc);
  struct Restore {
    WorkingSet& ws;
    WorkingSetConfig config;
    ~Restore() { ws.setConfig(config); }
  } restore{im.workingSet, saved};

  const int maxFrames = 8 * im.store.layout().levels() + 16;
  std::vector<std::string> errors;
  Frame frame;
  double uploadMs = 0, selectMs = 0;
  int64_t uploaded = 0;
  if (im.config.visibility == Visibility::None) {
    // Without feedback nothing needs a picture to decide: update until settled, draw once.
    const WorkingSetOptions wso = workingSetOptions(options);
    for (int i = 0; i < maxFrames; ++i) {
      im.workingSet.update(camera, tf, wso);
      for (const volume::LoadError& e : im.workingSet.takeErrors()) errors.push_back(e.message);
      uploadMs += im.workingSet.stats().uploadMs;
      selectMs += im.workingSet.stats().selectMs;
      uploaded += im.workingSet.stats().uploaded;
      if (im.workingSet.settled()) break;
      im.loader.waitIdle();
    }
  }
  for (int i = 0; i < maxFrames; ++i) {
    frame = renderFrame(camera, tf, options);
    errors.insert(errors.end(), frame.stats.errors.begin(), frame.stats.errors.end());
    uploadMs += frame.stats.uploadMs;
    selectMs += frame.stats.selectMs;
    uploaded += frame.stats.bricksUploaded;
    if (im.workingSet.settled()) break;
    if (im.workingSet.stats().waitingForData > 0 || im.workingSet.stats().requestsQueued > 0) {
      im.loader.waitIdle();
    }
  }
  if (!errors.empty()) throw Error("", errors.front());
  frame.stats.uploadMs = uploadMs;
  frame.stats.selectMs = selectMs;
  frame.stats.bricksUploaded = uploaded;
  frame.stats.errors = std::move(errors);
  return frame;
}

std::vector<std::string> GpuRenderer::variantDefines(const transfer::TransferFunction& tf,
                                                     const RaycastOptions& options,
                                                     Projection projection) const {
  return impl_->raycaster.variantDefines(tf, options, projection);
}

const std::string& GpuRenderer::variantSource(const transfer::TransferFunction& tf,
                                              const RaycastOptions& options,
                                              Projection projection) {
  return impl_->raycaster.variantSource(tf, options, projection);
}

unsigned GpuRenderer::variantProgram(const transfer::TransferFunction& tf,
                                     const RaycastOptions& options, Projection projection) {
  return impl_->raycaster.variantProgram(tf, options, projection);
}

int64_t GpuRenderer::poolSlots() const { return impl_->pool.stats().slots; }
double GpuRenderer::defaultStepMm() const { return impl_->raycaster.defaultStepMm(); }
const RendererConfig& GpuRenderer::config() const { return impl_->config; }

void GpuRenderer::setStreaming(std::size_t uploadBytesPerFrame, Visibility visibility, int threshold) {
  if (threshold < 1) throw Error("", fmt::format("visibility threshold {} must be at least 1 pixel", threshold));
  impl_->config.uploadBytesPerFrame = uploadBytesPerFrame;
  impl_->config.visibility = visibility;
  impl_->config.visibilityThreshold = threshold;
  impl_->workingSet.setConfig(workingSetConfig(impl_->config));
}

const SpatialIndex& GpuRenderer::lastIndex() const { return impl_->index; }
OctreeRay GpuRenderer::pixelRay(const Camera& camera, int x, int y) const {
  return impl_->raycaster.pixelRay(camera, x, y);
}
std::array<float, 3> GpuRenderer::domainMax(const Camera& camera) const {
  return impl_->raycaster.domainMax(camera);
}
const WorkingSet& GpuRenderer::workingSet() const { return impl_->workingSet; }
const BrickPool& GpuRenderer::pool() const { return impl_->pool; }
const volume::BrickCache& GpuRenderer::cache() const { return impl_->cache; }
volume::BrickCache& GpuRenderer::sharedCache() { return impl_->cache; }
const volume::BrickLoader& GpuRenderer::loader() const { return impl_->loader; }

}  // namespace octoray::gpu
