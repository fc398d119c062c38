#include "octoray/gpu/working_set.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <queue>

#include "octoray/dicom/error.h"
#include "octoray/transfer/opacity_table.h"

namespace octoray::gpu {
namespace {

constexpr double kDegrees = 3.14159265358979323846 / 180.0;

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
      // The lowest value with non-zero opacity: the TF is zero below it (clamped low end).
      mipThreshold_ = -std::numeric_limits<double>::infinity();
      if (!tf.opacity.empty() && !(tf.opacity.front().alpha > 0)) {
        mipThreshold_ = std::numeric_limits<double>::infinity();
        for (std::size_t i = 0; i < tf.opacity.size(); ++i) {
          if (tf.opacity[i].alpha > 0) {
            // Opacity rises from the previous point's value on.
            mipThreshold_ = i > 0 ? tf.opacity[i - 1].value : tf.opacity[i].value;
            break;
          }
        }
      }
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

struct Candidate {
  double pixels;  // projected voxel size
  int64_t id;
  bool operator<(const Candidate& o) const { return pixels < o.pixels; }
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
      tanY_ = std::tan(0.5 * camera.fovYDegrees * kDegrees);
      tanX_ = tanY_ * aspect;
    } else {
      halfY_ = 0.5 * camera.orthoHeightMm;
      halfX_ = halfY_ * aspect;
    }
  }

  // The node's 8 corners in patient space (its box clipped to the volume's domain).
  std::array<Vec3, 8> corners(int64_t id) const {
    const volume::NodeKey key = layout_.nodeKey(id);
    const int64_t cells = static_cast<int64_t>(layout_.brickSize()) * layout_.levelScale(key.level);
    const volume::Index3& dims = layout_.levelDims(layout_.leafLevel());
    std::array<double, 3> lo{}, hi{};
    for (int a = 0; a < 3; ++a) {
      lo[a] = static_cast<double>(key.brick[a] * cells) - 0.5;
      hi[a] = static_cast<double>(std::min((key.brick[a] + 1) * cells, dims[a])) - 0.5;
    }
    std::array<Vec3, 8> out;
    for (int c = 0; c < 8; ++c) {
      out[c] = m_.transformPoint({(c & 1) ? hi[0] : lo[0], (c & 2) ? hi[1] : lo[1],
                                  (c & 4) ? hi[2] : lo[2]});
    }
    return out;
  }

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

WorkingSet selectWorkingSet(const volume::StoreReader& store, const Camera& camera,
                            const transfer::TransferFunction& tf, const WorkingSetOptions& options) {
  if (!(options.lodPixels >= 0 && std::isfinite(options.lodPixels))) {
    throw Error("", fmt::format("--lod-pixels {} must be 0 or positive", options.lodPixels));
  }
  camera.validate();
  const volume::OctreeLayout& layout = store.layout();
  const EmptinessTest emptiness(store, tf, options);
  const Projector projector(store, camera);
  const int64_t capacity = options.slotCapacity > 0 ? options.slotCapacity
                                                    : std::numeric_limits<int64_t>::max();

  WorkingSet ws;
  if (emptiness.empty(store.node(0))) {
    ws.emptyNodes = 1;
    return ws;
  }
  std::priority_queue<Candidate> queue;
  queue.push({projector.projectedPixels(0), 0});
  int64_t slots = 1;  // non-empty nodes queued or kept
  std::vector<int64_t> kept;
  while (!queue.empty()) {
    const Candidate c = queue.top();
    queue.pop();
    const volume::NodeKey key = layout.nodeKey(c.id);
    const bool fineEnough = key.level == layout.leafLevel() ||
                            (options.lodPixels > 0 && c.pixels <= options.lodPixels);
    if (fineEnough) {
      kept.push_back(c.id);
      continue;
    }
    if (!projector.visible(c.id)) {
      ++ws.culledNodes;
      kept.push_back(c.id);
      continue;
    }
    std::vector<int64_t> nonEmpty;
    for (int64_t child : layout.children(c.id)) {
      if (emptiness.empty(store.node(child))) {
        ++ws.emptyNodes;
      } else {
        nonEmpty.push_back(child);
      }
    }
    if (slots - 1 + static_cast<int64_t>(nonEmpty.size()) > capacity) {
      ++ws.capacityLimited;
      kept.push_back(c.id);
      continue;
    }
    slots += static_cast<int64_t>(nonEmpty.size()) - 1;
    for (int64_t child : nonEmpty) queue.push({projector.projectedPixels(child), child});
  }
  ws.dataNodes.reserve(kept.size());
  for (int64_t id : kept) {
    ws.dataNodes.push_back(layout.nodeKey(id));
    ws.finestProjectedPixels = std::max(ws.finestProjectedPixels, projector.projectedPixels(id));
  }
  return ws;
}

}  // namespace octoray::gpu
