#include "octoray/volume/octree_layout.h"

#include <fmt/format.h>

#include "octoray/core/error.h"

namespace octoray::volume {
namespace {

int64_t ceilDiv(int64_t a, int64_t b) { return (a + b - 1) / b; }

}  // namespace

OctreeLayout::OctreeLayout(Index3 dims, int brickSize, int border)
    : brickSize_(brickSize), border_(border) {
  if (brickSize != 16 && brickSize != 32 && brickSize != 64) {
    throw Error("", fmt::format("brick size {} not supported (16, 32 or 64)", brickSize));
  }
  if (border != 1 && border != 2) throw Error("", fmt::format("border {} not supported (1 or 2)", border));
  for (int64_t d : dims) {
    if (d < 1 || d > (int64_t{1} << 24)) throw Error("", fmt::format("invalid dimension {}", d));
  }
  // Levels from the leaves up until one brick covers every axis.
  std::vector<Index3> dimsUp{dims};
  while (true) {
    const Index3& d = dimsUp.back();
    if (d[0] <= brickSize && d[1] <= brickSize && d[2] <= brickSize) break;
    dimsUp.push_back({ceilDiv(d[0], 2), ceilDiv(d[1], 2), ceilDiv(d[2], 2)});
  }
  levels_ = static_cast<int>(dimsUp.size());
  levelDims_.assign(dimsUp.rbegin(), dimsUp.rend());
  levelOffset_.push_back(0);
  for (const Index3& d : levelDims_) {
    const Index3 bricks{ceilDiv(d[0], brickSize), ceilDiv(d[1], brickSize), ceilDiv(d[2], brickSize)};
    levelBricks_.push_back(bricks);
    levelOffset_.push_back(levelOffset_.back() + bricks[0] * bricks[1] * bricks[2]);
  }
}

int64_t OctreeLayout::nodeId(const NodeKey& key) const {
  const Index3& n = levelBricks(key.level);
  return levelNodeOffset(key.level) + key.brick[0] + n[0] * (key.brick[1] + n[1] * key.brick[2]);
}

NodeKey OctreeLayout::nodeKey(int64_t id) const {
  if (id < 0 || id >= nodeCount()) throw Error("", fmt::format("node {} out of range", id));
  int level = 0;
  while (levelNodeOffset(level + 1) <= id) ++level;
  const Index3& n = levelBricks(level);
  int64_t local = id - levelNodeOffset(level);
  NodeKey key;
  key.level = level;
  key.brick[0] = local % n[0];
  local /= n[0];
  key.brick[1] = local % n[1];
  key.brick[2] = local / n[1];
  return key;
}

std::vector<int64_t> OctreeLayout::children(int64_t id) const {
  std::vector<int64_t> result;
  const NodeKey key = nodeKey(id);
  if (key.level + 1 >= levels_) return result;
  const Index3& n = levelBricks(key.level + 1);
  for (int dz = 0; dz < 2; ++dz)
    for (int dy = 0; dy < 2; ++dy)
      for (int dx = 0; dx < 2; ++dx) {
        const Index3 c{2 * key.brick[0] + dx, 2 * key.brick[1] + dy, 2 * key.brick[2] + dz};
        if (c[0] < n[0] && c[1] < n[1] && c[2] < n[2]) result.push_back(nodeId({key.level + 1, c}));
      }
  return result;
}

int64_t OctreeLayout::parent(int64_t id) const {
  const NodeKey key = nodeKey(id);
  if (key.level == 0) return -1;
  return nodeId({key.level - 1, {key.brick[0] / 2, key.brick[1] / 2, key.brick[2] / 2}});
}

int64_t OctreeLayout::neighbor(int64_t id, int axis, int step) const {
  NodeKey key = nodeKey(id);
  key.brick[static_cast<std::size_t>(axis)] += step;
  const int64_t b = key.brick[static_cast<std::size_t>(axis)];
  if (b < 0 || b >= levelBricks(key.level)[static_cast<std::size_t>(axis)]) return -1;
  return nodeId(key);
}

}  // namespace octoray::volume
