#pragma once
// The spatial index the raycaster walks (paper 003 §5.1): an octree with neighbour pointers
// over the current working set, rebuilt on the CPU whenever the working set changes and
// uploaded as two shader storage buffers.
//
// Octree space. The store's octree (volume/octree_layout.h) is a regular octree over a cube of
// S = B * 2^(L-1) leaf voxels per axis: brick b of level l covers leaf cells
// [b * B * 2^(L-1-l), (b + 1) * B * 2^(L-1-l)). The index works in the unit cube
// q = (leafIndex + 0.5) / S, so a node of level l is the box of edge 2^-l at
// q = brick * 2^-l (exact in binary floating point). The volume's domain is the box
// [0, dims / S] inside it; cube cells without a brick in the store are empty leaves.
//
// Encoding (std430 arrays of uint):
//   nodes[]: one entry per node. The root is entry 0; an inner node's 8 children are
//            consecutive entries, child (sx, sy, sz) at first + sx + 2 sy + 4 sz.
//            bits 30..31: kind (kEmptyLeaf, kDataLeaf, kInner); bits 0..29: for an inner
//            node the first child's entry, for a leaf its leaf record.
//   leaves[]: 8 uints per leaf record: [0] the brick-pool slot in bits 0..23 and in bits
//            24..31 how many levels up the node whose brick it is lies (0: the leaf's own;
//            d > 0: the leaf is drawn from its ancestor d levels up, whose brick covers it),
//            kNoSlot for empty leaves,
//            [1..6] neighbour pointers across faces -x, +x, -y, +y, -z, +z, [7] the bits of
//            the node's maximum value as a float (MIP skips leaves that cannot raise a ray's
//            maximum; -inf for empty leaves). A neighbour pointer is the entry of the smallest node of the index that
//            holds the same-size box on the other side of the face (its level <= the leaf's,
//            paper Fig. 3) in bits 0..26 and that node's level in bits 27..31, or kNull when
//            the face lies on the cube's boundary.
//
// Traversal (paper Fig. 5, traverseRay below and raycast.frag.glsl, which mirror each other
// operation for operation in single precision): the ray q(t) = origin + t * direction, t in
// patient mm, clipped to the domain [t0, t1]. From the root, a down traversal picks at each
// inner node the child whose slab holds t_min on every axis (decided by comparing t_min with
// the t at the node's mid planes, never by comparing a rounded point with them, so that a ray
// entering through a face always lands in the box behind that face); the leaf's exit t is the
// nearest far plane (ties: the lowest axis); the ray then follows the neighbour pointer of the
// exit face, snaps the box to the neighbour's level (box_min = floor(box_min / dim) * dim) and
// descends again from there. All box coordinates are dyadic, so these operations are exact;
// every plane's t comes from one expression, so the exit t of a leaf is bit-for-bit the entry t
// of the next. A ray passing exactly through an edge or a corner of a leaf crosses the
// touching leaves at a single t (a "pass", not a visit: it covers no length).

#include <array>
#include <cstdint>
#include <functional>
#include <vector>

#include "octoray/volume/octree_layout.h"

namespace octoray::gpu {

inline constexpr uint32_t kEmptyLeaf = 0u;
inline constexpr uint32_t kDataLeaf = 1u;
inline constexpr uint32_t kInner = 2u;
inline constexpr uint32_t kNoSlot = 0xFFFFFFFFu;
inline constexpr uint32_t kNull = 0xFFFFFFFFu;
inline constexpr int kLeafRecordUints = 8;
inline constexpr uint32_t kMaxIndexEntries = 1u << 27;

// One leaf of a cut through the store's octree.
inline constexpr uint32_t kSlotBits = 24;
inline constexpr uint32_t kMaxSlots = 1u << kSlotBits;

struct CutLeaf {
  volume::NodeKey key;
  uint32_t slot = kNoSlot;  // brick-pool slot; kNoSlot: the leaf is empty (skipped)
  float maxValue = 0;       // the node's maximum physical value (NodeRecord::maxValue)
  int dataLevelsUp = 0;     // > 0: the slot holds the brick of the ancestor this many levels up
};

// A cut: leaves whose boxes tile the cube's cells that exist in the store. Cells of the cube
// not covered (outside the store's bricks, or under an empty node that was not refined) are
// empty leaves of the index.
struct SpatialIndex {
  std::vector<uint32_t> nodes;
  std::vector<uint32_t> leaves;
  std::vector<int32_t> cutIndex;  // per leaf record: its position in the cut, -1 when empty
  int levels = 0;        // the store's levels (node levels run 0 .. levels - 1)
  int64_t dataLeaves = 0;
  int64_t emptyLeaves = 0;

  // Builds the index of `cut` (leaves must not overlap; throws octoray::Error when they do,
  // when a key is outside the layout, or when the index would not fit the encoding).
  static SpatialIndex build(const volume::OctreeLayout& layout, const std::vector<CutLeaf>& cut);
};

// The ray in octree space; t in the caller's units (the renderers use patient mm).
struct OctreeRay {
  std::array<float, 3> origin{};
  std::array<float, 3> direction{};
};

// One leaf crossed by a ray: [tEnter, tExit] with tExit > tEnter for a visit; tExit == tEnter
// for a pass through an edge or corner (reported only when `reportPasses`).
struct LeafCrossing {
  uint32_t entry = 0;     // node entry of the leaf
  uint32_t kind = kEmptyLeaf;
  uint32_t slot = kNoSlot;
  int dataLevelsUp = 0;
  int level = 0;
  std::array<float, 3> boxMin{};
  float boxDim = 1;
  float tEnter = 0, tExit = 0;
};

// The domain clip of the raycaster in octree space: [tNear, tFar] of the ray inside
// [0, domainMax] (closed box), from tMin on; tFar < tNear when the ray misses.
struct OctreeChord {
  float tNear = 0, tFar = -1;
};
OctreeChord clipOctreeDomain(const OctreeRay& ray, const std::array<float, 3>& domainMax,
                             float tMin);

// Walks the index along the ray from t0 to t1 exactly as the shader does, calling `visit`
// for every leaf crossed (empty ones included) until it returns false, the ray leaves the
// cube, or t reaches t1. The last crossing is clipped to t1. Returns the number of loop
// iterations (a bound on it is part of the robustness test).
int64_t traverseRay(const SpatialIndex& index, const OctreeRay& ray, float t0, float t1,
                    const std::function<bool(const LeafCrossing&)>& visit,
                    bool reportPasses = false);

}  // namespace octoray::gpu
