#include "octoray/gpu/spatial_index.h"

#include <fmt/format.h>

#include <bit>
#include <cmath>
#include <deque>
#include <limits>
#include <unordered_map>
#include <unordered_set>

#include "octoray/core/error.h"

namespace octoray::gpu {
namespace {

// (level, x, y, z) packed: level < 32, coordinates < 2^19 (levels <= 20 for B >= 16 and
// dims <= 2^24 leave coordinates below 2^20; checked).
uint64_t packKey(int level, int64_t x, int64_t y, int64_t z) {
  return (static_cast<uint64_t>(level) << 60) | (static_cast<uint64_t>(x) << 40) |
         (static_cast<uint64_t>(y) << 20) | static_cast<uint64_t>(z);
}

uint32_t word(uint32_t kind, uint32_t payload) { return (kind << 30) | payload; }
uint32_t kindOf(uint32_t w) { return w >> 30; }
uint32_t payloadOf(uint32_t w) { return w & 0x3FFFFFFFu; }

constexpr float kFar = std::numeric_limits<float>::infinity();

}  // namespace

SpatialIndex SpatialIndex::build(const volume::OctreeLayout& layout,
                                 const std::vector<CutLeaf>& cut) {
  const int levels = layout.levels();
  if (levels < 1 || levels > 20) {
    throw Error("", fmt::format("spatial index: {} octree levels not supported (1..20)", levels));
  }
  // The cut's leaves, and every ancestor of one (those become inner nodes).
  struct LeafData {
    uint32_t slotWord;
    float maxValue;
    int32_t cutIndex;
  };
  std::unordered_map<uint64_t, LeafData> leafSlot;
  std::unordered_set<uint64_t> ancestors;
  leafSlot.reserve(cut.size() * 2);
  for (std::size_t cutIndex = 0; cutIndex < cut.size(); ++cutIndex) {
    const CutLeaf& leaf = cut[cutIndex];
    const volume::NodeKey& k = leaf.key;
    if (k.level < 0 || k.level >= levels) {
      throw Error("", fmt::format("spatial index: node level {} outside 0..{}", k.level, levels - 1));
    }
    const volume::Index3& bricks = layout.levelBricks(k.level);
    for (int a = 0; a < 3; ++a) {
      if (k.brick[a] < 0 || k.brick[a] >= bricks[a]) {
        throw Error("", fmt::format("spatial index: brick ({}, {}, {}) outside level {}",
                                    k.brick[0], k.brick[1], k.brick[2], k.level));
      }
    }
    uint32_t slotWord = leaf.slot;
    if (leaf.slot != kNoSlot) {
      if (leaf.slot >= kMaxSlots || leaf.dataLevelsUp < 0 || leaf.dataLevelsUp > k.level) {
        throw Error("", fmt::format("spatial index: slot {} or data level offset {} out of range",
                                    leaf.slot, leaf.dataLevelsUp));
      }
      slotWord = leaf.slot | (static_cast<uint32_t>(leaf.dataLevelsUp) << kSlotBits);
    }
    if (!leafSlot.emplace(packKey(k.level, k.brick[0], k.brick[1], k.brick[2]),
                          LeafData{slotWord, leaf.maxValue, static_cast<int32_t>(cutIndex)}).second) {
      throw Error("", fmt::format("spatial index: node ({}, {}, {}) of level {} listed twice",
                                  k.brick[0], k.brick[1], k.brick[2], k.level));
    }
    for (int l = k.level - 1; l >= 0; --l) {
      const int s = k.level - l;
      if (!ancestors.insert(packKey(l, k.brick[0] >> s, k.brick[1] >> s, k.brick[2] >> s)).second) {
        break;  // its own ancestors are in already
      }
    }
  }
  for (const CutLeaf& leaf : cut) {
    const volume::NodeKey& k = leaf.key;
    if (ancestors.count(packKey(k.level, k.brick[0], k.brick[1], k.brick[2]))) {
      throw Error("", fmt::format("spatial index: node ({}, {}, {}) of level {} overlaps a finer "
                                  "node of the cut", k.brick[0], k.brick[1], k.brick[2], k.level));
    }
  }

  SpatialIndex index;
  index.levels = levels;
  struct Pending {
    uint32_t entry;
    int level;
    std::array<int64_t, 3> c;
  };
  struct LeafInfo {
    int level;
    std::array<int64_t, 3> c;
  };
  std::vector<LeafInfo> leafInfo;
  index.nodes.push_back(0);
  std::deque<Pending> queue{{0, 0, {0, 0, 0}}};
  while (!queue.empty()) {
    const Pending p = queue.front();
    queue.pop_front();
    const uint64_t key = packKey(p.level, p.c[0], p.c[1], p.c[2]);
    if (ancestors.count(key)) {
      const auto first = static_cast<uint32_t>(index.nodes.size());
      if (first + 8 >= kMaxIndexEntries) throw Error("", "spatial index: too many nodes");
      index.nodes[p.entry] = word(kInner, first);
      index.nodes.resize(index.nodes.size() + 8, 0);
      for (int child = 0; child < 8; ++child) {
        queue.push_back({first + static_cast<uint32_t>(child), p.level + 1,
                         {2 * p.c[0] + (child & 1), 2 * p.c[1] + ((child >> 1) & 1),
                          2 * p.c[2] + ((child >> 2) & 1)}});
      }
      continue;
    }
    const auto found = leafSlot.find(key);
    const uint32_t slot = found == leafSlot.end() ? kNoSlot : found->second.slotWord;
    const float maxValue =
        found == leafSlot.end() ? -std::numeric_limits<float>::infinity() : found->second.maxValue;
    index.cutIndex.push_back(found == leafSlot.end() ? -1 : found->second.cutIndex);
    const auto record = static_cast<uint32_t>(leafInfo.size());
    if (record >= kMaxIndexEntries) throw Error("", "spatial index: too many leaves");
    index.nodes[p.entry] = word(slot == kNoSlot ? kEmptyLeaf : kDataLeaf, record);
    leafInfo.push_back({p.level, p.c});
    (slot == kNoSlot ? index.emptyLeaves : index.dataLeaves) += 1;
    index.leaves.insert(index.leaves.end(), {slot, kNull, kNull, kNull, kNull, kNull, kNull,
                                             std::bit_cast<uint32_t>(maxValue)});
  }

  // Neighbour pointers: the smallest node holding the same-size box across each face.
  for (std::size_t r = 0; r < leafInfo.size(); ++r) {
    const LeafInfo& leaf = leafInfo[r];
    const int64_t extent = int64_t{1} << leaf.level;
    for (int face = 0; face < 6; ++face) {
      std::array<int64_t, 3> n = leaf.c;
      n[face / 2] += (face & 1) ? 1 : -1;
      if (n[face / 2] < 0 || n[face / 2] >= extent) continue;  // kNull: the cube's boundary
      uint32_t entry = 0;
      int level = 0;
      while (kindOf(index.nodes[entry]) == kInner && level < leaf.level) {
        const int s = leaf.level - level - 1;
        const uint32_t child = static_cast<uint32_t>(((n[0] >> s) & 1) | (((n[1] >> s) & 1) << 1) |
                                                     (((n[2] >> s) & 1) << 2));
        entry = payloadOf(index.nodes[entry]) + child;
        ++level;
      }
      index.leaves[r * kLeafRecordUints + 1 + static_cast<std::size_t>(face)] =
          entry | (static_cast<uint32_t>(level) << 27);
    }
  }
  return index;
}

OctreeChord clipOctreeDomain(const OctreeRay& ray, const std::array<float, 3>& domainMax,
                             float tMin) {
  OctreeChord c{tMin, kFar};
  for (int a = 0; a < 3; ++a) {
    const float o = ray.origin[a], d = ray.direction[a];
    if (d == 0.0f) {
      if (o < 0.0f || o > domainMax[a]) return {0, -1};
      continue;
    }
    const float inv = 1.0f / d;
    float tn = (0.0f - o) * inv, tf = (domainMax[a] - o) * inv;
    if (tn > tf) std::swap(tn, tf);
    c.tNear = std::max(c.tNear, tn);
    c.tFar = std::min(c.tFar, tf);
  }
  if (!(c.tFar >= c.tNear)) return {0, -1};
  return c;
}

int64_t traverseRay(const SpatialIndex& index, const OctreeRay& ray, float t0, float t1,
                    const std::function<bool(const LeafCrossing&)>& visit, bool reportPasses) {
  const std::array<float, 3>& o = ray.origin;
  const std::array<float, 3>& d = ray.direction;
  std::array<float, 3> inv{};
  for (int a = 0; a < 3; ++a) inv[a] = d[a] != 0.0f ? 1.0f / d[a] : 0.0f;
  const auto tPlane = [&](int a, float plane) { return (plane - o[a]) * inv[a]; };
  // Each leaf is entered at most once per face crossing; 3 * (leaves + 2) bounds any path.
  const int64_t maxIterations = 3 * (static_cast<int64_t>(index.leaves.size() / kLeafRecordUints) + 2);

  uint32_t entry = 0;
  int level = 0;
  std::array<float, 3> boxMin{0, 0, 0};
  float dim = 1.0f;
  float t = t0;
  int64_t iterations = 0;
  while (t < t1 && iterations < maxIterations) {
    ++iterations;
    uint32_t w = index.nodes[entry];
    while (kindOf(w) == kInner) {
      dim *= 0.5f;
      uint32_t child = 0;
      for (int a = 0; a < 3; ++a) {
        const float mid = boxMin[a] + dim;
        const bool upper = d[a] > 0.0f ? t >= tPlane(a, mid)
                           : d[a] < 0.0f ? t < tPlane(a, mid)
                                         : o[a] >= mid;
        if (upper) {
          boxMin[a] = mid;
          child |= 1u << a;
        }
      }
      entry = payloadOf(w) + child;
      w = index.nodes[entry];
      ++level;
    }
    float tExit = kFar;
    int face = -1;
    for (int a = 0; a < 3; ++a) {
      if (d[a] == 0.0f) continue;
      const float tf = tPlane(a, d[a] > 0.0f ? boxMin[a] + dim : boxMin[a]);
      if (tf < tExit) {
        tExit = tf;
        face = 2 * a + (d[a] > 0.0f ? 1 : 0);
      }
    }
    const uint32_t record = payloadOf(w);
    const float tEnd = std::min(tExit, t1);
    if (tEnd > t || reportPasses) {
      LeafCrossing crossing;
      crossing.entry = entry;
      crossing.kind = kindOf(w);
      const uint32_t slotWord = index.leaves[record * kLeafRecordUints];
      crossing.slot = slotWord == kNoSlot ? kNoSlot : slotWord & (kMaxSlots - 1);
      crossing.dataLevelsUp = slotWord == kNoSlot ? 0 : static_cast<int>(slotWord >> kSlotBits);
      crossing.level = level;
      crossing.boxMin = boxMin;
      crossing.boxDim = dim;
      crossing.tEnter = t;
      crossing.tExit = tEnd;
      if (!visit(crossing)) break;
    }
    if (face < 0 || !(tExit < t1)) break;
    const uint32_t neighbour = index.leaves[record * kLeafRecordUints + 1 + static_cast<uint32_t>(face)];
    if (neighbour == kNull) break;
    boxMin[face / 2] += (face & 1) ? dim : -dim;
    level = static_cast<int>(neighbour >> 27);
    dim = std::ldexp(1.0f, -level);
    for (int a = 0; a < 3; ++a) boxMin[a] = std::floor(boxMin[a] / dim) * dim;
    entry = neighbour & 0x07FFFFFFu;
    t = tExit;
  }
  return iterations;
}

}  // namespace octoray::gpu
