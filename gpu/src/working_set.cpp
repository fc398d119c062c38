#include "octoray/gpu/working_set.h"

#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <optional>
#include <queue>
#include <stdexcept>

#include "octoray/core/elapsed.h"
#include "octoray/core/error.h"
#include "octoray/transfer/opacity_table.h"

namespace octoray::gpu {
namespace {

// What the emptiness test needs of the TF and the store's value mapping.
class EmptinessTest {
 public:
  EmptinessTest(const volume::StoreReader& store, const transfer::TransferFunction& tf,
                const WorkingSetOptions& options)
      : store_(store), options_(options) {
    if (options.mode == RaycastMode::Dvr) {
      const volume::StoreHeader& h = store.header();
      if (store.sampleFormat() == volume::SampleFormat::UInt16) {
        table_.emplace(tf, h.valueOffset, h.valueScale);
      } else {
        const volume::NodeRecord& root = store.node(0);
        const double lo = root.minValue, hi = root.maxValue > root.minValue ? root.maxValue
                                                                             : root.minValue + 1;
        table_.emplace(transfer::OpacitySummedAreaTable::overRange(tf, lo, hi, 65536));
      }
    } else if (options.mode == RaycastMode::Mip) {
      mipThreshold_ = mipVisibleFrom(tf);
    }
  }

  bool empty(const volume::NodeRecord& node) const {
    const double lo = node.minValue, hi = node.maxValue;
    switch (options_.mode) {
      case RaycastMode::Iso:
        return !(options_.isoValue >= lo && options_.isoValue <= hi);
      case RaycastMode::Mip:
        return hi < mipThreshold_;
      case RaycastMode::Dvr:
        break;
    }
    if (store_.sampleFormat() == volume::SampleFormat::UInt16) {
      const volume::StoreHeader& h = store_.header();
      // Stored samples s with physical = offset + scale * s; the node's range in stored units,
      // widened by one so rounding can only make the test more conservative.
      double s0 = (lo - h.valueOffset) / h.valueScale, s1 = (hi - h.valueOffset) / h.valueScale;
      if (s0 > s1) std::swap(s0, s1);
      const auto clampStored = [](double s) {
        return static_cast<std::uint16_t>(std::clamp(s, 0.0, 65535.0));
      };
      return table_->transparent(clampStored(std::floor(s0) - 1), clampStored(std::ceil(s1) + 1));
    }
    return table_->transparentValues(lo, hi);
  }

 private:
  const volume::StoreReader& store_;
  WorkingSetOptions options_;
  std::optional<transfer::OpacitySummedAreaTable> table_;
  double mipThreshold_ = 0;
};


class Projector {
 public:
  Projector(const volume::StoreReader& store, const Camera& camera)
      : layout_(store.layout()), m_(store.patientFromIndex()), camera_(camera) {
    const Vec3 forward = normalize(camera.target - camera.eye);
    right_ = normalize(cross(forward, camera.up));
    up_ = cross(right_, forward);
    forward_ = forward;
    for (int a = 0; a < 3; ++a) voxelMm_ = std::max(voxelMm_, length(m_.column(a)));
    const double aspect = static_cast<double>(camera.width) / camera.height;
    if (camera.projection == Projection::Perspective) {
      tanY_ = camera.tanHalfFovY();
      tanX_ = tanY_ * aspect;
    } else {
      halfY_ = 0.5 * camera.orthoHeightMm;
      halfX_ = halfY_ * aspect;
    }
  }

  std::array<Vec3, 8> corners(int64_t id) const { return nodeBoxCorners(layout_, m_, layout_.nodeKey(id)); }

  // Projected size in pixels of one voxel of the node's level, at the node's nearest point.
  double projectedPixels(int64_t id) const {
    const volume::NodeKey key = layout_.nodeKey(id);
    const double voxelMm = voxelMm_ * static_cast<double>(layout_.levelScale(key.level));
    if (camera_.projection == Projection::Orthographic) {
      return voxelMm * camera_.height / camera_.orthoHeightMm;
    }
    const std::array<Vec3, 8> c = corners(id);
    Vec3 centre{0, 0, 0};
    for (const Vec3& p : c) centre = centre + 0.125 * p;
    double radius = 0;
    for (const Vec3& p : c) radius = std::max(radius, length(p - centre));
    const double distance = dot(centre - camera_.eye, forward_) - radius;
    if (!(distance > 1e-9)) return std::numeric_limits<double>::infinity();
    return voxelMm * camera_.height / (2.0 * distance * tanY_);
  }

  // False only when the node's box lies wholly outside one plane of the view frustum.
  bool visible(int64_t id) const {
    const std::array<Vec3, 8> c = corners(id);
    std::array<int, 5> outside{};  // behind, left, right, below, above
    for (const Vec3& p : c) {
      const Vec3 v = p - camera_.eye;
      const double z = dot(v, forward_), x = dot(v, right_), y = dot(v, up_);
      if (camera_.projection == Projection::Perspective) {
        outside[0] += z <= 0;
        outside[1] += x < -tanX_ * z;
        outside[2] += x > tanX_ * z;
        outside[3] += y < -tanY_ * z;
        outside[4] += y > tanY_ * z;
      } else {
        outside[1] += x < -halfX_;
        outside[2] += x > halfX_;
        outside[3] += y < -halfY_;
        outside[4] += y > halfY_;
      }
    }
    return std::none_of(outside.begin(), outside.end(), [](int n) { return n == 8; });
  }

 private:
  const volume::OctreeLayout& layout_;
  Mat4 m_;
  const Camera& camera_;
  Vec3 forward_, right_, up_;
  double voxelMm_ = 0;
  double tanX_ = 0, tanY_ = 0, halfX_ = 0, halfY_ = 0;
};

}  // namespace

double mipVisibleFrom(const transfer::TransferFunction& tf) {
  if (tf.opacity.empty() || tf.opacity.front().alpha > 0) {
    return -std::numeric_limits<double>::infinity();
  }
  for (std::size_t i = 0; i < tf.opacity.size(); ++i) {
    // Opacity rises from the previous point's value on.
    if (tf.opacity[i].alpha > 0) return i > 0 ? tf.opacity[i - 1].value : tf.opacity[i].value;
  }
  return std::numeric_limits<double>::infinity();
}

std::array<Vec3, 8> nodeBoxCorners(const volume::OctreeLayout& layout, const Mat4& patientFromIndex,
                                   const volume::NodeKey& key) {
  const int64_t cells = static_cast<int64_t>(layout.brickSize()) * layout.levelScale(key.level);
  const volume::Index3& dims = layout.levelDims(layout.leafLevel());
  std::array<double, 3> lo{}, hi{};
  for (int a = 0; a < 3; ++a) {
    lo[a] = static_cast<double>(key.brick[a] * cells) - 0.5;
    hi[a] = static_cast<double>(std::min((key.brick[a] + 1) * cells, dims[a])) - 0.5;
  }
  std::array<Vec3, 8> out;
  for (int c = 0; c < 8; ++c) {
    out[static_cast<std::size_t>(c)] = patientFromIndex.transformPoint(
        {(c & 1) ? hi[0] : lo[0], (c & 2) ? hi[1] : lo[1], (c & 4) ? hi[2] : lo[2]});
  }
  return out;
}

std::vector<volume::NodeKey> nodesInFrustum(const volume::StoreReader& store, const Camera& camera,
                                            int level) {
  const volume::OctreeLayout& layout = store.layout();
  if (level < 0 || level > layout.leafLevel()) {
    throw Error(store.path(), fmt::format("level {} is not a level of the store (0..{})", level,
                                          layout.leafLevel()));
  }
  const Projector projector(store, camera);
  std::vector<volume::NodeKey> nodes;
  std::vector<int64_t> stack{0};
  while (!stack.empty()) {
    const int64_t id = stack.back();
    stack.pop_back();
    if (!projector.visible(id)) continue;
    const volume::NodeKey key = layout.nodeKey(id);
    if (key.level == level) {
      nodes.push_back(key);
      continue;
    }
    const std::vector<int64_t> children = layout.children(id);
    stack.insert(stack.end(), children.rbegin(), children.rend());
  }
  std::sort(nodes.begin(), nodes.end(), [&layout](const volume::NodeKey& a, const volume::NodeKey& b) {
    return layout.nodeId(a) < layout.nodeId(b);
  });
  return nodes;
}

Visibility parseVisibility(const std::string& name) {
  if (name == "none") return Visibility::None;
  if (name == "occlusion") return Visibility::Occlusion;
  if (name == "rays") return Visibility::Rays;
  if (name == "both") return Visibility::Both;
  throw Error("", fmt::format("visibility \"{}\": expected occlusion, rays, both or none", name));
}

const char* visibilityName(Visibility v) {
  switch (v) {
    case Visibility::None: return "none";
    case Visibility::Occlusion: return "occlusion";
    case Visibility::Rays: return "rays";
    case Visibility::Both: return "both";
  }
  return "?";
}

struct WorkingSet::FrameContext {
  Camera camera;
  WorkingSetOptions options;
  EmptinessTest emptiness;
  Projector projector;
  FrameContext(const volume::StoreReader& store, const Camera& c,
               const transfer::TransferFunction& tf, const WorkingSetOptions& o)
      : camera(c), options(o), emptiness(store, tf, o), projector(store, camera) {}
};

WorkingSet::WorkingSet(const volume::StoreReader& store, BrickPool& pool, volume::BrickCache& cache,
                       volume::BrickLoader& loader, WorkingSetConfig config)
    : store_(store), pool_(pool), cache_(cache), loader_(loader), config_(config),
      layout_(store.layout()) {
  // The root stands in for everything not yet loaded: read it now, keep it for good.
  root_ = std::make_shared<const volume::Brick>(store.readBrick(0));
  cache_.insert(root_);
  pool_.beginFrame();
  if (!upload(*root_)) throw Error(store.path(), "the GPU pool has no slot for the root brick");
}

bool WorkingSet::repack() {
  // The cut's data nodes (a leaf's own or the ancestor's it is drawn from) and the root.
  std::vector<int64_t> data{0};
  std::vector<int64_t> dataOfLeaf(cut_.size());
  for (std::size_t i = 0; i < cut_.size(); ++i) {
    dataOfLeaf[i] = pool_.nodeIn(cut_[i].slot);
    data.push_back(dataOfLeaf[i]);
  }
  std::sort(data.begin(), data.end());
  data.erase(std::unique(data.begin(), data.end()), data.end());
  bool inOrder = pool_.stats().slotsUsed == static_cast<int64_t>(data.size());
  for (std::size_t k = 0; inOrder && k < data.size(); ++k) inOrder = pool_.slotOf(data[k]) == static_cast<int64_t>(k);
  if (inOrder) return true;
  std::vector<std::shared_ptr<const volume::Brick>> bricks;
  bricks.reserve(data.size());
  for (int64_t id : data) {
    bricks.push_back(id == 0 ? root_ : cache_.find(id));
    if (!bricks.back()) return false;
  }
  const auto start = std::chrono::steady_clock::now();
  pool_.clear();  // an empty pool hands out slots 0, 1, 2, ... in turn
  for (const auto& brick : bricks) {
    if (!upload(*brick)) throw std::logic_error("working set: an emptied pool refused a brick");
  }
  for (std::size_t i = 0; i < cut_.size(); ++i) cut_[i].slot = static_cast<uint32_t>(pool_.slotOf(dataOfLeaf[i]));
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  stats_.uploadMs += ms;
  stats_.repackMs += ms;
  stats_.repacked += static_cast<int64_t>(bricks.size());
  return true;
}

bool WorkingSet::upload(const volume::Brick& brick) {
  const BrickPool::Placement p = pool_.upload(brick);
  if (p.slot < 0) return false;
  ++stats_.uploaded;
  stats_.uploadBytes += pool_.stats().slotBytes;
  return true;
}

std::pair<int64_t, int> WorkingSet::nearestResidentAncestor(int64_t id) const {
  int up = 0;
  for (int64_t n = id; n >= 0; n = layout_.parent(n), ++up) {
    if (pool_.resident(n)) return {n, up};
  }
  throw std::logic_error("working set: the root brick left the pool");
}

std::pair<int64_t, int> WorkingSet::drawnFrom(int64_t id, bool unseen) const {
  if (!unseen) return nearestResidentAncestor(id);
  // What no ray sees may be drawn from anything that covers it: the root, which is always
  // resident and drawn anyway, so an unseen leaf costs no brick of its own.
  return {0, layout_.nodeKey(id).level};
}

bool WorkingSet::hiddenNow(int64_t id) const {
  if (config_.visibility == Visibility::None || lastFeedbackFrame_ == 0) return false;
  const auto it = state_.find(id);
  if (it == state_.end() || it->second.feedbackFrame != lastFeedbackFrame_) return false;
  return it->second.seenFrame + static_cast<uint64_t>(std::max(1, config_.mergeAfterFrames)) <=
         lastFeedbackFrame_;
}

bool WorkingSet::wantsSplitIgnoringFeedback(int64_t id, double pixels, bool inFrustum) const {
  if (layout_.nodeKey(id).level >= layout_.leafLevel()) return false;
  const double lod = context_->options.lodPixels;
  if (lod > 0 && pixels <= lod) return false;
  return inFrustum;
}

uint64_t WorkingSet::viewDigest(const Camera& c, const transfer::TransferFunction& tf,
                                const WorkingSetOptions& o) {
  uint64_t h = 1469598103934665603ull;  // FNV-1a over the bytes of the fields
  const auto mix = [&](const void* data, std::size_t size) {
    const auto* bytes = static_cast<const unsigned char*>(data);
    for (std::size_t i = 0; i < size; ++i) h = (h ^ bytes[i]) * 1099511628211ull;
  };
  const double camera[] = {c.eye.x, c.eye.y, c.eye.z, c.target.x, c.target.y, c.target.z,
                           c.up.x, c.up.y, c.up.z, c.fovYDegrees, c.orthoHeightMm,
                           static_cast<double>(c.width), static_cast<double>(c.height),
                           static_cast<double>(c.projection == Projection::Perspective),
                           static_cast<double>(o.mode), o.isoValue, o.lodPixels, tf.unitDistanceMm};
  mix(camera, sizeof(camera));
  for (const transfer::OpacityPoint& p : tf.opacity) {
    mix(&p.value, sizeof(p.value));
    mix(&p.alpha, sizeof(p.alpha));
  }
  return h;
}

bool WorkingSet::wantsSplit(int64_t id, double pixels, bool inFrustum) const {
  if (!wantsSplitIgnoringFeedback(id, pixels, inFrustum)) return false;
  if (config_.visibility == Visibility::None) return true;
  const auto it = state_.find(id);
  if (it == state_.end() || lastFeedbackFrame_ == 0) return false;  // never seen: wait for feedback
  const NodeState& s = it->second;
  if (innerNodes_.count(id)) {
    // Split last frame: stays split until none of its leaves was seen for mergeAfterFrames.
    return s.seenFrame > 0 &&
           s.seenFrame + static_cast<uint64_t>(std::max(1, config_.mergeAfterFrames)) > lastFeedbackFrame_;
  }
  if (s.feedbackFrame != lastFeedbackFrame_ || s.seenFrame != lastFeedbackFrame_) return false;
  if (s.hiddenMergeFrame > viewChangedFrame_) return false;  // merged back for this very view
  if (config_.visibility == Visibility::Rays || config_.visibility == Visibility::Both) {
    return s.finerFrame == lastFeedbackFrame_;
  }
  return true;
}

const std::vector<CutLeaf>& WorkingSet::update(const Camera& camera,
                                               const transfer::TransferFunction& tf,
                                               const WorkingSetOptions& options) {
  if (!(options.lodPixels >= 0 && std::isfinite(options.lodPixels))) {
    throw Error("", fmt::format("--lod-pixels {} must be 0 or positive", options.lodPixels));
  }
  camera.validate();
  const auto start = std::chrono::steady_clock::now();
  ++frame_;
  stats_ = {};
  pool_.beginFrame();
  pool_.pin(0);
  FrameContext context(store_, camera, tf, options);
  if (const uint64_t digest = viewDigest(camera, tf, options); digest != viewDigest_) {
    viewDigest_ = digest;
    viewChangedFrame_ = frame_;
  }
  staleFeedback_ = config_.visibility != Visibility::None && lastFeedbackFrame_ < viewChangedFrame_;
  context_ = &context;

  // What the loader finished and what failed since the last frame.
  const std::vector<int64_t> loaded = loader_.poll();
  stats_.loaded = static_cast<int64_t>(loaded.size());
  for (int64_t id : loaded) {
    const volume::NodeRecord& n = store_.node(id);
    stats_.bytesRead += uint64_t{n.payloadBytes} + n.gradientBytes;
  }
  for (volume::LoadError& e : loader_.takeErrors()) {
    if (failed_.insert(e.id).second) errors_.push_back(std::move(e));
  }

  std::unordered_map<int64_t, float> requests;
  const auto request = [&](int64_t id, double priority) {
    if (failed_.count(id) || cache_.contains(id)) return;
    const auto p = static_cast<float>(std::isfinite(priority) ? priority : 1e30);
    auto [it, inserted] = requests.emplace(id, p);
    if (!inserted) it->second = std::max(it->second, p);
  };

  // 1. Cover with resident bricks only.
  struct Candidate {
    double priority;
    int64_t id;
    bool operator<(const Candidate& o) const { return priority < o.priority; }
  };
  std::vector<int64_t> leaves;
  std::vector<Candidate> refine;
  std::vector<std::pair<int, int64_t>> merges;  // level, id
  std::unordered_set<int64_t> inner;
  int64_t hiddenMerges = 0;
  std::unordered_set<int64_t> hiddenProxies;  // resident leaves drawn from an ancestor
  const auto cover = [&] {
    leaves.clear();
    refine.clear();
    merges.clear();
    inner.clear();
    hiddenProxies.clear();
    stats_.emptyNodes = 0;
    stats_.hiddenWaiting = 0;
    hiddenMerges = 0;
    if (context.emptiness.empty(store_.node(0))) {
      stats_.emptyNodes = 1;
      return;
    }
    std::vector<int64_t> stack{0};
    std::vector<int64_t> children;
    while (!stack.empty()) {
      const int64_t id = stack.back();
      stack.pop_back();
      const double pixels = context.projector.projectedPixels(id);
      const bool inFrustum = context.projector.visible(id);
      bool want = wantsSplit(id, pixels, inFrustum);
      const bool resident = pool_.resident(id);
      const bool wasInner = innerNodes_.count(id) > 0;
      children.clear();
      // With feedback, a node the view would split but no ray asks finer of (rays cross it
      // without meeting material) is split all the same when every child is empty: a split
      // into nothing costs no brick and draws what the finer levels hold, nothing, as the
      // working set without feedback does. (Kept as a leaf it would hold its own brick.)
      if (!want && config_.visibility != Visibility::None &&
          wantsSplitIgnoringFeedback(id, pixels, inFrustum)) {
        const std::vector<int64_t> all = layout_.children(id);
        want = std::all_of(all.begin(), all.end(),
                           [&](int64_t c) { return context.emptiness.empty(store_.node(c)); });
      }
      if (want) {
        for (int64_t child : layout_.children(id)) {
          if (context.emptiness.empty(store_.node(child))) {
            ++stats_.emptyNodes;
          } else {
            children.push_back(child);
          }
        }
      }
      if (config_.visibility != Visibility::None && wasInner) {
        const auto st = state_.find(id);
        const bool seenNow = st != state_.end() && st->second.seenFrame == lastFeedbackFrame_;
        // (A split into nothing has no leaf any feedback could see: it never waits.)
        if (want && !seenNow && !children.empty()) ++stats_.hiddenWaiting;
        if (!want && lastFeedbackFrame_ > 0 && !seenNow && st != state_.end() &&
            wantsSplitIgnoringFeedback(id, pixels, inFrustum)) {
          st->second.hiddenMergeFrame = frame_;
          ++hiddenMerges;
        }
      }
      // Split: the previous frame's split nodes stay split (children without their own brick
      // are drawn from an ancestor's); new splits need every child resident (else step 3).
      const bool childrenReady =
          wasInner || std::all_of(children.begin(), children.end(),
                                  [&](int64_t c) { return pool_.resident(c); });
      if (want && childrenReady) {
        inner.insert(id);
        stack.insert(stack.end(), children.begin(), children.end());
        continue;
      }
      leaves.push_back(id);
      const bool hidden = hiddenNow(id);
      if (want) refine.push_back({pixels, id});
      if (resident && !(hidden && id != 0)) {
        pool_.pin(id);
        if (id != 0 && config_.visibility != Visibility::None && lastFeedbackFrame_ > 0) {
          const auto st = state_.find(id);
          if (st != state_.end() && st->second.feedbackFrame == lastFeedbackFrame_ &&
              st->second.seenFrame != lastFeedbackFrame_) {
            ++stats_.hiddenWaiting;  // unseen: drawn from an ancestor after mergeAfterFrames
          }
        }
        continue;
      }
      // Drawn from its nearest resident ancestor: an unseen leaf gives its slot up; a leaf
      // without its brick asks for it unless it wants its children instead.
      if (resident) hiddenProxies.insert(id);
      pool_.pin(drawnFrom(id, resident).first);
      if (!resident && !hidden && !want) merges.emplace_back(layout_.nodeKey(id).level, id);
    }
  };
  cover();

  // 2. Merges: nodes that no longer need their children, once their own brick is here.
  const std::size_t slotBytes = pool_.stats().slotBytes;
  // The first split or merge of a frame is always allowed, so that a budget below one node's
  // children still makes progress.
  const auto budgetAllows = [&](std::size_t bricks) {
    return config_.uploadBytesPerFrame == 0 || stats_.uploadBytes == 0 ||
           stats_.uploadBytes + bricks * slotBytes <= config_.uploadBytesPerFrame;
  };
  std::sort(merges.begin(), merges.end());
  pendingMerges_ = 0;
  const auto uploadStart = std::chrono::steady_clock::now();
  double uploadMs = 0;
  for (const auto& [level, id] : merges) {
    if (failed_.count(id)) continue;  // its descendants stand in for good
    const std::shared_ptr<const volume::Brick> brick = cache_.find(id);
    if (brick && budgetAllows(1) && pool_.freeSlots() > 0 && upload(*brick)) {
      ++stats_.fetched;
      continue;
    }
    if (!brick) {
      request(id, context.projector.projectedPixels(id));
      ++pendingMerges_;
    } else if (!budgetAllows(1)) {
      ++pendingMerges_;
    }
  }
  uploadMs += millisecondsSince(uploadStart);
  stats_.merged += hiddenMerges;

  // 3. Refinement, largest projected voxel first.
  std::priority_queue<Candidate> queue(refine.begin(), refine.end());
  std::unordered_set<int64_t> splitNow;
  std::vector<int64_t> added;
  std::vector<int64_t> missing;
  while (!queue.empty()) {
    const Candidate c = queue.top();
    queue.pop();
    missing.clear();
    bool anyFailed = false;
    std::vector<int64_t> children;
    for (int64_t child : layout_.children(c.id)) {
      if (context.emptiness.empty(store_.node(child))) continue;
      children.push_back(child);
      if (!pool_.resident(child)) missing.push_back(child);
      if (failed_.count(child)) anyFailed = true;
    }
    if (anyFailed) {
      ++stats_.stoppedByError;
      continue;
    }
    bool allCached = true;
    for (int64_t m : missing) {
      if (!cache_.contains(m)) {
        allCached = false;
        request(m, c.priority);
      }
    }
    ++stats_.wantRefine;
    if (!allCached) {
      ++stats_.waitingForData;
      continue;
    }
    if (static_cast<int64_t>(missing.size()) > pool_.freeSlots()) {
      ++stats_.stoppedByPool;
      continue;
    }
    if (!budgetAllows(missing.size())) {
      ++stats_.stoppedByBudget;
      continue;
    }
    // The resident children first, so that uploading the missing ones cannot evict them.
    for (int64_t child : children) pool_.pin(child);
    const auto t0 = std::chrono::steady_clock::now();
    bool uploaded = true;
    for (int64_t m : missing) {
      const std::shared_ptr<const volume::Brick> brick = cache_.find(m);
      if (!brick) {  // evicted from the CPU cache since contains()
        request(m, c.priority);
        uploaded = false;
      } else if (!upload(*brick)) {
        uploaded = false;
      }
    }
    uploadMs += millisecondsSince(t0);
    if (!uploaded) {
      ++stats_.waitingForData;
      continue;
    }
    --stats_.wantRefine;
    ++stats_.split;
    splitNow.insert(c.id);
    inner.insert(c.id);
    for (int64_t child : children) {
      pool_.pin(child);
      const double pixels = context.projector.projectedPixels(child);
      // New nodes have no feedback yet: with feedback on they wait for the next frame.
      added.push_back(child);  // dropped again below if it is split in turn
      if (wantsSplit(child, pixels, context.projector.visible(child))) queue.push({pixels, child});
    }
  }
  stats_.uploadMs = uploadMs;

  // The new cut, and the frame's requests.
  cut_.clear();
  cutNodes_.clear();
  std::unordered_set<int64_t> bricks;
  const auto addLeaf = [&](int64_t id) {
    CutLeaf leaf;
    leaf.key = layout_.nodeKey(id);
    int64_t data = id;
    if (hiddenProxies.count(id) || !pool_.resident(id)) {
      const auto [ancestor, up] = drawnFrom(id, hiddenProxies.count(id) > 0);
      data = ancestor;
      leaf.dataLevelsUp = up;
      ++stats_.proxyLeaves;
    }
    leaf.slot = static_cast<uint32_t>(pool_.slotOf(data));
    leaf.maxValue = store_.node(id).maxValue;
    // An unseen leaf drawn from the root costs no brick: the root is resident for good.
    if (!(data == 0 && id != 0 && hiddenProxies.count(id))) bricks.insert(data);
    cut_.push_back(leaf);
    cutNodes_.push_back(id);
  };
  for (int64_t id : leaves) {
    if (!splitNow.count(id)) addLeaf(id);
  }
  for (int64_t id : added) {
    if (!splitNow.count(id)) addLeaf(id);
  }
  innerNodes_ = std::move(inner);
  stats_.leaves = static_cast<int64_t>(cut_.size());
  stats_.bricks = static_cast<int64_t>(bricks.size());
  for (int64_t id : cutNodes_) {
    const auto it = state_.find(id);
    if (config_.visibility == Visibility::None || it == state_.end() ||
        it->second.feedbackFrame != lastFeedbackFrame_ || lastFeedbackFrame_ == 0) {
      ++stats_.unknownLeaves;
    } else if (it->second.seenFrame == lastFeedbackFrame_) {
      ++stats_.visibleLeaves;
    } else {
      ++stats_.hiddenLeaves;
    }
  }

  std::vector<volume::LoadRequest> list;
  list.reserve(requests.size());
  std::unordered_set<int64_t> current;
  for (const auto& [id, priority] : requests) {
    list.push_back({id, priority});
    current.insert(id);
    if (!lastRequests_.count(id)) ++stats_.requestsIssued;
  }
  const std::unordered_set<int64_t> loadedSet(loaded.begin(), loaded.end());
  for (int64_t id : lastRequests_) {
    if (!current.count(id) && !loadedSet.count(id) && !cache_.contains(id)) ++stats_.requestsCancelled;
  }
  loader_.setRequests(list);
  lastRequests_ = std::move(current);
  stats_.requestsQueued = static_cast<int64_t>(list.size());
  stats_.selectMs = millisecondsSince(start) - uploadMs;
  context_ = nullptr;
  return cut_;
}

void WorkingSet::applyFeedback(std::span<const LeafFeedback> feedback) {
  lastFeedbackFrame_ = frame_;
  for (const LeafFeedback& f : feedback) {
    if (f.seen) pool_.markSeen(f.node);
    bool first = true;
    for (int64_t n = f.node; n >= 0; n = layout_.parent(n)) {
      NodeState& s = state_[n];
      if (!first && s.feedbackFrame == frame_ && (!f.seen || s.seenFrame == frame_)) break;
      s.feedbackFrame = frame_;
      if (f.seen) s.seenFrame = frame_;
      if (first && f.wantsFiner) s.finerFrame = frame_;
      first = false;
    }
  }
}

bool WorkingSet::settled() const {
  return stats_.split == 0 && stats_.merged == 0 && stats_.fetched == 0 && stats_.waitingForData == 0 &&
         stats_.stoppedByBudget == 0 && pendingMerges_ == 0 && stats_.hiddenWaiting == 0 &&
         (config_.visibility == Visibility::None || (stats_.unknownLeaves == 0 && !staleFeedback_));
}

std::vector<volume::LoadError> WorkingSet::takeErrors() { return std::exchange(errors_, {}); }

}  // namespace octoray::gpu
