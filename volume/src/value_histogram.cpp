#include "octoray/volume/value_histogram.h"

#include <algorithm>

#include "octoray/core/error.h"
#include "octoray/volume/store_reader.h"

namespace octoray::volume {

double histogramTop(double lo, double hi) { return hi > lo ? hi : lo + 1; }

int histogramBin(double value, double lo, double hi, int bins) {
  return std::clamp(static_cast<int>((value - lo) / (hi - lo) * bins), 0, bins - 1);
}

ValueHistogram storeHistogram(const StoreReader& store, int bins) {
  const OctreeLayout& layout = store.layout();
  constexpr int64_t kMaxBricks = 256;
  int level = layout.leafLevel();
  while (level > 0) {
    const auto& d = layout.levelDims(level);
    const int64_t bricks = layout.levelNodeOffset(level + 1) - layout.levelNodeOffset(level);
    if (d[0] * d[1] * d[2] <= kHistogramSamples && bricks <= kMaxBricks) break;
    --level;
  }
  ValueHistogram h;
  h.level = level;
  h.lo = store.node(0).minValue;
  h.hi = histogramTop(h.lo, store.node(0).maxValue);
  std::vector<int> counts(static_cast<std::size_t>(bins), 0);
  const int B = layout.brickSize(), A = layout.border(), E = layout.storedEdge();
  const auto& dims = layout.levelDims(level);
  const int64_t first = layout.levelNodeOffset(level), last = layout.levelNodeOffset(level + 1);
  for (int64_t id = first; id < last; ++id) {
    Brick b;
    try {
      b = store.readBrick(id);
    } catch (const Error& e) {
      h.problem = e.what();
      break;
    }
    const auto key = layout.nodeKey(id);
    for (int z = 0; z < B && key.brick[2] * B + z < dims[2]; ++z) {
      for (int y = 0; y < B && key.brick[1] * B + y < dims[1]; ++y) {
        for (int x = 0; x < B && key.brick[0] * B + x < dims[0]; ++x) {
          const std::size_t i = (static_cast<std::size_t>(z + A) * E + (y + A)) * E + (x + A);
          const double v = store.physical(b.format == SampleFormat::UInt16 ? b.u16[i] : b.f32[i]);
          ++counts[static_cast<std::size_t>(histogramBin(v, h.lo, h.hi, bins))];
        }
      }
    }
  }
  h.counts = std::move(counts);
  return h;
}

}  // namespace octoray::volume
