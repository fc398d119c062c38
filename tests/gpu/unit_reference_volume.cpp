// The reference volume: loading from a VolumeSource and from an octree store's leaf bricks
// gives the same samples; trilinear sampling with clamping at the domain's faces.

#include <fmt/format.h>
#include <gtest/gtest.h>

#include "memory_volume.h"
#include "octoray/core/error.h"
#include "octoray/gpu/reference/reference_volume.h"
#include "octoray/volume/store_builder.h"
#include "octoray/volume/store_reader.h"
#include "test_paths.h"

namespace octoray::test {
namespace {

using gpu::reference::ReferenceVolume;

float valueAt(int64_t i, int64_t j, int64_t k) {
  return static_cast<float>((i * 37 + j * 11 + k * 101) % 700 - 300);
}

TEST(ReferenceVolume, SourceAndStoreAgree) {
  // Sizes that are not multiples of the brick size, so partial leaf bricks are read too.
  MemoryVolume source({37, 21, 19}, valueAt);
  const ReferenceVolume fromSource = ReferenceVolume::fromSource(source);
  const auto dir = freshTempDir("store");
  for (int brickSize : {16, 32}) {
    volume::BuildOptions options;
    options.brickSize = brickSize;
    const std::string path = (dir / fmt::format("v{}.octoray", brickSize)).string();
    volume::buildStore(source, path, options);
    const volume::StoreReader store(path);
    const ReferenceVolume fromStore = ReferenceVolume::fromStore(store);
    ASSERT_EQ(fromStore.dims(), fromSource.dims());
    EXPECT_EQ(fromStore.values(), fromSource.values());
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c)
        EXPECT_DOUBLE_EQ(fromStore.patientFromIndex().m[r][c],
                         source.info().patientFromIndex.m[r][c]);
  }
  for (int64_t k : {0, 7, 18}) EXPECT_EQ(fromSource.at(36, 20, k), valueAt(36, 20, k));
}

TEST(ReferenceVolume, TrilinearWithClampedFaces) {
  MemoryVolume source({3, 2, 2}, [](int64_t i, int64_t j, int64_t k) {
    return static_cast<float>(i + 10 * j + 100 * k);
  });
  const ReferenceVolume v = ReferenceVolume::fromSource(source);
  EXPECT_DOUBLE_EQ(v.sample(1.25, 0.5, 0.75), 1.25 + 5 + 75);  // linear data: exact
  EXPECT_DOUBLE_EQ(v.sample(-0.5, -0.5, -0.5), 0.0);           // clamped to the edge sample
  EXPECT_DOUBLE_EQ(v.sample(2.5, 1.5, 1.5), 112.0);
  EXPECT_DOUBLE_EQ(v.sample(2.0, 1.0, 1.0), 112.0);
  EXPECT_THROW(ReferenceVolume({2, 2, 2}, Mat4{}, std::vector<float>(7)), Error);
  EXPECT_THROW(ReferenceVolume({2, 2, 0}, Mat4{}, {}), Error);
}

}  // namespace
}  // namespace octoray::test
