// Precomputed gradients (paper §4): the unit patient-space gradient in RGB and its norm in A.
#include <gtest/gtest.h>

#include <cmath>

#include "memory_volume.h"
#include "store_leaf_check.h"
#include "octoray/volume/store_builder.h"
#include "octoray/volume/store_reader.h"
#include "test_paths.h"

namespace octoray::volume {
namespace {

TEST(StoreGradients, LinearRampGivesItsPatientSpaceGradientEverywhereInside) {
  // value = 3i + 2j + k on the MemoryVolume's sheared affine: the patient-space gradient is
  // (indexFromPatient)^T (3, 2, 1), the same at every sample and on every level.
  test::MemoryVolume volume({40, 36, 34}, [](int64_t i, int64_t j, int64_t k) {
    return static_cast<float>(3 * i + 2 * j + k);
  });
  const Mat4 inv = volume.info().patientFromIndex.inverseAffine();
  const Vec3 g{inv.m[0][0] * 3 + inv.m[1][0] * 2 + inv.m[2][0] * 1,
               inv.m[0][1] * 3 + inv.m[1][1] * 2 + inv.m[2][1] * 1,
               inv.m[0][2] * 3 + inv.m[1][2] * 2 + inv.m[2][2] * 1};
  const Vec3 unit = normalize(g);

  const std::string path = (test::freshTempDir("gradients") / "g.octoray").string();
  BuildOptions options;
  options.brickSize = 16;
  options.border = 2;
  options.gradients = true;
  buildStore(volume, path, options);
  test::expectStoreValid(path);
  const StoreReader store(path);
  ASSERT_TRUE(store.header().flags & kStoreHasGradients);
  const double scale = store.header().gradientScale;
  ASSERT_GT(scale, 0);

  const OctreeLayout& layout = store.layout();
  const int E = layout.storedEdge(), B = layout.brickSize(), A = layout.border();
  int checked = 0;
  for (int64_t id = layout.levelNodeOffset(layout.leafLevel()); id < layout.nodeCount(); ++id) {
    const NodeKey key = layout.nodeKey(id);
    const Brick brick = store.readBrick(id);
    ASSERT_EQ(brick.gradients.size(), static_cast<std::size_t>(E) * E * E * 4);
    for (int z = 0; z < E; ++z)
      for (int y = 0; y < E; ++y)
        for (int x = 0; x < E; ++x) {
          // Central differences are exact for a linear function away from the clamped edge.
          const int64_t gi = key.brick[0] * B - A + x, gj = key.brick[1] * B - A + y,
                        gk = key.brick[2] * B - A + z;
          if (gi < 1 || gj < 1 || gk < 1 || gi > 38 || gj > 34 || gk > 32) continue;
          const uint8_t* rgba = &brick.gradients[4 * (static_cast<std::size_t>(x) + E * (y + static_cast<std::size_t>(E) * z))];
          const auto decode = [](uint8_t c) { return c / 255.0 * 2.0 - 1.0; };
          EXPECT_NEAR(decode(rgba[0]), unit.x, 1.0 / 255 + 1e-9);
          EXPECT_NEAR(decode(rgba[1]), unit.y, 1.0 / 255 + 1e-9);
          EXPECT_NEAR(decode(rgba[2]), unit.z, 1.0 / 255 + 1e-9);
          EXPECT_NEAR(rgba[3], std::min(1.0, length(g) / scale) * 255.0, 0.5 + 1e-9);
          ++checked;
        }
  }
  EXPECT_GT(checked, 30000);
}

TEST(StoreGradients, ConstantVolumeHasZeroNormAndNoNaN) {
  test::MemoryVolume volume({20, 20, 20}, [](int64_t, int64_t, int64_t) { return 40.0f; });
  const std::string path = (test::freshTempDir("flat") / "f.octoray").string();
  BuildOptions options;
  options.brickSize = 16;
  options.gradients = true;
  buildStore(volume, path, options);
  const StoreReader store(path);
  for (int64_t id = 0; id < store.layout().nodeCount(); ++id) {
    const Brick brick = store.readBrick(id);
    for (std::size_t i = 0; i < brick.gradients.size(); i += 4) ASSERT_EQ(brick.gradients[i + 3], 0);
  }
}

}  // namespace
}  // namespace octoray::volume
