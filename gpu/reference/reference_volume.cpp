#include "octoray/gpu/reference/reference_volume.h"

#include <fmt/format.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <span>
#include <unordered_map>

#include "octoray/core/error.h"
#include "octoray/dicom/formats.h"
#include "octoray/dicom/volume_source.h"
#include "octoray/volume/store_format.h"
#include "octoray/volume/store_reader.h"

namespace octoray::gpu::reference {
namespace {

// Sample count of `dims`, or an error when it cannot be held in memory as float.
std::size_t checkedSampleCount(const std::array<int64_t, 3>& dims, const std::string& path) {
  for (int64_t d : dims) {
    if (d < 1)
      throw Error(path, fmt::format("volume dims {}x{}x{} are empty", dims[0], dims[1], dims[2]));
  }
  const double samples =
      static_cast<double>(dims[0]) * static_cast<double>(dims[1]) * static_cast<double>(dims[2]);
  if (samples * sizeof(float) >
      static_cast<double>(std::numeric_limits<std::ptrdiff_t>::max() / 2)) {
    throw Error(path, fmt::format("volume {}x{}x{} is too large to hold in memory", dims[0],
                                  dims[1], dims[2]));
  }
  return static_cast<std::size_t>(dims[0] * dims[1] * dims[2]);
}

}  // namespace

// The bricks of an LOD cut and the lookup from a point to the leaf that holds it.
class CutSamples {
 public:
  CutSamples(const volume::StoreReader& store, std::span<const CutLeafRef> leaves);
  double sample(double i, double j, double k) const {
    const Leaf* leaf = find(i, j, k);
    return leaf ? levelSample(*leaf, {i, j, k}) : std::numeric_limits<double>::quiet_NaN();
  }
  Vec3 gradient(const Vec3& p) const;
  bool hasCoarseLeaves() const {
    return std::ranges::any_of(leaves_, [this](const Leaf& l) { return l.dataLevel != layout_.leafLevel(); });
  }

 private:
  struct Leaf {
    volume::Index3 lo, hi;     // the leaf's cells, [lo, hi) in leaf voxels
    int dataLevel = 0;         // the level of the brick it is drawn from
    double scale = 1;          // leaf voxels per voxel of that level
    volume::Index3 origin;     // level index of the brick's stored sample 0 (may be negative)
    volume::Index3 levelDims;  // that level's sample counts
    std::size_t brick = 0;     // index into bricks_
  };
  const Leaf* find(double i, double j, double k) const;
  double levelSample(const Leaf& leaf, const Vec3& p) const;

  // Tells the per-thread memo of find() which CutSamples it belongs to (an address could be
  // reused by a later one).
  static inline std::atomic<uint64_t> nextId_{1};
  uint64_t id_ = nextId_.fetch_add(1);
  volume::OctreeLayout layout_;
  int edge_ = 0;
  double gradientDelta_ = 1;  // level voxels
  std::vector<std::unordered_map<int64_t, std::size_t>> byLevel_;  // brick key -> leaves_ entry
  std::vector<Leaf> leaves_;
  std::vector<std::vector<float>> bricks_;
};

CutSamples::CutSamples(const volume::StoreReader& store, std::span<const CutLeafRef> leaves)
    : layout_(store.layout()),
      edge_(layout_.storedEdge()),
      gradientDelta_(layout_.border() >= 2 ? 1.0 : 0.5),
      byLevel_(static_cast<std::size_t>(layout_.levels())) {
  const int last = layout_.leafLevel();
  const volume::Index3& dims = layout_.levelDims(last);
  std::unordered_map<int64_t, std::size_t> brickOf;  // data node id -> bricks_ entry
  for (const CutLeafRef& ref : leaves) {
    const volume::NodeKey& key = ref.key;
    const bool inStore = key.level >= 0 && key.level <= last &&
                         std::ranges::all_of(std::array{0, 1, 2}, [&](int a) {
                           return key.brick[a] >= 0 && key.brick[a] < layout_.levelBricks(key.level)[a];
                         });
    if (!inStore || ref.dataLevelsUp < 0 || ref.dataLevelsUp > key.level) {
      throw Error(store.path(), fmt::format("cut leaf (level {}, brick {} {} {}, drawn {} levels up) "
                                            "is not a node of the store",
                                            key.level, key.brick[0], key.brick[1], key.brick[2],
                                            ref.dataLevelsUp));
    }
    int64_t data = layout_.nodeId(key);
    for (int up = 0; up < ref.dataLevelsUp; ++up) data = layout_.parent(data);
    const volume::NodeKey dataKey = layout_.nodeKey(data);
    auto [it, added] = brickOf.try_emplace(data, bricks_.size());
    if (added) {
      const volume::Brick brick = store.readBrick(data);
      std::vector<float> values(static_cast<std::size_t>(layout_.storedSamples()));
      for (std::size_t s = 0; s < values.size(); ++s) {
        values[s] = brick.format == volume::SampleFormat::UInt16
                        ? static_cast<float>(store.physical(brick.u16[s]))
                        : brick.f32[s];
      }
      bricks_.push_back(std::move(values));
    }
    Leaf leaf;
    const int64_t span = layout_.brickSize() * layout_.levelScale(key.level);
    for (int a = 0; a < 3; ++a) {
      leaf.lo[a] = key.brick[a] * span;
      leaf.hi[a] = std::min(leaf.lo[a] + span, dims[a]);
      leaf.origin[a] = dataKey.brick[a] * layout_.brickSize() - layout_.border();
    }
    leaf.dataLevel = dataKey.level;
    leaf.scale = static_cast<double>(layout_.levelScale(dataKey.level));
    leaf.levelDims = layout_.levelDims(dataKey.level);
    leaf.brick = it->second;
    const volume::Index3& n = layout_.levelBricks(key.level);
    const int64_t linear = key.brick[0] + n[0] * (key.brick[1] + n[1] * key.brick[2]);
    if (!byLevel_[static_cast<std::size_t>(key.level)].emplace(linear, leaves_.size()).second) {
      throw Error(store.path(), fmt::format("cut leaf (level {}, brick {} {} {}) is listed twice",
                                            key.level, key.brick[0], key.brick[1], key.brick[2]));
    }
    leaves_.push_back(leaf);
  }
  // No leaf may lie inside another: every leaf's cells must find the leaf itself.
  for (const Leaf& leaf : leaves_) {
    const Leaf* found = find(static_cast<double>(leaf.lo[0]), static_cast<double>(leaf.lo[1]),
                             static_cast<double>(leaf.lo[2]));
    if (found != &leaf) {
      throw Error(store.path(), fmt::format("cut leaves overlap at leaf voxel {} {} {}", leaf.lo[0],
                                            leaf.lo[1], leaf.lo[2]));
    }
  }
}

// The leaf whose cells hold point p (cell c holds [c - 0.5, c + 0.5)), coarsest level first;
// points on the domain's far faces belong to the last cell.
const CutSamples::Leaf* CutSamples::find(double i, double j, double k) const {
  const volume::Index3& dims = layout_.levelDims(layout_.leafLevel());
  const double p[3] = {i, j, k};
  volume::Index3 cell;
  for (int a = 0; a < 3; ++a) {
    if (!std::isfinite(p[a])) return nullptr;
    cell[a] = std::clamp(static_cast<int64_t>(std::floor(p[a] + 0.5)), int64_t{0}, dims[a] - 1);
  }
  // Consecutive samples of a ray mostly fall in the leaf of the sample before.
  thread_local uint64_t lastOwner = 0;
  thread_local const Leaf* lastLeaf = nullptr;
  const auto holds = [&cell](const Leaf& leaf) {
    return cell[0] >= leaf.lo[0] && cell[0] < leaf.hi[0] && cell[1] >= leaf.lo[1] &&
           cell[1] < leaf.hi[1] && cell[2] >= leaf.lo[2] && cell[2] < leaf.hi[2];
  };
  if (lastOwner == id_ && lastLeaf && holds(*lastLeaf)) return lastLeaf;
  for (int level = 0; level <= layout_.leafLevel(); ++level) {
    const auto& leaves = byLevel_[static_cast<std::size_t>(level)];
    if (leaves.empty()) continue;
    const int64_t span = layout_.brickSize() * layout_.levelScale(level);
    const volume::Index3& n = layout_.levelBricks(level);
    const int64_t linear = cell[0] / span + n[0] * (cell[1] / span + n[1] * (cell[2] / span));
    const auto it = leaves.find(linear);
    if (it != leaves.end()) {
      lastOwner = id_;
      lastLeaf = &leaves_[it->second];
      return lastLeaf;
    }
  }
  return nullptr;
}

// The trilinear interpolant of the leaf's data level at leaf-index point p, clamped to the
// level's extent, from the leaf's brick alone (indices held to the stored samples: a point
// outside the brick's reach, as a gradient's neighbour may be, reads its nearest border).
double CutSamples::levelSample(const Leaf& leaf, const Vec3& p) const {
  const double q[3] = {p.x, p.y, p.z};
  int64_t lo[3], hi[3];
  double f[3];
  for (int a = 0; a < 3; ++a) {
    // The leaf level's own coordinates need no mapping (and stay bit-identical to fromStore).
    const double s = leaf.scale == 1.0 ? q[a] : (q[a] + 0.5) / leaf.scale - 0.5;
    const double c = std::clamp(s, 0.0, static_cast<double>(leaf.levelDims[a] - 1));
    const int64_t i0 = static_cast<int64_t>(c);
    f[a] = c - static_cast<double>(i0);
    const int64_t i1 = std::min(i0 + 1, leaf.levelDims[a] - 1);
    lo[a] = std::clamp<int64_t>(i0 - leaf.origin[a], 0, edge_ - 1);
    hi[a] = std::clamp<int64_t>(i1 - leaf.origin[a], 0, edge_ - 1);
  }
  const float* b = bricks_[leaf.brick].data();
  const int64_t e = edge_;
  const auto at = [&](int64_t x, int64_t y, int64_t z) -> double {
    return b[static_cast<std::size_t>(x + e * (y + e * z))];
  };
  // The same blend, in the same order, as ReferenceVolume::sample.
  const double c00 = at(lo[0], lo[1], lo[2]) + f[0] * (at(hi[0], lo[1], lo[2]) - at(lo[0], lo[1], lo[2]));
  const double c10 = at(lo[0], hi[1], lo[2]) + f[0] * (at(hi[0], hi[1], lo[2]) - at(lo[0], hi[1], lo[2]));
  const double c01 = at(lo[0], lo[1], hi[2]) + f[0] * (at(hi[0], lo[1], hi[2]) - at(lo[0], lo[1], hi[2]));
  const double c11 = at(lo[0], hi[1], hi[2]) + f[0] * (at(hi[0], hi[1], hi[2]) - at(lo[0], hi[1], hi[2]));
  const double c0 = c00 + f[1] * (c10 - c00);
  const double c1 = c01 + f[1] * (c11 - c01);
  return c0 + f[2] * (c1 - c0);
}

Vec3 CutSamples::gradient(const Vec3& p) const {
  const Leaf* leaf = find(p.x, p.y, p.z);
  if (!leaf) return {0, 0, 0};
  const double h = gradientDelta_ * leaf->scale;  // in leaf voxels
  const double inv = 1.0 / (2.0 * h);
  return {(levelSample(*leaf, {p.x + h, p.y, p.z}) - levelSample(*leaf, {p.x - h, p.y, p.z})) * inv,
          (levelSample(*leaf, {p.x, p.y + h, p.z}) - levelSample(*leaf, {p.x, p.y - h, p.z})) * inv,
          (levelSample(*leaf, {p.x, p.y, p.z + h}) - levelSample(*leaf, {p.x, p.y, p.z - h})) * inv};
}

ReferenceVolume::ReferenceVolume(std::shared_ptr<const CutSamples> cut,
                                 std::array<int64_t, 3> dims, const Mat4& patientFromIndex)
    : dims_(dims), patientFromIndex_(patientFromIndex), cut_(std::move(cut)) {
  patientFromIndex_.inverseAffine();
}

ReferenceVolume ReferenceVolume::fromCut(const volume::StoreReader& store,
                                         std::span<const CutLeafRef> leaves) {
  const volume::OctreeLayout& layout = store.layout();
  return ReferenceVolume(std::make_shared<const CutSamples>(store, leaves),
                         layout.levelDims(layout.leafLevel()), store.patientFromIndex());
}

bool ReferenceVolume::hasCoarseLeaves() const { return cut_ && cut_->hasCoarseLeaves(); }

ReferenceVolume ReferenceVolume::fromPath(const std::string& path) {
  if (volume::isStoreFile(path)) {
    const volume::StoreReader store(path);
    return fromStore(store);
  }
  const auto source = openVolume(path);
  return fromSource(*source);
}

Vec3 ReferenceVolume::gradientIndex(const Vec3& p) const {
  if (cut_) return cut_->gradient(p);
  return {0.5 * (sample(p.x + 1, p.y, p.z) - sample(p.x - 1, p.y, p.z)),
          0.5 * (sample(p.x, p.y + 1, p.z) - sample(p.x, p.y - 1, p.z)),
          0.5 * (sample(p.x, p.y, p.z + 1) - sample(p.x, p.y, p.z - 1))};
}

ReferenceVolume::ReferenceVolume(std::array<int64_t, 3> dims, const Mat4& patientFromIndex,
                                 std::vector<float> values)
    : dims_(dims), patientFromIndex_(patientFromIndex), values_(std::move(values)) {
  if (values_.size() != checkedSampleCount(dims_, "")) {
    throw Error("", fmt::format("{} values for a {}x{}x{} volume", values_.size(), dims_[0],
                                dims_[1], dims_[2]));
  }
  patientFromIndex_.inverseAffine();  // throws for a singular affine
}

ReferenceVolume ReferenceVolume::fromSource(VolumeSource& source) {
  const VolumeInfo& info = source.info();
  std::vector<float> values(checkedSampleCount(info.dims, info.sourcePath));
  const int64_t slice = info.sliceSamples();
  // Slabs of about 16 MiB keep the source's read calls large without a second full copy.
  const int64_t slabSlices = std::max<int64_t>(1, (int64_t{4} << 20) / slice);
  for (int64_t first = 0; first < info.dims[2]; first += slabSlices) {
    const int64_t count = std::min(slabSlices, info.dims[2] - first);
    source.readSlab(
        first, count,
        std::span<float>(values.data() + first * slice, static_cast<std::size_t>(count * slice)));
  }
  return ReferenceVolume(info.dims, info.patientFromIndex, std::move(values));
}

ReferenceVolume ReferenceVolume::fromStore(const volume::StoreReader& store) {
  const volume::OctreeLayout& layout = store.layout();
  const int leaf = layout.leafLevel();
  const volume::Index3 dims = layout.levelDims(leaf);
  std::vector<float> values(checkedSampleCount(dims, store.path()));
  const int b = layout.brickSize();
  const int a = layout.border();
  const int64_t edge = layout.storedEdge();
  const int64_t first = layout.levelNodeOffset(leaf);
  const int64_t end = first + layout.levelBricks(leaf)[0] * layout.levelBricks(leaf)[1] *
                                  layout.levelBricks(leaf)[2];
  for (int64_t id = first; id < end; ++id) {
    const volume::NodeKey key = layout.nodeKey(id);
    const volume::Brick brick = store.readBrick(id);
    const volume::Index3 origin{key.brick[0] * b, key.brick[1] * b, key.brick[2] * b};
    // The brick's interior, clipped to the volume (the last brick on an axis may be partial).
    const std::array<int64_t, 3> extent{std::min<int64_t>(b, dims[0] - origin[0]),
                                        std::min<int64_t>(b, dims[1] - origin[1]),
                                        std::min<int64_t>(b, dims[2] - origin[2])};
    for (int64_t z = 0; z < extent[2]; ++z) {
      for (int64_t y = 0; y < extent[1]; ++y) {
        const int64_t stored = a + edge * ((y + a) + edge * (z + a));
        float* out =
            values.data() + origin[0] + dims[0] * ((origin[1] + y) + dims[1] * (origin[2] + z));
        for (int64_t x = 0; x < extent[0]; ++x) {
          const std::size_t s = static_cast<std::size_t>(stored + x);
          out[x] = brick.format == volume::SampleFormat::UInt16
                       ? static_cast<float>(store.physical(brick.u16[s]))
                       : brick.f32[s];
        }
      }
    }
  }
  return ReferenceVolume(dims, store.patientFromIndex(), std::move(values));
}

double ReferenceVolume::sample(double i, double j, double k) const {
  if (cut_) return cut_->sample(i, j, k);
  // Clamp to the outermost centres (edge samples extend to the domain's faces), then blend
  // the 8 neighbours; the upper neighbour of an edge sample is the sample itself.
  const double pi = std::clamp(i, 0.0, static_cast<double>(dims_[0] - 1));
  const double pj = std::clamp(j, 0.0, static_cast<double>(dims_[1] - 1));
  const double pk = std::clamp(k, 0.0, static_cast<double>(dims_[2] - 1));
  const int64_t i0 = static_cast<int64_t>(pi), j0 = static_cast<int64_t>(pj),
                k0 = static_cast<int64_t>(pk);
  const double fi = pi - static_cast<double>(i0), fj = pj - static_cast<double>(j0),
               fk = pk - static_cast<double>(k0);
  const int64_t si = i0 + 1 < dims_[0] ? 1 : 0;
  const int64_t sj = j0 + 1 < dims_[1] ? dims_[0] : 0;
  const int64_t sk = k0 + 1 < dims_[2] ? dims_[0] * dims_[1] : 0;
  const float* p = values_.data() + (i0 + dims_[0] * (j0 + dims_[1] * k0));
  const double c00 = p[0] + fi * (static_cast<double>(p[si]) - p[0]);
  const double c10 = p[sj] + fi * (static_cast<double>(p[sj + si]) - p[sj]);
  const double c01 = p[sk] + fi * (static_cast<double>(p[sk + si]) - p[sk]);
  const double c11 = p[sk + sj] + fi * (static_cast<double>(p[sk + sj + si]) - p[sk + sj]);
  const double c0 = c00 + fj * (c10 - c00);
  const double c1 = c01 + fj * (c11 - c01);
  return c0 + fk * (c1 - c0);
}

}  // namespace octoray::gpu::reference
