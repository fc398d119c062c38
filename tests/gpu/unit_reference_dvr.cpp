// Direct volume rendering by the reference renderer against analytic transmittance:
// constant media (T = (1 - alpha)^(L / unit) for the exact chord L), linear ramps (closed-form
// integral of ln(1 - alpha)), steps, spheres; every awkward ray geometry.

#include <gtest/gtest.h>

#include <cmath>

#include "render_test_support.h"

namespace octoray::test {
namespace {

using gpu::reference::RenderMode;
using gpu::reference::RenderOptions;

RenderOptions oracle() {
  RenderOptions o;
  o.mode = RenderMode::Dvr;
  o.earlyTermination = 1.0;
  return o;
}

// Checks a constant medium's pixel against the exact chord length.
void expectConstantMedium(const Pixel& px, double chordMm, double alpha, double unitMm = 1.0) {
  const double expectedA = 1.0 - std::pow(1.0 - alpha, chordMm / unitMm);
  EXPECT_NEAR(px.a, expectedA, 1e-6 * std::max(expectedA, 1e-300) + 1e-12)
      << "chord " << chordMm << " mm";
  EXPECT_NEAR(px.r, 1.0 * expectedA, 1e-6 * expectedA + 1e-12);
  EXPECT_NEAR(px.g, 0.5 * expectedA, 1e-6 * expectedA + 1e-12);
  EXPECT_NEAR(px.b, 0.25 * expectedA, 1e-6 * expectedA + 1e-12);
}

class ConstantBox : public ::testing::Test {
 protected:
  ReferenceVolume volume = makeVolume({8, 8, 8}, scaling(1, 1, 1), [](auto...) { return 100.0; });
  transfer::TransferFunction tf = constantTf(0.05f);
  double alpha = static_cast<double>(0.05f);
};

TEST_F(ConstantBox, AxisParallelRays) {
  const Vec3 p{3.2, 4.1, 2.7};
  for (Vec3 d : {Vec3{1, 0, 0}, Vec3{0, 1, 0}, Vec3{0, 0, 1}, Vec3{-1, 0, 0}, Vec3{0, 0, -1}}) {
    const Pixel px = renderRay(volume, tf, oracle(), p - 20.0 * d, d);
    expectConstantMedium(px, 8.0, alpha);
    // Depth: the first sample, half a step (0.125 mm) past the entry face.
    const double along = dot(p, d);
    const double entry = 20.0 - (along > 0 ? along + 0.5 : 7.5 + along);
    EXPECT_NEAR(px.depth, entry + 0.125, 1e-5);
  }
}

TEST_F(ConstantBox, ObliqueRaysMatchExactChord) {
  const Vec3 centre{3.5, 3.5, 3.5};
  for (int n = 0; n < 40; ++n) {
    // Deterministic spread of directions and offsets.
    const double u = std::fmod(0.618034 * n, 1.0), v = std::fmod(0.414214 * n + 0.1, 1.0);
    const double theta = std::acos(2 * u - 1), phi = 2 * M_PI * v;
    const Vec3 d{std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta)};
    const Vec3 offset{std::fmod(1.7 * n, 3.0) - 1.5, std::fmod(2.3 * n, 3.0) - 1.5,
                      std::fmod(0.9 * n, 3.0) - 1.5};
    const Vec3 origin = centre + offset - 30.0 * d;
    const double chord = domainChord(volume, origin, d);
    ASSERT_GT(chord, 0);
    expectConstantMedium(renderRay(volume, tf, oracle(), origin, d), chord, alpha);
  }
}

TEST_F(ConstantBox, GrazingFaceEdgeAndCorner) {
  // Along the face x = -0.5 (inside by convention: the whole length counts).
  expectConstantMedium(renderRay(volume, tf, oracle(), {-0.5, 3, -10}, {0, 0, 1}), 8.0, alpha);
  // Along the edge x = -0.5, y = 7.5.
  expectConstantMedium(renderRay(volume, tf, oracle(), {-0.5, 7.5, -10}, {0, 0, 1}), 8.0, alpha);
  // Just outside a face: nothing.
  const Pixel outside = renderRay(volume, tf, oracle(), {-0.5 - 1e-9, 3, -10}, {0, 0, 1});
  EXPECT_EQ(outside.a, 0.0);
  EXPECT_TRUE(std::isinf(outside.depth));
  // Through the corner (-0.5, -0.5, -0.5) only, from outside: a zero-length chord.
  const Pixel corner = renderRay(volume, tf, oracle(), {-1.5, -1.5, 0.5}, {1, 1, -1});
  EXPECT_EQ(corner.a, 0.0);
  EXPECT_EQ(renderRay(volume, constantTf(1), oracle(), {-1.5, -1.5, 0.5}, {1, 1, -1}).a, 0.0);
  // Diagonal through two opposite corners: the full diagonal.
  const Vec3 d = normalize({1, 1, 1});
  expectConstantMedium(renderRay(volume, tf, oracle(), Vec3{-0.5, -0.5, -0.5} - 5.0 * d, d),
                       8.0 * std::sqrt(3.0), alpha);
  // Within a face plane, obliquely (grazing the face x = 7.5 diagonally).
  const Vec3 dz = normalize({0, 1, 1});
  expectConstantMedium(renderRay(volume, tf, oracle(), Vec3{7.5, -0.5, -0.5} - 3.0 * dz, dz),
                       8.0 * std::sqrt(2.0), alpha);
}

TEST_F(ConstantBox, CameraInsideFarAndNear) {
  // Inside: only the part of the chord in front of the eye.
  const Vec3 d = normalize({0.3, -0.2, 0.9});
  const Vec3 eye{2.2, 5.1, 3.3};
  expectConstantMedium(renderRay(volume, tf, oracle(), eye, d), domainChord(volume, eye, d), alpha);
  // 1e5 mm away, axis-parallel and oblique.
  expectConstantMedium(renderRay(volume, tf, oracle(), {3, 4, -1e5}, {0, 0, 1}), 8.0, alpha);
  const Vec3 far = Vec3{3.5, 3.5, 3.5} - 1e5 * d;
  expectConstantMedium(renderRay(volume, tf, oracle(), far, d), domainChord(volume, far, d), alpha);
  // 1e-3 mm from a face, looking in; and looking away (nothing behind the eye counts).
  expectConstantMedium(renderRay(volume, tf, oracle(), {3, 4, -0.501}, {0, 0, 1}), 8.0, alpha);
  EXPECT_EQ(renderRay(volume, tf, oracle(), {3, 4, -0.501}, {0, 0, -1}).a, 0.0);
  // 1e-3 mm inside a face, looking out through it.
  expectConstantMedium(renderRay(volume, tf, oracle(), {3, 4, -0.499}, {0, 0, -1}), 1e-3, alpha);
}

TEST(ReferenceDvr, OpacityZeroAndOne) {
  const auto volume = makeVolume({6, 6, 6}, scaling(1, 1, 1), [](auto...) { return 0.0; });
  const Pixel none = renderRay(volume, constantTf(0.0f), oracle(), {2, 2, -5}, {0, 0, 1});
  EXPECT_EQ(none.a, 0.0);
  EXPECT_EQ(none.r, 0.0);
  EXPECT_TRUE(std::isinf(none.depth));
  const Pixel full = renderRay(volume, constantTf(1.0f), oracle(), {2, 2, -5}, {0, 0, 1});
  EXPECT_EQ(full.a, 1.0);
  EXPECT_EQ(full.r, 1.0);
  EXPECT_EQ(full.g, 0.5);
  EXPECT_EQ(full.b, 0.25);
  EXPECT_NEAR(full.depth, 4.5 + 0.125, 1e-6);  // the first sample's midpoint
  // Early termination at 0.99 stops, but the answer stays within 1 - threshold.
  RenderOptions early = oracle();
  early.earlyTermination = 0.99;
  const Pixel stopped = renderRay(volume, constantTf(0.9f), early, {2, 2, -5}, {0, 0, 1});
  EXPECT_GE(stopped.a, 0.99);
}

// Tiny opacities keep their relative accuracy (log1p / expm1).
TEST(ReferenceDvr, TinyOpacityIsAccurate) {
  const auto volume = makeVolume({4, 4, 4}, scaling(1, 1, 1), [](auto...) { return 0.0; });
  const double alpha = static_cast<double>(1e-7f);
  const Pixel px = renderRay(volume, constantTf(1e-7f), oracle(), {1, 1, -5}, {0, 0, 1});
  const double expected = -std::expm1(4.0 * std::log1p(-alpha));
  EXPECT_NEAR(px.a, expected, 1e-6 * expected);
  EXPECT_EQ(gpu::reference::correctOpacity(0.0, 0.25), 0.0);
  EXPECT_EQ(gpu::reference::correctOpacity(1.0, 0.25), 1.0);
  EXPECT_EQ(gpu::reference::correctOpacity(1.0, 1e-9), 1.0);
  EXPECT_NEAR(gpu::reference::correctOpacity(1e-12, 0.5), 0.5e-12, 1e-24);
}

// A ramp along x: value = clamp(i, 0, n - 1); opacity alpha = value / (n - 1) * amax. The
// transmittance is exp(integral of ln(1 - alpha) dx), in closed form on the three pieces
// (clamped low end, ramp, clamped high end).
TEST(ReferenceDvr, LinearRampMatchesAnalyticIntegral) {
  const int64_t n = 16;
  const double spacing = 0.7;
  const auto volume = makeVolume({n, 5, 5}, scaling(spacing, 1, 1),
                                 [](int64_t i, auto...) { return static_cast<double>(i); });
  transfer::TransferFunction tf = constantTf(0);
  const float amax = 0.3f;
  tf.opacity = {{0, 0.0f}, {static_cast<double>(n - 1), amax}};
  const double w0 = 1.0, w1 = 1.0 - static_cast<double>(amax);
  const double logT = integralLogLinear(w0, w0, 0.5 * spacing) +
                      integralLogLinear(w0, w1, static_cast<double>(n - 1) * spacing) +
                      integralLogLinear(w1, w1, 0.5 * spacing);
  const double expected = 1.0 - std::exp(logT);
  for (Vec3 d : {Vec3{1, 0, 0}, Vec3{-1, 0, 0}}) {
    const Pixel px = renderRay(volume, tf, oracle(), Vec3{5, 2, 2} - 100.0 * d, d);
    // Midpoint rule on a smooth integrand, step 0.175 mm: error far below 1e-5.
    EXPECT_NEAR(px.a, expected, 1e-5 * expected);
  }
}

// Opacity jumping between neighbouring HU values: 0 HU for i < 4, 1 HU from i = 4.
TEST(ReferenceDvr, StepTransferFunctions) {
  const auto volume =
      makeVolume({8, 3, 3}, scaling(1, 1, 1), [](int64_t i, auto...) { return i < 4 ? 0.0 : 1.0; });
  // A ramp over one HU: alpha = 0.8 * clamp(x - 3, 0, 1) along x.
  transfer::TransferFunction ramp = constantTf(0);
  ramp.opacity = {{0, 0.0f}, {1, 0.8f}};
  const double a = static_cast<double>(0.8f);
  const double logT = integralLogLinear(1.0, 1.0 - a, 1.0) + 3.5 * std::log(1.0 - a);
  // The midpoint rule's error on ln(1 - alpha) is h^2/24 |integral of its 2nd derivative|,
  // 0.8% of T at h = 0.25 mm for this steep ramp; h = 0.025 mm brings it to 1e-4 of T.
  RenderOptions fine = oracle();
  fine.stepMm = 0.025;
  const double expectedT = std::exp(logT);
  EXPECT_NEAR(1 - renderRay(volume, ramp, fine, {-3, 1, 1}, {1, 0, 0}).a, expectedT,
              1e-4 * expectedT);
  // A true step at 0.5 HU (two points at one value): material from x = 3.5 on.
  transfer::TransferFunction step = constantTf(0);
  step.opacity = {{0.5, 0.0f}, {0.5, 0.8f}};
  RenderOptions aligned = oracle();
  aligned.stepMm = 0.25;  // sample boundaries fall on x = 3.5: exact
  EXPECT_NEAR(renderRay(volume, step, aligned, {-3, 1, 1}, {1, 0, 0}).a, 1 - std::pow(1 - a, 4.0),
              1e-6);
  RenderOptions odd = oracle();
  odd.stepMm = 0.3;  // not aligned: the step is found within half a sample step
  const double got = renderRay(volume, step, odd, {-3, 1, 1}, {1, 0, 0}).a;
  const double chord = std::log1p(-got) / std::log1p(-a);
  EXPECT_NEAR(chord, 4.0, 0.5 * 0.3 + 1e-9);
}

// A sphere of radius R: value = R - |x - c| (a distance field), opacity a step at 0. The
// rendered chord (from the transmittance) is the analytic chord to within the trilinear
// interpolation error of the distance field.
TEST(ReferenceDvr, SphereChord) {
  const double radius = 9.0;
  const Vec3 centre{15.5, 15.5, 15.5};
  const auto volume =
      makeVolume({32, 32, 32}, scaling(1, 1, 1), [&](int64_t i, int64_t j, int64_t k) {
        return radius - length(Vec3{double(i), double(j), double(k)} - centre);
      });
  transfer::TransferFunction tf = constantTf(0);
  tf.opacity = {{0, 0.0f}, {0, 0.1f}};
  const double a = static_cast<double>(0.1f);
  // A step in opacity is found to within half a sample step at each end: a fine step.
  RenderOptions fine = oracle();
  fine.stepMm = 0.01;
  for (double offset : {0.0, 3.3, 6.1, 8.2}) {
    const Vec3 origin{centre.x + offset, centre.y, -40};
    const double expectedChord = 2 * std::sqrt(radius * radius - offset * offset);
    const Pixel px = renderRay(volume, tf, fine, origin, {0, 0, 1});
    const double chord = std::log1p(-px.a) / std::log1p(-a);
    EXPECT_NEAR(chord, expectedChord, 0.1) << "offset " << offset;
  }
}

// Spacing 0.3 x 0.3 x 5 mm: chords of a constant box in mm, through every axis.
TEST(ReferenceDvr, AnisotropicSpacing) {
  const auto volume =
      makeVolume({20, 20, 4}, scaling(0.3, 0.3, 5.0, {-3, -3, 0}), [](auto...) { return 1.0; });
  const auto tf = constantTf(0.02f);
  const double a = static_cast<double>(0.02f);
  expectConstantMedium(renderRay(volume, tf, oracle(), {0, 0, -50}, {0, 0, 1}), 20.0, a);
  expectConstantMedium(renderRay(volume, tf, oracle(), {-50, 0, 7}, {1, 0, 0}), 6.0, a);
  for (Vec3 d : {Vec3{0.1, 0.05, 1}, Vec3{1, 0.3, 0.2}, Vec3{-0.2, 1, -1}}) {
    const Vec3 origin = Vec3{-0.1, 0.2, 8} - 60.0 * normalize(d);
    const double chord = domainChord(volume, origin, d);
    ASSERT_GT(chord, 0);
    expectConstantMedium(renderRay(volume, tf, oracle(), origin, d), chord, a);
  }
}

// Oblique (rotated) and sheared (gantry tilt) grids: the chord through the parallelepiped.
TEST(ReferenceDvr, ObliqueAndShearedAffines) {
  const double c = std::cos(0.4), s = std::sin(0.4);
  const Mat4 oblique = Mat4::fromColumns({0.8 * c, 0.8 * s, 0}, {-0.8 * s, 0.8 * c, 0},
                                         {0, 0.3, 2.0}, {10, -20, 30});
  const Mat4 tilted = Mat4::fromColumns({0.5, 0, 0}, {0, 0.5, 0}, {0, 0.9, 2.0}, {-5, 5, 100});
  const auto tf = constantTf(0.04f);
  const double a = static_cast<double>(0.04f);
  for (const Mat4& m : {oblique, tilted}) {
    const auto volume = makeVolume({12, 10, 7}, m, [](auto...) { return 5.0; });
    const Vec3 centre = m.transformPoint({5.5, 4.5, 3});
    for (Vec3 d : {Vec3{0, 0, 1}, Vec3{1, 0, 0}, Vec3{0.3, -0.7, 0.5}, Vec3{0, 1, 0}}) {
      const Vec3 origin = centre - 80.0 * normalize(d);
      const double chord = domainChord(volume, origin, d);
      ASSERT_GT(chord, 0);
      expectConstantMedium(renderRay(volume, tf, oracle(), origin, d), chord, a);
    }
  }
}

// A field linear in patient z sampled on a sheared grid renders like the same field on an
// orthogonal grid: along a patient-z ray the value is z clamped to the slice range, so the
// transmittance has the ramp's closed form whatever the shear.
TEST(ReferenceDvr, ShearedGridRepresentsPatientSpaceRamp) {
  const int64_t slices = 10;
  const double sliceMm = 2.0;
  for (double shear : {0.0, 0.9}) {
    const Mat4 m = Mat4::fromColumns({0.5, 0, 0}, {0, 0.5, 0}, {0, shear, sliceMm}, {0, 0, 0});
    const auto volume = makeVolume({16, 64, slices}, m, [&](int64_t, int64_t, int64_t k) {
      return sliceMm * static_cast<double>(k);  // patient z of the voxel centre
    });
    transfer::TransferFunction tf = constantTf(0);
    const double zMax = sliceMm * static_cast<double>(slices - 1);
    tf.opacity = {{0, 0.0f}, {zMax, 0.25f}};
    const double w1 = 1.0 - static_cast<double>(0.25f);
    const double logT = integralLogLinear(1, 1, 0.5 * sliceMm) + integralLogLinear(1, w1, zMax) +
                        integralLogLinear(w1, w1, 0.5 * sliceMm);
    const Pixel px = renderRay(volume, tf, oracle(), {3.7, 12.3, -30}, {0, 0, 1});
    EXPECT_NEAR(px.a, 1 - std::exp(logT), 1e-6) << "shear " << shear;
  }
}

TEST(ReferenceDvr, OneVoxelThickVolume) {
  const auto volume = makeVolume({8, 8, 1}, scaling(1, 1, 2), [](auto...) { return 1.0; });
  const auto tf = constantTf(0.3f);
  const double a = static_cast<double>(0.3f);
  expectConstantMedium(renderRay(volume, tf, oracle(), {3, 3, -10}, {0, 0, 1}), 2.0, a);
  expectConstantMedium(renderRay(volume, tf, oracle(), {-10, 3, 0}, {1, 0, 0}), 8.0, a);
  expectConstantMedium(renderRay(volume, tf, oracle(), {-10, 3, 1}, {1, 0, 0}), 8.0, a);  // face
  const Vec3 d = normalize({1, 0, 1});
  const Vec3 origin = Vec3{3, 3, 0} - 10.0 * d;
  expectConstantMedium(renderRay(volume, tf, oracle(), origin, d), domainChord(volume, origin, d),
                       a);
}

// A ramp of 20 HU/mm along x (value 10 i, spacing 0.5): rays along y inside see a constant
// gradient magnitude of 20, so gradient opacity and boundary enhancement scale alpha exactly.
TEST(ReferenceDvr, GradientOpacityAndBoundaryEnhancement) {
  const auto volume = makeVolume({12, 8, 8}, scaling(0.5, 1, 1),
                                 [](int64_t i, auto...) { return 10.0 * static_cast<double>(i); });
  auto tf = constantTf(0.1f);
  const double a = static_cast<double>(0.1f);
  const Vec3 origin{2.5, -5, 3}, d{0, 1, 0};  // x = 2.5 mm: index 5, differences inside
  tf.gradientOpacity = {{0, 0.0f}, {40, 1.0f}};
  expectConstantMedium(renderRay(volume, tf, oracle(), origin, d), 8.0, a * 0.5);
  RenderOptions noGradientOpacity = oracle();
  noGradientOpacity.gradientOpacity = false;
  expectConstantMedium(renderRay(volume, tf, noGradientOpacity, origin, d), 8.0, a);
  tf.gradientOpacity.clear();
  RenderOptions boundary = oracle();
  boundary.boundary = {true, 0.2, 0.01, 1.5};
  const double k = 0.2 + 0.01 * std::pow(20.0, 1.5);
  expectConstantMedium(renderRay(volume, tf, boundary, origin, d), 8.0, a * k);
  // In a constant region the gradient is zero: enhancement leaves kC, never NaN.
  const auto flat = makeVolume({6, 6, 6}, scaling(1, 1, 1), [](auto...) { return 1.0; });
  expectConstantMedium(renderRay(flat, tf, boundary, {2, -5, 2}, d), 6.0, a * 0.2);
}

// Constant regions have a zero gradient: shading must give ambient only, never NaN.
TEST(ReferenceDvr, ShadingOfConstantRegionIsAmbientOnly) {
  const auto volume = makeVolume({8, 8, 8}, scaling(1, 1, 1), [](auto...) { return 7.0; });
  auto tf = constantTf(0.2f);
  tf.material = {true, 0.25f, 0.7f, 0.4f, 12.0f};
  const Pixel px = renderRay(volume, tf, oracle(), {3, 3, -9}, {0.1, 0, 1});
  const double expectedA = px.a;
  EXPECT_GT(expectedA, 0.5);
  EXPECT_NEAR(px.r, 0.25 * expectedA, 1e-6);
  EXPECT_NEAR(px.g, 0.25 * 0.5 * expectedA, 1e-6);
  // A whole image of it: every pixel finite.
  gpu::reference::ReferenceRenderer renderer(volume);
  const auto result = renderer.render(
      gpu::orbitCamera({volume.dims(), volume.patientFromIndex()}, {30, 20, 1.2}), tf, oracle());
  for (float v : result.image.rgba) ASSERT_TRUE(std::isfinite(v));
}

// A sphere with shading: lit by a headlight, the centre of the disc is brighter than its rim,
// and the same render twice is bit-identical.
TEST(ReferenceDvr, ShadedSphereImage) {
  const Vec3 centre{15.5, 15.5, 15.5};
  const auto volume =
      makeVolume({32, 32, 32}, scaling(1, 1, 1), [&](int64_t i, int64_t j, int64_t k) {
        return 100.0 * (10.0 - length(Vec3{double(i), double(j), double(k)} - centre));
      });
  transfer::TransferFunction tf = constantTf(0, 0.9f, 0.8f, 0.7f);
  tf.opacity = {{-50, 0.0f}, {50, 1.0f}};
  tf.material = {true, 0.1f, 0.8f, 0.3f, 20.0f};
  gpu::OrbitParameters orbit;
  orbit.width = orbit.height = 48;
  const auto camera = gpu::orbitCamera({volume.dims(), volume.patientFromIndex()}, orbit);
  gpu::reference::ReferenceRenderer renderer(volume);
  const auto a = renderer.render(camera, tf, {});
  const auto b = renderer.render(camera, tf, {});
  EXPECT_EQ(a.image.rgba, b.image.rgba);
  const float* middle = a.image.pixel(24, 24);
  const float* rim = a.image.pixel(24, 24 - 7);
  EXPECT_GT(middle[3], 0.99f);
  EXPECT_GT(middle[0], 0.8f);
  EXPECT_GT(rim[3], 0.9f);
  EXPECT_LT(rim[0], middle[0] - 0.2f);
  EXPECT_EQ(a.image.pixel(0, 0)[3], 0.0f);
  for (float v : a.image.rgba) ASSERT_TRUE(std::isfinite(v));
  saveIfFailed(a.image, "shaded-sphere");
}

// Whole images through perspective cameras (outside with some pixels missing, and inside the
// volume with a wide field of view) on a sheared grid: every pixel is the exact chord's answer.
TEST(ReferenceDvr, PerspectiveImagesMatchChordsPerPixel) {
  const Mat4 tilted = Mat4::fromColumns({0.7, 0, 0}, {0, 0.7, 0}, {0, 0.6, 1.5}, {-5, 5, 100});
  const auto volume = makeVolume({14, 12, 9}, tilted, [](auto...) { return 1.0; });
  const auto tf = constantTf(0.03f);
  const double a = static_cast<double>(0.03f);
  gpu::OrbitParameters orbit;
  orbit.width = 24;
  orbit.height = 18;
  orbit.azimuthDegrees = 40;
  orbit.elevationDegrees = 25;
  orbit.zoom = 1.3;
  gpu::Camera outside = gpu::orbitCamera({volume.dims(), volume.patientFromIndex()}, orbit);
  gpu::Camera inside = outside;
  inside.eye = tilted.transformPoint({4.2, 6.1, 3.3});
  inside.fovYDegrees = 100;
  gpu::reference::RenderOptions options;
  options.earlyTermination = 1.0;
  gpu::reference::ReferenceRenderer renderer(volume);
  for (int which = 0; which < 2; ++which) {
    const gpu::Camera& camera = which == 0 ? outside : inside;
    const auto result = renderer.render(camera, tf, options);
    int hits = 0, misses = 0;
    for (int y = 0; y < camera.height; ++y) {
      for (int x = 0; x < camera.width; ++x) {
        const gpu::Ray ray = camera.ray(x, y);
        const double chord = domainChord(volume, ray.origin, ray.direction);
        const double expected = 1.0 - std::pow(1.0 - a, chord);
        EXPECT_NEAR(result.image.pixel(x, y)[3], expected, 1e-6 * expected + 1e-7) << x << "," << y;
        (chord > 0 ? hits : misses) += 1;
      }
    }
    EXPECT_GT(hits, 20);
    if (which == 0) {
      EXPECT_GT(misses, 20);
    }
    saveIfFailed(result.image, "perspective");
  }
}

}  // namespace
}  // namespace octoray::test
