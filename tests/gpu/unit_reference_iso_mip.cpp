// Isosurface and maximum intensity projection by the reference renderer against analytic
// answers: sphere radii and depths, the maximum of a trilinear interpolant along a ray.

#include <gtest/gtest.h>

#include <cmath>

#include "render_test_support.h"

namespace octoray::test {
namespace {

using gpu::reference::RenderMode;
using gpu::reference::RenderOptions;

RenderOptions isoAt(double value) {
  RenderOptions o;
  o.mode = RenderMode::Iso;
  o.isoValue = value;
  return o;
}

RenderOptions mip() {
  RenderOptions o;
  o.mode = RenderMode::Mip;
  return o;
}

// value = |x - c| in mm; the isosurface at R is a sphere of radius R up to the trilinear
// interpolation error of the distance field (below 0.02 mm at R >= 8 voxels).
ReferenceVolume distanceField(Vec3 centre, const Mat4& m, std::array<int64_t, 3> dims) {
  return makeVolume(dims, m, [&](int64_t i, int64_t j, int64_t k) {
    return length(m.transformPoint({double(i), double(j), double(k)}) - centre);
  });
}

TEST(ReferenceIso, SphereDepthMatchesRadius) {
  const Vec3 centre{20, 18, 25};
  const double radius = 10.0;
  auto tf = constantTf(1, 0.9f, 0.9f, 0.9f);
  tf.material = {true, 0.2f, 0.8f, 0.0f, 1.0f};
  for (const Mat4& m : {scaling(1, 1, 1), scaling(0.8, 0.8, 1.6),
                        Mat4::fromColumns({1, 0, 0}, {0, 1, 0}, {0, 0.4, 1.5}, {0, -2, 0})}) {
    const auto volume = distanceField(centre, m, {40, 40, 34});
    for (Vec3 d : {Vec3{0, 0, 1}, Vec3{1, 0.2, 0.1}, Vec3{-0.3, 1, -0.4}}) {
      const Vec3 dn = normalize(d);
      for (double offset : {0.0, 4.0, 7.5}) {
        const Vec3 side = normalize(cross(dn, Vec3{0.31, 0.52, 0.79}));
        const Vec3 origin = centre + offset * side - 60.0 * dn;
        const Pixel px = renderRay(volume, tf, isoAt(radius), origin, d);
        const double expectedDepth = 60.0 - std::sqrt(radius * radius - offset * offset);
        EXPECT_NEAR(px.depth, expectedDepth, 0.05) << "offset " << offset;
        EXPECT_EQ(px.a, 1.0);
        // Headlight on a sphere: diffuse = cos of the angle to the normal.
        const double cosine = std::sqrt(radius * radius - offset * offset) / radius;
        EXPECT_NEAR(px.r, 0.9 * (0.2 + 0.8 * cosine), 0.03) << "offset " << offset;
      }
    }
  }
}

TEST(ReferenceIso, RefinesToTheExactCrossing) {
  // A linear ramp along x is its own trilinear interpolant: the crossing is exact.
  const auto volume = makeVolume({16, 4, 4}, scaling(0.5, 1, 1),
                                 [](int64_t i, auto...) { return 10.0 * static_cast<double>(i); });
  const Pixel px = renderRay(volume, constantTf(1), isoAt(37.3), {-20, 1.5, 1.5}, {1, 0, 0});
  EXPECT_NEAR(px.depth, 20.0 + 0.5 * 3.73, 1e-6 * 0.5);
  // Camera inside the surface: the first crossing on the way out is found too.
  const Pixel inside = renderRay(volume, constantTf(1), isoAt(37.3), {5, 1.5, 1.5}, {-1, 0, 0});
  EXPECT_NEAR(inside.depth, 5.0 - 0.5 * 3.73, 1e-6);
  // An isovalue the ray never reaches: nothing.
  const Pixel miss = renderRay(volume, constantTf(1), isoAt(1000), {-20, 1.5, 1.5}, {1, 0, 0});
  EXPECT_EQ(miss.a, 0.0);
  EXPECT_TRUE(std::isinf(miss.depth));
}

// One plane of 1000 (k = 8) in zeros: along z the interpolant is a tent 2 voxels wide, and the
// isovalue 990 cuts from it a sliver 0.02 voxel thick, between z = 7.99 and 8.01. A ray
// grazing thin bone meets such a sliver; the default step (0.25 voxel) mostly straddles it:
// no sample is above 990, the surface is there all the same (isoDip).
TEST(ReferenceIso, FindsASurfaceThinnerThanTheStep) {
  // 18 planes: the domain's chord is not a multiple of the step from z = -0.5 to the peak.
  const auto volume = makeVolume({12, 12, 18}, scaling(1, 1, 1), [](int64_t, int64_t, int64_t k) {
    return k == 8 ? 1000.0 : 0.0;
  });
  const auto tent = [](double z) { return 1000.0 * std::max(0.0, 1.0 - std::abs(z - 8.0)); };
  int straddled = 0, cases = 0;
  for (const Vec3 d : {Vec3{0, 0, 1}, normalize({0.05, 0.03, 1}), normalize({-0.1, 0.08, 1})}) {
    for (double step = 0.2; step <= 0.3001; step += 0.01) {
      const Vec3 origin{5.3, 6.1, -10};
      RenderOptions options = isoAt(990);
      options.stepMm = step;
      const Pixel px = renderRay(volume, constantTf(1), options, origin, d);
      // The samples the march takes: the domain's chord in equal steps, from its entry.
      const double entry = (-0.5 - origin.z) / d.z, chord = 18.0 / d.z;
      const double n = std::ceil(chord / step), delta = chord / n;
      bool seen = false;
      for (int s = 0; s <= static_cast<int>(n); ++s) {
        seen = seen || tent(origin.z + (entry + s * delta) * d.z) >= 990.0;
      }
      straddled += seen ? 0 : 1;
      ++cases;
      ASSERT_EQ(px.a, 1.0) << "step " << step << ", direction " << d.x << " " << d.y;
      EXPECT_NEAR(px.depth, (7.99 - origin.z) / d.z, 1e-4) << "step " << step;
    }
  }
  // Most of these rays straddle the sliver: the test is about surfaces between samples.
  EXPECT_GE(straddled, cases * 3 / 4) << straddled << " of " << cases;
}

TEST(ReferenceIso, ConstantVolumeAtTheIsovalueHasNoNanNormal) {
  const auto volume = makeVolume({6, 6, 6}, scaling(1, 1, 1), [](auto...) { return 3.0; });
  auto tf = constantTf(1);
  tf.material.shade = true;
  const Pixel px = renderRay(volume, tf, isoAt(3.0), {2, 2, -4}, {0, 0, 1});
  EXPECT_EQ(px.a, 1.0);
  EXPECT_NEAR(px.depth, 3.5, 1e-9);
  EXPECT_NEAR(px.r, tf.material.ambient, 1e-6);  // ambient only: the normal is undefined
}

TEST(ReferenceMip, MaximumOfTheInterpolant) {
  const auto volume = makeVolume({9, 9, 9}, scaling(1, 1, 1), [](int64_t i, int64_t j, int64_t k) {
    return i == 4 && j == 4 && k == 4 ? 1000.0 : 0.0;
  });
  const auto tf = constantTf(1);
  // Through the hot voxel's centre, axis-parallel and diagonal.
  EXPECT_EQ(renderRay(volume, tf, mip(), {4, 4, -10}, {0, 0, 1}).value, 1000.0);
  const Vec3 d = normalize({1, 1, 1});
  const Pixel diagonal = renderRay(volume, tf, mip(), Vec3{4, 4, 4} - 20.0 * d, d);
  EXPECT_NEAR(diagonal.value, 1000.0, 1e-9);
  EXPECT_NEAR(diagonal.depth, 20.0, 1e-9);
  // Off the centre by (0.3, 0.2): the bilinear weight.
  EXPECT_NEAR(renderRay(volume, tf, mip(), {4.3, 4.2, -10}, {0, 0, 1}).value, 1000.0 * 0.7 * 0.8,
              1e-9);
  // A skew line: max of (1-|x|)(1-|y|)(1-|z|) along p + t d, brute force on a fine grid.
  const Vec3 skewD = normalize({0.2, -0.3, 1});
  const Vec3 skewP{4.25, 4.1, 4};
  double best = 0;
  for (int s = -200000; s <= 200000; ++s) {
    const Vec3 q = skewP + (s * 1e-5) * skewD - Vec3{4, 4, 4};
    best = std::max(best, 1000.0 * std::max(0.0, 1 - std::abs(q.x)) *
                              std::max(0.0, 1 - std::abs(q.y)) * std::max(0.0, 1 - std::abs(q.z)));
  }
  EXPECT_NEAR(renderRay(volume, tf, mip(), skewP - 10.0 * skewD, skewD).value, best, 1e-6);
}

TEST(ReferenceMip, SphereAndGrazingRays) {
  const Vec3 centre{12, 12, 12};
  const auto volume =
      makeVolume({25, 25, 25}, scaling(1, 1, 1), [&](int64_t i, int64_t j, int64_t k) {
        return 100.0 - length(Vec3{double(i), double(j), double(k)} - centre);
      });
  const auto tf = constantTf(1);
  // Through the centre (a voxel centre): the maximum is exactly 100.
  EXPECT_NEAR(renderRay(volume, tf, mip(), {12, 12, -5}, {0, 0, 1}).value, 100.0, 1e-9);
  // Along the domain's face and edge: finite, the values there.
  const Pixel face = renderRay(volume, tf, mip(), {-0.5, 12, -5}, {0, 0, 1});
  EXPECT_NEAR(face.value, 100.0 - 12.0, 1e-9);  // clamped to i = 0
  const Pixel edge = renderRay(volume, tf, mip(), {-0.5, -0.5, -5}, {0, 0, 1});
  EXPECT_NEAR(edge.value, static_cast<float>(100.0 - std::sqrt(288.0)), 1e-9);  // stored as float
  // Missing the box: NaN value, transparent.
  const Pixel miss = renderRay(volume, tf, mip(), {-0.6, 12, -5}, {0, 0, 1});
  EXPECT_TRUE(std::isnan(miss.value));
  EXPECT_EQ(miss.a, 0.0);
}

TEST(ReferenceMip, ImageIsFiniteAndDeterministic) {
  const auto volume =
      makeVolume({16, 12, 3}, scaling(0.3, 0.3, 5), [](int64_t i, int64_t j, int64_t k) {
        return static_cast<double>((i * 7 + j * 3 + k * 11) % 13);
      });
  transfer::TransferFunction tf = constantTf(0);
  tf.opacity = {{0, 0.0f}, {12, 1.0f}};
  gpu::OrbitParameters orbit;
  orbit.width = 24;
  orbit.height = 16;
  orbit.azimuthDegrees = 33;
  orbit.elevationDegrees = -12;
  const auto camera = gpu::orbitCamera({volume.dims(), volume.patientFromIndex()}, orbit);
  gpu::reference::ReferenceRenderer renderer(volume);
  const auto a = renderer.render(camera, tf, mip());
  const auto b = renderer.render(camera, tf, mip());
  EXPECT_EQ(a.image.rgba, b.image.rgba);
  int hits = 0;
  for (std::size_t i = 0; i < a.value.size(); ++i) {
    if (std::isnan(a.value[i])) continue;
    ++hits;
    EXPECT_LE(a.value[i], 12.0);
    EXPECT_GE(a.value[i], 0.0);
  }
  EXPECT_GT(hits, 50);
  saveIfFailed(a.image, "mip");
}

}  // namespace
}  // namespace octoray::test
