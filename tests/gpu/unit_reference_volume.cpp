// The reference volume: loading from a VolumeSource and from an octree store's leaf bricks
// gives the same samples; trilinear sampling with clamping at the domain's faces; an LOD cut
// samples each leaf at its brick's level, in the octree's geometry.

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <optional>
#include <random>

#include "memory_volume.h"
#include "render_test_support.h"
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


// A store of f = i + 2j + 4k (float samples, 64^3 in 16^3 bricks: levels of 16, 32 and 64
// samples). Every level of a linear function holds the same function: a level sample
// averages 2x2x2 finer ones around its centre, and a linear function's average is its value
// at the centre. So a cut at any levels must return f wherever the coarsest level used still
// interpolates (leaf index 1.5 .. 61.5), if it maps points to level samples right.
class CutVolume : public ::testing::Test {
 protected:
  static double f(double i, double j, double k) { return i + 2 * j + 4 * k; }
  void SetUp() override {
    MemoryVolume source({64, 64, 64}, [](int64_t i, int64_t j, int64_t k) {
      return static_cast<float>(f(static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)));
    }, "HU", false);
    volume::BuildOptions options;
    options.brickSize = 16;
    options.format = volume::BuildOptions::Format::Float32;
    path_ = (freshTempDir("cut_volume") / "linear.octoray").string();
    volume::buildStore(source, path_, options);
    store_.emplace(path_);
    ASSERT_EQ(store_->layout().levels(), 3);
  }
  gpu::reference::CutLeafRef leaf(int level, int64_t x, int64_t y, int64_t z, int up = 0) const {
    return {volume::NodeKey{level, {x, y, z}}, up};
  }
  std::string path_;
  std::optional<volume::StoreReader> store_;
};

TEST_F(CutVolume, EveryLeafBrickIsTheFullVolume) {
  std::vector<gpu::reference::CutLeafRef> leaves;
  for (int64_t z = 0; z < 4; ++z)
    for (int64_t y = 0; y < 4; ++y)
      for (int64_t x = 0; x < 4; ++x) leaves.push_back(leaf(2, x, y, z));
  const ReferenceVolume cut = ReferenceVolume::fromCut(*store_, leaves);
  const ReferenceVolume full = ReferenceVolume::fromStore(*store_);
  EXPECT_TRUE(cut.isCut());
  EXPECT_FALSE(full.isCut());
  EXPECT_EQ(cut.dims(), full.dims());
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-0.5, 63.5);
  for (int n = 0; n < 2000; ++n) {
    const double i = u(rng), j = u(rng), k = u(rng);
    ASSERT_EQ(cut.sample(i, j, k), full.sample(i, j, k)) << i << " " << j << " " << k;
  }
}

TEST_F(CutVolume, CoarseLeavesSampleTheirLevelInTheOctreesGeometry) {
  // The root's 8 children (level 1), one of them refined into its 8 children (level 2), and
  // one level-1 leaf drawn from the root's brick (one level up).
  std::vector<gpu::reference::CutLeafRef> leaves;
  for (int64_t z = 0; z < 2; ++z)
    for (int64_t y = 0; y < 2; ++y)
      for (int64_t x = 0; x < 2; ++x) {
        if (x == 1 && y == 0 && z == 0) {
          for (int64_t c = 0; c < 8; ++c) leaves.push_back(leaf(2, 2 + (c & 1), (c >> 1) & 1, c >> 2));
        } else {
          leaves.push_back(leaf(1, x, y, z, x == 0 && y == 1 && z == 1 ? 1 : 0));
        }
      }
  const ReferenceVolume cut = ReferenceVolume::fromCut(*store_, leaves);
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(1.5, 61.5);
  for (int n = 0; n < 4000; ++n) {
    const double i = u(rng), j = u(rng), k = u(rng);
    ASSERT_NEAR(cut.sample(i, j, k), f(i, j, k), 1e-9) << i << " " << j << " " << k;
  }
  // The gradient: +-0.5 voxels of the leaf's level (a border of one sample), i.e. +-2 leaf
  // voxels in the leaf drawn from the root; away from the faces by that much it is f's.
  std::uniform_real_distribution<double> inner(3.5, 59.5);
  for (int n = 0; n < 2000; ++n) {
    const Vec3 p{inner(rng), inner(rng), inner(rng)};
    const Vec3 g = cut.gradientIndex(p);
    ASSERT_NEAR(g.x, 1.0, 1e-9) << p.x << " " << p.y << " " << p.z;
    ASSERT_NEAR(g.y, 2.0, 1e-9);
    ASSERT_NEAR(g.z, 4.0, 1e-9);
  }
  // Near the faces a coarse level clamps earlier than the leaf level: the root's first
  // sample sits at leaf index 1.5 and extends to the face, the leaf level's at 0.
  const double rootEdge = f(1.5, 40, 40);  // in the leaf drawn from the root (x < 32, y, z >= 32)
  EXPECT_NEAR(cut.sample(-0.5, 40, 40), rootEdge, 1e-9);
  EXPECT_NEAR(cut.sample(0.0, 40, 40), rootEdge, 1e-9);
  // A level-1 leaf's first sample sits at 0.5: (0.5, 0.5, 0.5) in leaf (0, 0, 0).
  EXPECT_NEAR(cut.sample(-0.5, -0.5, -0.5), f(0.5, 0.5, 0.5), 1e-9);
}

TEST_F(CutVolume, PointsNoLeafHoldsAreEmptyAndBadCutsAreRefused) {
  const std::vector<gpu::reference::CutLeafRef> one{leaf(1, 0, 0, 0)};
  const ReferenceVolume cut = ReferenceVolume::fromCut(*store_, one);
  EXPECT_NEAR(cut.sample(10, 10, 10), f(10, 10, 10), 1e-9);
  EXPECT_TRUE(std::isnan(cut.sample(40, 10, 10)));
  EXPECT_TRUE(std::isnan(cut.sample(31.5, 10, 10))) << "cell 32 belongs to the next leaf";
  const Vec3 g = cut.gradientIndex({40, 10, 10});
  EXPECT_EQ(g.x, 0.0);
  const auto refused = [&](std::vector<gpu::reference::CutLeafRef> leaves, const std::string& what) {
    try {
      ReferenceVolume::fromCut(*store_, leaves);
      ADD_FAILURE() << "accepted: " << what;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
    }
  };
  refused({leaf(0, 0, 0, 0), leaf(1, 1, 1, 1)}, "overlap");
  refused({leaf(1, 1, 1, 1), leaf(1, 1, 1, 1)}, "listed twice");
  refused({leaf(1, 2, 0, 0)}, "not a node of the store");
  refused({leaf(3, 0, 0, 0)}, "not a node of the store");
  refused({leaf(1, 0, 0, 0, 2)}, "not a node of the store");
}

// The exact MIP splits chords at the leaf level's voxel-centre planes: right over a cut of
// leaf-level bricks (the full volume where it has leaves), refused over coarse leaves.
TEST_F(CutVolume, MipOverLeafLevelCutsOnly) {
  gpu::reference::RenderOptions mip;
  mip.mode = gpu::reference::RenderMode::Mip;
  const auto tf = constantTf(1);
  // Along x through leaf-level bricks (x, 0, 1), in patient space (the store's grid is sheared).
  const Mat4& m = store_->patientFromIndex();
  const Vec3 origin = m.transformPoint({-20, 10.3, 20.7}), direction = m.transformVector({1, 0.02, 0.03});
  std::vector<gpu::reference::CutLeafRef> leafLevel;
  for (int64_t x = 0; x < 4; ++x) leafLevel.push_back(leaf(2, x, 0, 1));
  const ReferenceVolume fine = ReferenceVolume::fromCut(*store_, leafLevel);
  EXPECT_FALSE(fine.hasCoarseLeaves());
  const ReferenceVolume full = ReferenceVolume::fromStore(*store_);
  EXPECT_FALSE(full.hasCoarseLeaves());
  const double fullMax = renderRay(full, tf, mip, origin, direction).value;
  EXPECT_GT(fullMax, f(60, 10, 20)) << "the ray crosses the volume";
  EXPECT_EQ(renderRay(fine, tf, mip, origin, direction).value, fullMax);
  const std::vector<gpu::reference::CutLeafRef> coarse{leaf(1, 0, 0, 0)};
  const ReferenceVolume cut = ReferenceVolume::fromCut(*store_, coarse);
  EXPECT_TRUE(cut.hasCoarseLeaves());
  EXPECT_THROW(renderRay(cut, tf, mip, origin, direction), Error);
}

}  // namespace
}  // namespace octoray::test
