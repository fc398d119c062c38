// Adaptive sampling in the image plane (paper 002, raycast.frag.glsl): a vanishing error bound
// must give the full picture bit for bit with fewer rays (background pixels copied or
// interpolated from identical neighbours); the default bound must cast at most half the rays
// and lose at most 1 dB against the converged truth on a band-limited phantom in DVR; MIP and
// isosurfaces must work through it too.

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>

#include "gl_test_support.h"
#include "octoray/gpu/camera.h"
#include "octoray/gpu/gpu_renderer.h"
#include "octoray/gpu/image_metrics.h"
#include "octoray/gpu/reference/reference_renderer.h"
#include "octoray/transfer/transfer_function_io.h"
#include "octoray/volume/phantom.h"
#include "octoray/volume/store_reader.h"
#include "test_paths.h"
#include "test_stores.h"

namespace octoray::gpu {
namespace {

const std::filesystem::path& adaptivePhantomStore() {
  static const std::filesystem::path path = [] {
    volume::PhantomOptions options;
    options.dims = {96, 96, 80};
    options.spacingMm = {0.7, 0.7, 0.9};
    return test::buildPhantomTestStore(options, "gl_image_adaptive", 16);
  }();
  return path;
}

Camera view(const volume::StoreReader& store, int size) {
  OrbitParameters o;
  o.azimuthDegrees = 30;
  o.elevationDegrees = 15;
  o.width = o.height = size;
  return orbitCamera({store.layout().levelDims(store.layout().leafLevel()), store.patientFromIndex()}, o);
}

class ImageAdaptiveTest : public GlTest {};

TEST_F(ImageAdaptiveTest, AVanishingBoundIsExactWithFewerRays) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const volume::StoreReader store(adaptivePhantomStore().string());
  GpuRenderer renderer(store);
  const Camera camera = view(store, 128);
  const transfer::TransferFunction tf = transfer::findPreset("bone");
  for (const RaycastMode mode : {RaycastMode::Dvr, RaycastMode::Mip, RaycastMode::Iso}) {
    RaycastOptions options;
    options.mode = mode;
    options.isoValue = 300;
    options.lodPixels = 0;
    const Frame full = renderer.render(camera, tf, options);
    EXPECT_EQ(full.stats.raysCast, 128 * 128);
    options.imageAdaptive = 1e-12;
    for (const int levels : {1, 2, 3}) {
      options.imageAdaptiveLevels = levels;
      const Frame adaptive = renderer.render(camera, tf, options);
      EXPECT_EQ(adaptive.image.rgba, full.image.rgba) << "mode " << static_cast<int>(mode) << " levels " << levels;
      EXPECT_LT(adaptive.stats.raysCast, full.stats.raysCast) << "the background should not need rays";
      EXPECT_GT(adaptive.stats.raysCast, full.stats.raysCast / 8);
    }
  }
  EXPECT_TRUE(context_->takeErrors().empty());
}

// The adaptive passes carry each pixel's depth in the aux target and fill the depth buffer
// from it at the end (raycast.frag.glsl's early stencil test leaves gl_FragDepth unused); the
// occlusion queries test the cut's bricks against that buffer. With a vanishing bound the
// buffer must be the full frame's: the same leaves hidden, the same working set, the same
// picture.
TEST_F(ImageAdaptiveTest, OcclusionQueriesSeeTheSameDepthAsWithEveryRayCast) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const volume::StoreReader store(adaptivePhantomStore().string());
  RendererConfig config;
  config.visibility = Visibility::Occlusion;
  config.visibilityThreshold = 1;
  const Camera camera = view(store, 128);
  const transfer::TransferFunction tf = transfer::findPreset("bone");
  RaycastOptions options;
  options.lodPixels = 0;
  GpuRenderer fullRenderer(store, config);
  const Frame full = fullRenderer.render(camera, tf, options);
  options.imageAdaptive = 1e-12;
  GpuRenderer adaptiveRenderer(store, config);
  const Frame adaptive = adaptiveRenderer.render(camera, tf, options);
  const WorkingSetStats& f = full.stats.workingSet;
  const WorkingSetStats& a = adaptive.stats.workingSet;
  std::printf("hidden leaves: every ray cast %lld, adaptive %lld; bricks %lld / %lld; rays %lld / %lld\n",
              static_cast<long long>(f.hiddenLeaves), static_cast<long long>(a.hiddenLeaves),
              static_cast<long long>(full.stats.workingSetBricks), static_cast<long long>(adaptive.stats.workingSetBricks),
              static_cast<long long>(full.stats.raysCast), static_cast<long long>(adaptive.stats.raysCast));
  EXPECT_GT(f.hiddenLeaves, 0) << "the bone hides some of the cut, or this test shows nothing";
  EXPECT_LT(f.hiddenLeaves, f.leaves);
  EXPECT_EQ(a.hiddenLeaves, f.hiddenLeaves);
  EXPECT_EQ(adaptive.stats.workingSetBricks, full.stats.workingSetBricks);
  EXPECT_EQ(adaptive.image.rgba, full.image.rgba);
  EXPECT_LT(adaptive.stats.raysCast, full.stats.raysCast);
  EXPECT_TRUE(context_->takeErrors().empty());
}

TEST_F(ImageAdaptiveTest, DefaultBoundHalvesTheRaysWithinADecibelOfTheTruth) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const volume::StoreReader store(adaptivePhantomStore().string());
  GpuRenderer renderer(store);
  const Camera camera = view(store, 128);
  const transfer::TransferFunction tf = transfer::findPreset("bone");
  RaycastOptions options;
  options.lodPixels = 0;
  options.stats = true;
  const Frame full = renderer.render(camera, tf, options);
  options.imageAdaptive = kImageAdaptiveDefaultThreshold;
  const Frame adaptive = renderer.render(camera, tf, options);
  // The truth: the reference, converged.
  const reference::ReferenceVolume volume = reference::ReferenceVolume::fromStore(store);
  reference::RenderOptions truthOptions;
  truthOptions.preintegration = true;
  truthOptions.earlyTermination = options.earlyTermination;
  reference::ReferenceRenderer::ConvergenceRule rule;
  rule.maxChange = 0.02;  // any pixel (grazing rays at silhouettes converge last)
  rule.minPsnrDb = 55;
  rule.maxHalvings = 4;
  const auto truth = reference::ReferenceRenderer(volume).renderConverged(camera, tf, truthOptions, rule);
  ASSERT_TRUE(truth.converged);
  const double fullDb = compare(truth.result.image, full.image).psnrDb;
  const double adaptiveDb = compare(truth.result.image, adaptive.image).psnrDb;
  const double rays = static_cast<double>(adaptive.stats.raysCast) / static_cast<double>(full.stats.raysCast);
  std::printf("rays %.3f of full, samples %lld of %lld; against the truth (%s at %.3g mm): full %.2f dB, "
              "adaptive %.2f dB\n",
              rays, static_cast<long long>(adaptive.stats.samplesTaken),
              static_cast<long long>(full.stats.samplesTaken), truth.converged ? "converged" : "not converged",
              truth.result.stats.stepMm, fullDb, adaptiveDb);
  EXPECT_LE(rays, 0.5);
  EXPECT_GE(adaptiveDb, fullDb - 1.0);
  EXPECT_GE(fullDb, 35.0);  // a truth worth the name, and a picture that matches it
  EXPECT_GT(adaptive.stats.samplesTaken, 0);
  EXPECT_LT(adaptive.stats.samplesTaken, full.stats.samplesTaken);
  EXPECT_TRUE(context_->takeErrors().empty());
}

TEST_F(ImageAdaptiveTest, BadBoundsAreRejected) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const volume::StoreReader store(adaptivePhantomStore().string());
  GpuRenderer renderer(store);
  const Camera camera = view(store, 32);
  const transfer::TransferFunction tf = transfer::findPreset("bone");
  RaycastOptions options;
  options.imageAdaptive = -1;
  EXPECT_THROW(renderer.render(camera, tf, options), Error);
  options.imageAdaptive = std::nan("");
  EXPECT_THROW(renderer.render(camera, tf, options), Error);
  options.imageAdaptive = 0.02;
  options.imageAdaptiveLevels = 5;
  EXPECT_THROW(renderer.render(camera, tf, options), Error);
}

}  // namespace
}  // namespace octoray::gpu
