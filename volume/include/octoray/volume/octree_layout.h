#pragma once
// The geometry of the brick octree, shared by the builder, the reader, the validator and the
// renderer. Level 0 is the root; level L-1 holds the original samples. Level l has
// dims_l = ceil(dims_{l+1} / 2) samples per axis; its sample s averages the 2x2x2 samples
// {2s, 2s+1} of level l+1 (clamped at the volume's edge), so its centre sits at the centre of
// the samples it averages: leaf index = (s + 0.5) * 2^(L-1-l) - 0.5.
// A brick b of level l owns samples [b*B, b*B + B) per axis and stores (B + 2A)^3 samples
// from b*B - A, clamped to the level's extent (edge samples replicated).

#include <array>
#include <cstdint>
#include <vector>

namespace octoray::volume {

using Index3 = std::array<int64_t, 3>;

struct NodeKey {
  int level = 0;
  Index3 brick{0, 0, 0};
  friend bool operator==(const NodeKey&, const NodeKey&) = default;
};

class OctreeLayout {
 public:
  OctreeLayout() = default;
  // Throws octoray::Error for empty dims or an unsupported brick size / border.
  OctreeLayout(Index3 dims, int brickSize, int border);

  int levels() const { return levels_; }
  int brickSize() const { return brickSize_; }
  int border() const { return border_; }
  int storedEdge() const { return brickSize_ + 2 * border_; }
  int64_t storedSamples() const {
    const int64_t e = storedEdge();
    return e * e * e;
  }
  int leafLevel() const { return levels_ - 1; }

  const Index3& levelDims(int level) const { return levelDims_[static_cast<std::size_t>(level)]; }
  const Index3& levelBricks(int level) const {
    return levelBricks_[static_cast<std::size_t>(level)];
  }
  int64_t nodeCount() const { return levelOffset_.back(); }
  int64_t levelNodeOffset(int level) const { return levelOffset_[static_cast<std::size_t>(level)]; }

  int64_t nodeId(const NodeKey& key) const;
  NodeKey nodeKey(int64_t id) const;
  // The up to 8 children of a node (none for leaves), in z-major then y then x order.
  std::vector<int64_t> children(int64_t id) const;
  // The parent of a node, or -1 for the root.
  int64_t parent(int64_t id) const;
  // A neighbour on the same level across face `axis` in direction `step` (-1 or +1), or -1.
  int64_t neighbor(int64_t id, int axis, int step) const;
  // Leaf-level samples one sample of `level` spans along an axis: 2^(L-1-level).
  int64_t levelScale(int level) const { return int64_t{1} << (levels_ - 1 - level); }

 private:
  int brickSize_ = 32;
  int border_ = 1;
  int levels_ = 0;
  std::vector<Index3> levelDims_;
  std::vector<Index3> levelBricks_;
  std::vector<int64_t> levelOffset_;  // first node id of each level; back() = node count
};

}  // namespace octoray::volume
