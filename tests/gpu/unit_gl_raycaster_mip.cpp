// The GPU raycaster's MIP against the CPU reference: the exact maximum equal to the reference's
// at 16 bits, the sampled one never above it, and cell skipping changing no visible maximum.

#include <gtest/gtest.h>

#include "raycaster_test_support.h"

namespace octoray::gpu {
namespace {

using namespace raycaster_test;

TEST_F(RaycasterTest, MipEqualsTheReferenceAtSixteenBits) {
  OCTORAY_GL_TEST_PREAMBLE();
  const volume::StoreReader store(phantomStore().string());
  RaycastOptions options;
  options.mode = RaycastMode::Mip;
  options.lodPixels = 0;
  const transfer::TransferFunction tf = transfer::findPreset("bone");
  for (const Projection projection : {Projection::Perspective, Projection::Orthographic}) {
    const Camera camera = orbit(store, 250, 40, 96, projection);
    const Pair p = renderBoth(store, camera, tf, options);
    // One 16-bit stored step, in HU.
    const MipAgreement a = mipAgreement(p.gpu.value, p.reference.value, tf, store.header().valueScale);
    EXPECT_EQ(a.invisibleShown, 0);
    EXPECT_EQ(a.missed, 0) << "visible maxima missed by the GPU";
    EXPECT_GT(a.hits, 1000);
    EXPECT_EQ(a.differ, 0) << "worst difference " << a.worst << " HU";
  }
}

// The sampled MIP takes the interpolant at the step's samples only: never above the exact
// maximum beyond the filtering hardware's precision (GL lets texture filtering weights have
// 8 fractional bits, as llvmpipe's do: up to 1/256 of the value range), and close to it.
TEST_F(RaycasterTest, SampledMipNeverExceedsTheExactMaximum) {
  OCTORAY_GL_TEST_PREAMBLE();
  const volume::StoreReader store(phantomStore().string());
  GpuRenderer renderer(store);
  const transfer::TransferFunction tf = transfer::findPreset("bone");
  const Camera camera = orbit(store, 300, 20, 96);
  RaycastOptions options;
  options.mode = RaycastMode::Mip;
  options.lodPixels = 0;
  const Frame exact = renderer.render(camera, tf, options);
  options.mip = RaycastOptions::MipMethod::Sampled;
  const Frame sampled = renderer.render(camera, tf, options);
  const double filtering = (store.node(0).maxValue - store.node(0).minValue) / 256.0;
  int64_t lower = 0, hits = 0, unsampled = 0;
  for (std::size_t i = 0; i < exact.value.size(); ++i) {
    if (std::isnan(exact.value[i])) {  // no maximum found, or none that shows
      const float s = sampled.value[i];
      EXPECT_TRUE(std::isnan(s) || !(reference::classify(tf, s).alpha > 0)) << "pixel " << i;
      continue;
    }
    if (std::isnan(sampled.value[i])) {  // the chord's part in data leaves holds no sample
      ++unsampled;
      continue;
    }
    // Below the TF's first opacity the MIP picture is black whatever the maximum, and the
    // working set does not refine nodes whose range stays there (the MIP threshold): the
    // maxima are compared where they are seen.
    if (!(reference::classify(tf, exact.value[i]).alpha > 0)) continue;
    ++hits;
    EXPECT_LE(sampled.value[i], exact.value[i] + filtering) << "pixel " << i;
    lower += sampled.value[i] < exact.value[i] - filtering ? 1 : 0;
  }
  EXPECT_GT(hits, 1000);
  EXPECT_LT(unsampled, hits / 100);
  EXPECT_GT(lower, 0) << "sampling should miss some peaks between samples";
  EXPECT_GE(compare(exact.image, sampled.image).psnrDb, 40.0);
  EXPECT_EQ(nonFinite(sampled), 0);
  EXPECT_TRUE(context_->takeErrors().empty());
}


// The exact MIP crosses groups of cells that cannot raise the maximum, or whose values all
// show black, in one step: the same picture and depths bit for bit, the same visible maxima,
// from far fewer cells evaluated. Invisible maxima may be left unfound (NaN), never shown.
TEST_F(RaycasterTest, MipCellSkippingChangesNoPixelAndVisitsFewerCells) {
  OCTORAY_GL_TEST_PREAMBLE();
  const auto sameBits = [](float a, float b) { return std::memcmp(&a, &b, sizeof a) == 0; };
  for (const std::filesystem::path* path : {&phantomStore(), &rampStore()}) {
    const volume::StoreReader store(path->string());
    GpuRenderer renderer(store);
    const transfer::TransferFunction tf = transfer::findPreset("bone");
    const auto visible = [&](float v) { return !std::isnan(v) && tf.evaluate(v)[3] > 0; };
    for (const Projection projection : {Projection::Perspective, Projection::Orthographic}) {
      RaycastOptions options;
      options.mode = RaycastMode::Mip;
      options.lodPixels = 0;
      options.stats = true;
      const Camera camera = orbit(store, 250, 40, 96, projection);
      const Frame skipping = renderer.render(camera, tf, options);
      options.cellSkipping = false;
      const Frame evaluating = renderer.render(camera, tf, options);
      EXPECT_EQ(skipping.image.rgba, evaluating.image.rgba) << path->filename();
      ASSERT_EQ(skipping.value.size(), evaluating.value.size());
      int64_t visibleMaxima = 0, differ = 0, invisibleShown = 0;
      for (std::size_t i = 0; i < evaluating.value.size(); ++i) {
        if (visible(evaluating.value[i])) {
          ++visibleMaxima;
          differ += sameBits(skipping.value[i], evaluating.value[i]) &&
                            sameBits(skipping.image.depth[i], evaluating.image.depth[i])
                        ? 0
                        : 1;
        } else {
          invisibleShown += visible(skipping.value[i]) ? 1 : 0;
        }
      }
      EXPECT_GT(visibleMaxima, 1000) << path->filename();
      EXPECT_EQ(differ, 0) << path->filename() << ": visible maxima or their depths differ";
      EXPECT_EQ(invisibleShown, 0) << path->filename();
      // On the ramp the maximum rises toward one end of most chords: little to skip there.
      if (path == &phantomStore()) {
        EXPECT_LT(skipping.stats.samplesPerPixel, 0.8 * evaluating.stats.samplesPerPixel);
      }
    }
  }
  EXPECT_TRUE(context_->takeErrors().empty());
}


}  // namespace
}  // namespace octoray::gpu
