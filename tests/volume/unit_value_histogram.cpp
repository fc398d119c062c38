// The histogram the automatic window and isovalue read (value_histogram.h): which level it
// counts, and its counts against values computed here from the source, not read back through
// the store.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <iterator>
#include <vector>

#include "memory_volume.h"
#include "octoray/volume/store_reader.h"
#include "octoray/volume/value_histogram.h"
#include "test_stores.h"

namespace octoray::volume {
namespace {

using test::MemoryVolume;

// The store of `volume` with 32^3 bricks (test_stores.h).
std::string build(MemoryVolume& volume, const std::string& name) {
  return test::buildTestStore(volume, "value_histogram_" + name, 32, 1).string();
}

// 256 bins over [lo, hi], counted here.
std::vector<int> expectedCounts(const std::vector<float>& values, double lo, double hi) {
  std::vector<int> counts(256, 0);
  for (const float v : values) {
    const int bin = std::min(255, static_cast<int>(std::floor((v - lo) / (hi - lo) * 256)));
    ++counts[static_cast<std::size_t>(std::max(0, bin))];
  }
  return counts;
}

// A value constant over each 2 x 2 x 2 block, so the builder's box-filtered level one step
// coarser holds exactly f of the block's index.
float blockValue(int64_t i, int64_t j, int64_t k) {
  return static_cast<float>((i / 2 * 37 + j / 2 * 11 + k / 2 * 101) % 1500 - 700);
}

// 256 x 256 x 80 (5.2 Mi samples) is over the 4 Mi budget: the level above the leaves,
// 128 x 128 x 40, is counted, and it holds the blocks' values exactly.
TEST(ValueHistogram, CountsTheFinestLevelWithinItsBudget) {
  MemoryVolume volume({256, 256, 80}, blockValue);
  const StoreReader store(build(volume, "blocks"));
  const ValueHistogram h = storeHistogram(store, 256);
  EXPECT_TRUE(h.problem.empty()) << h.problem;
  EXPECT_EQ(h.level, store.layout().leafLevel() - 1);
  std::vector<float> coarse;
  for (int64_t k = 0; k < 40; ++k)
    for (int64_t j = 0; j < 128; ++j)
      for (int64_t i = 0; i < 128; ++i) coarse.push_back(blockValue(2 * i, 2 * j, 2 * k));
  // The bins span the whole volume's range (the root node's), here the blocks' own.
  const auto [lo, hi] = std::minmax_element(coarse.begin(), coarse.end());
  EXPECT_EQ(h.lo, *lo);
  EXPECT_EQ(h.hi, *hi);
  EXPECT_EQ(h.counts, expectedCounts(coarse, *lo, *hi));

  // A small volume is counted whole, every leaf sample once.
  MemoryVolume small({70, 45, 33}, [](int64_t i, int64_t j, int64_t k) {
    return static_cast<float>((i * 7 + j * 13 + k * 5) % 301 - 150);
  });
  const StoreReader smallStore(build(small, "small"));
  const ValueHistogram s = storeHistogram(smallStore, 256);
  EXPECT_EQ(s.level, smallStore.layout().leafLevel());
  std::vector<float> all;
  for (int64_t k = 0; k < 33; ++k)
    for (int64_t j = 0; j < 45; ++j)
      for (int64_t i = 0; i < 70; ++i) all.push_back(small.at(i, j, k));
  EXPECT_EQ(s.counts, expectedCounts(all, -150, 150));
}

// A thin volume of exactly 4 Mi samples (1024 x 1024 x 4) has 1,024 leaf bricks: over the
// 256-brick limit, so the next level (512 x 512 x 2, 256 bricks) is counted.
TEST(ValueHistogram, ReadsAtMost256Bricks) {
  MemoryVolume thin({1024, 1024, 4}, blockValue);
  const StoreReader store(build(thin, "thin"));
  const ValueHistogram h = storeHistogram(store, 256);
  EXPECT_EQ(h.level, store.layout().leafLevel() - 1);
  int64_t total = 0;
  for (const int c : h.counts) total += c;
  EXPECT_EQ(total, 512 * 512 * 2);
}

// A constant volume: the bins span one unit above its value, and every sample is in the first.
TEST(ValueHistogram, AConstantVolumeSpansOneUnit) {
  MemoryVolume flat({40, 40, 40}, [](int64_t, int64_t, int64_t) { return 35.0f; });
  const ValueHistogram h = storeHistogram(StoreReader(build(flat, "flat")), 256);
  EXPECT_EQ(h.lo, 35);
  EXPECT_EQ(h.hi, 36);
  EXPECT_EQ(h.counts[0], 40 * 40 * 40);
}

// A brick that fails its checksum: the store's message naming the file, not an exception;
// the counts hold the bricks read before it.
TEST(ValueHistogram, ADamagedBrickIsNamedNotThrown) {
  MemoryVolume volume({70, 45, 33}, [](int64_t i, int64_t j, int64_t k) {
    return static_cast<float>((i * 7 + j * 13 + k * 5) % 301 - 150);
  });
  const std::string path = build(volume, "damaged");
  int64_t damagedId = -1;
  uint64_t at = 0;
  {
    const StoreReader store(path);
    const auto& layout = store.layout();
    for (int64_t id = layout.levelNodeOffset(layout.leafLevel()); id < layout.nodeCount(); ++id) {
      if (store.node(id).payloadBytes > 0) {
        damagedId = id;
        at = store.node(id).payloadOffset + store.node(id).payloadBytes / 2;
        break;
      }
    }
  }
  ASSERT_GE(damagedId, 0);
  std::vector<char> bytes;
  {
    std::ifstream in(path, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
  }
  bytes[at] ^= 0x20;
  std::ofstream(path, std::ios::binary | std::ios::trunc).write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  const StoreReader store(path);
  ValueHistogram h;
  ASSERT_NO_THROW(h = storeHistogram(store, 256));
  EXPECT_NE(h.problem.find(path), std::string::npos) << h.problem;
  EXPECT_NE(h.problem.find("checksum"), std::string::npos) << h.problem;
  int64_t total = 0;
  for (const int c : h.counts) total += c;
  EXPECT_LT(total, 70 * 45 * 33);
}

}  // namespace
}  // namespace octoray::volume
