// The converged truth (ReferenceRenderer::renderConverged) and what approaches it: on a
// volume whose interpolant is exactly linear along every ray, with a thin-shell transfer
// function (opacity 0 -> 0.9 -> 0 over 680..720 HU, one colour), every pixel has a closed-form
// value. The midpoint rule must converge to it at order 2, pre-integration must be near exact
// at any step, jitter must not move the mean, and the converged truth must land on it.

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <numeric>
#include <vector>

#include "octoray/core/error.h"
#include "render_test_support.h"

namespace octoray::gpu::reference {
namespace {

using test::makeVolume;
using test::scaling;

constexpr double kHuPerVoxel = 20.0;  // v = 20 k: the shell (680..720 HU) spans k = 34..36

transfer::TransferFunction thinShell() {
  transfer::TransferFunction tf;
  tf.name = "thin shell";
  tf.color = {{0, 1.0f, 0.9f, 0.8f}};
  tf.opacity = {{680, 0.0f}, {700, 0.9f}, {720, 0.0f}};
  tf.material.shade = false;
  tf.unitDistanceMm = 1.0;
  return tf;
}

// Integral over the shell's values of the extinction -ln(1 - alpha(v)) (per unit distance):
// each half is 20 HU of alpha linear 0 -> 0.9, (20 / 0.9) * integral_0^0.9 -ln(1 - x) dx.
double shellExtinctionIntegral() {
  const double a = static_cast<double>(0.9f);  // the TF's opacity as stored
  const double half = (20.0 / a) * ((1.0 - a) * std::log1p(-a) + a);
  return 2.0 * half;
}

const ReferenceVolume& slab() {
  static const ReferenceVolume v = makeVolume({12, 12, 80}, scaling(1, 1, 1),
                                              [](int64_t, int64_t, int64_t k) { return kHuPerVoxel * k; });
  return v;
}

// A narrow perspective view up the z axis: every ray enters through the bottom face and
// leaves through the top one, crossing the whole shell, and each has its own slope, so the
// samples fall at a different phase against the shell on every ray.
Camera upTheSlab() {
  Camera c;
  c.projection = Projection::Perspective;
  c.eye = {5.3, 5.6, -40};
  c.target = {5.9, 5.1, 40};
  c.up = {0, 1, 0};
  c.fovYDegrees = 5;
  c.width = c.height = 24;
  return c;
}

// The closed-form opacity of a ray: dv/dt = 20 * direction.z, so its optical depth is the
// extinction integral over values divided by that; colour = (1, 0.9, 0.8) * alpha.
double trueAlpha(const Vec3& direction) {
  return 1.0 - std::exp(-shellExtinctionIntegral() / (kHuPerVoxel * normalize(direction).z));
}

// Mean and largest |error| of R and A over the pixels of a picture of upTheSlab().
struct RayErrors {
  double mean = 0, max = 0;
};
RayErrors errors(const Image& image) {
  const Camera c = upTheSlab();
  RayErrors e;
  for (int y = 0; y < c.height; ++y) {
    for (int x = 0; x < c.width; ++x) {
      const double alpha = trueAlpha(c.ray(x, y).direction);
      const float* p = image.pixel(x, y);
      const double err = std::max(std::abs(p[3] - alpha), std::abs(p[0] - alpha));
      e.mean += err / static_cast<double>(image.pixelCount());
      e.max = std::max(e.max, err);
    }
  }
  return e;
}
RayErrors errors(RenderOptions options, double stepMm) {
  options.stepMm = stepMm;
  options.earlyTermination = 1.0;
  return errors(ReferenceRenderer(slab()).render(upTheSlab(), thinShell(), options).image);
}

TEST(ReferenceTruth, MidpointRuleConvergesAtOrderTwo) {
  const Camera c = upTheSlab();
  for (const auto& [x, y] : {std::pair{0, 0}, std::pair{23, 23}}) {
    const double alpha = trueAlpha(c.ray(x, y).direction);
    ASSERT_GT(alpha, 0.5);  // a shell that matters
    ASSERT_LT(alpha, 0.999);
  }
  std::vector<double> steps{0.2, 0.1, 0.05, 0.025, 0.0125, 0.00625};
  std::vector<double> mean;
  for (double h : steps) mean.push_back(errors({}, h).mean);
  for (std::size_t i = 1; i < steps.size(); ++i) {
    const double order = std::log2(mean[i - 1] / mean[i]);
    std::printf("step %.4f mm: mean error %.3g (order %.2f)\n", steps[i], mean[i], order);
    EXPECT_LT(mean[i], 0.75 * mean[i - 1]) << "step " << steps[i];
    // Asymptotic once the step is a small fraction of the shell's 2 mm along the ray: the
    // midpoint rule's second order (coarser steps converge irregularly, faster or slower).
    if (steps[i] <= 0.0125) {
      EXPECT_GT(order, 1.7) << "step " << steps[i] << " error " << mean[i] << " after " << mean[i - 1];
      EXPECT_LT(order, 2.3) << "step " << steps[i] << " error " << mean[i] << " after " << mean[i - 1];
    }
  }
  EXPECT_LT(mean.back(), 1e-4);
}

TEST(ReferenceTruth, PreintegrationIsNearExactAtCoarseSteps) {
  RenderOptions pre;
  pre.preintegration = true;
  for (double h : {2.0, 1.0, 0.5}) {
    const RayErrors post = errors({}, h);
    const RayErrors p = errors(pre, h);
    // The interpolant is linear along each ray, so only the sub-step quadrature remains.
    EXPECT_LT(p.max, 1e-3) << "step " << h;
    EXPECT_LT(p.max, 0.1 * post.max) << "step " << h;
  }
  // And it converges to the same value as the midpoint rule.
  EXPECT_LT(errors(pre, 0.05).max, 1e-4);
}

TEST(ReferenceTruth, JitterTurnsRingsIntoZeroMeanNoise) {
  // At a 1 mm step (half the shell's thickness) the midpoint rule's error has a sign that
  // depends on where the samples fall; with jitter the error over many pixels averages out.
  const ReferenceVolume& v = slab();
  Camera camera;
  camera.projection = Projection::Orthographic;
  camera.eye = {5.5, 5.5, -20};
  camera.target = camera.eye + normalize(Vec3{0.05, 0.03, 1.0});
  camera.up = {0, 1, 0};
  camera.orthoHeightMm = 6;
  camera.width = camera.height = 48;
  RenderOptions o;
  o.stepMm = 1.0;
  o.earlyTermination = 1.0;
  const ReferenceRenderer renderer(v);
  const double alpha = 1.0 - std::exp(-shellExtinctionIntegral() / (kHuPerVoxel * normalize(camera.target - camera.eye).z));
  auto meanError = [&](const RenderResult& r) {
    double sum = 0;
    for (std::size_t i = 3; i < r.image.rgba.size(); i += 4) sum += r.image.rgba[i] - alpha;
    return sum / static_cast<double>(r.image.pixelCount());
  };
  const RenderResult plain = renderer.render(camera, thinShell(), o);
  o.jitter = true;
  const RenderResult jittered = renderer.render(camera, thinShell(), o);
  EXPECT_LT(std::abs(meanError(jittered)), 0.5 * std::abs(meanError(plain)))
      << "plain " << meanError(plain) << ", jittered " << meanError(jittered);
  // Deterministic: the same hash every time, and a spread of offsets.
  EXPECT_EQ(rayJitter(3, 4), rayJitter(3, 4));
  double lo = 1, hi = 0;
  for (uint32_t x = 0; x < 64; ++x) {
    const float j = rayJitter(x, 7);
    EXPECT_GE(j, 0.0f);
    EXPECT_LT(j, 1.0f);
    lo = std::min<double>(lo, j);
    hi = std::max<double>(hi, j);
  }
  EXPECT_LT(lo, 0.1);
  EXPECT_GT(hi, 0.9);
  o.preintegration = true;
  EXPECT_THROW(renderer.render(camera, thinShell(), o), Error);
}

TEST(ReferenceTruth, ConvergedTruthLandsOnTheClosedForm) {
  const ReferenceRenderer renderer(slab());
  for (const bool pre : {false, true}) {
    RenderOptions o;
    o.preintegration = pre;
    o.stepMm = 0.5;
    o.earlyTermination = 1.0;
    ReferenceRenderer::ConvergenceRule rule;
    rule.maxChange = 1e-4;
    rule.minPsnrDb = 80;
    rule.maxHalvings = 8;
    const auto truth = renderer.renderConverged(upTheSlab(), thinShell(), o, rule);
    ASSERT_TRUE(truth.converged) << "pre-integration " << pre;
    EXPECT_EQ(truth.stepsMm.size(), truth.changeMax.size() + 1);
    EXPECT_DOUBLE_EQ(truth.stepsMm.back(), 0.5 / std::exp2(static_cast<double>(truth.stepsMm.size() - 1)));
    EXPECT_LE(truth.changeMax.back(), rule.maxChange);
    // The truth is within the rule's bound of the integral on every pixel.
    const RayErrors e = errors(truth.result.image);
    EXPECT_LE(e.max, rule.maxChange) << "pre-integration " << pre;
    std::printf("pre-integration %d: converged at %.4g mm after %zu pictures, largest error %.2g (estimate %.2g)\n",
                pre, truth.stepsMm.back(), truth.stepsMm.size(), e.max, truth.estimatedMaxError);
    // Pre-integration gets there in fewer halvings.
    if (pre) {
      EXPECT_LE(truth.stepsMm.size(), 3u);
    }
  }
}

}  // namespace
}  // namespace octoray::gpu::reference
