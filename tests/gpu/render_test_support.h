#pragma once
// Helpers for the reference-renderer tests: volumes from a function of the index, single-ray
// renders through a 1x1 camera, simple transfer functions, and independent analytic chords.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "octoray/gpu/camera.h"
#include "octoray/gpu/image_io.h"
#include "octoray/gpu/reference/reference_renderer.h"
#include "test_paths.h"

namespace octoray::test {

using gpu::reference::ReferenceVolume;

inline ReferenceVolume makeVolume(std::array<int64_t, 3> dims, const Mat4& patientFromIndex,
                                  const std::function<double(int64_t, int64_t, int64_t)>& value) {
  std::vector<float> values;
  values.reserve(static_cast<std::size_t>(dims[0] * dims[1] * dims[2]));
  for (int64_t k = 0; k < dims[2]; ++k)
    for (int64_t j = 0; j < dims[1]; ++j)
      for (int64_t i = 0; i < dims[0]; ++i) values.push_back(static_cast<float>(value(i, j, k)));
  return ReferenceVolume(dims, patientFromIndex, std::move(values));
}

inline Mat4 scaling(double sx, double sy, double sz, Vec3 origin = {}) {
  return Mat4::fromColumns({sx, 0, 0}, {0, sy, 0}, {0, 0, sz}, origin);
}

// Opacity `alpha` per `unitMm` for every value, one colour, no shading.
inline transfer::TransferFunction constantTf(float alpha, float r = 1, float g = 0.5f,
                                             float b = 0.25f, double unitMm = 1.0) {
  transfer::TransferFunction tf;
  tf.name = "constant";
  tf.color = {{0, r, g, b}};
  tf.opacity = {{0, alpha}};
  tf.material.shade = false;
  tf.unitDistanceMm = unitMm;
  return tf;
}

struct Pixel {
  double r = 0, g = 0, b = 0, a = 0, depth = 0, value = 0;
};

// One ray: a 1x1 orthographic camera whose only pixel centre is `origin`, looking along
// `direction` (patient space).
inline gpu::Camera rayCamera(Vec3 origin, Vec3 direction) {
  gpu::Camera c;
  c.projection = gpu::Projection::Orthographic;
  c.eye = origin;
  c.target = origin + normalize(direction);
  const Vec3 d = normalize(direction);
  c.up = std::abs(d.z) < 0.9 ? Vec3{0, 0, 1} : Vec3{0, 1, 0};
  c.orthoHeightMm = 1.0;
  c.width = c.height = 1;
  return c;
}

inline Pixel renderRay(const ReferenceVolume& volume, const transfer::TransferFunction& tf,
                       gpu::reference::RenderOptions options, Vec3 origin, Vec3 direction) {
  const gpu::reference::ReferenceRenderer renderer(volume);
  const auto result = renderer.render(rayCamera(origin, direction), tf, options);
  const float* p = result.image.pixel(0, 0);
  Pixel px{p[0],
           p[1],
           p[2],
           p[3],
           result.image.depth[0],
           result.value.empty() ? std::numeric_limits<double>::quiet_NaN() : result.value[0]};
  EXPECT_TRUE(std::isfinite(px.r) && std::isfinite(px.g) && std::isfinite(px.b) &&
              std::isfinite(px.a))
      << "non-finite pixel";
  return px;
}

// Chord length of a ray (unit direction) through the parallelepiped corner + [0,1]^3 spanned
// by edges e0, e1, e2, computed in patient space from its face planes (independent of the
// renderer's index-space clipping). Faces count as inside.
inline double chordThroughParallelepiped(Vec3 corner, Vec3 e0, Vec3 e1, Vec3 e2, Vec3 origin,
                                         Vec3 direction, double tMin = 0) {
  const Vec3 edges[3] = {e0, e1, e2};
  double tNear = tMin, tFar = std::numeric_limits<double>::infinity();
  for (int a = 0; a < 3; ++a) {
    const Vec3 n = cross(edges[(a + 1) % 3], edges[(a + 2) % 3]);
    const double lo = dot(n, corner), hi = dot(n, corner + edges[a]);
    const double o = dot(n, origin), d = dot(n, direction);
    const double mn = std::min(lo, hi), mx = std::max(lo, hi);
    if (d == 0) {
      if (o < mn || o > mx) return 0;
      continue;
    }
    double t0 = (mn - o) / d, t1 = (mx - o) / d;
    if (t0 > t1) std::swap(t0, t1);
    tNear = std::max(tNear, t0);
    tFar = std::min(tFar, t1);
  }
  return tFar > tNear ? tFar - tNear : 0.0;
}

// The domain [-0.5, dim - 0.5]^3 of a volume as a parallelepiped in patient space.
inline double domainChord(const ReferenceVolume& v, Vec3 origin, Vec3 direction, double tMin = 0) {
  const Mat4& m = v.patientFromIndex();
  const auto& d = v.dims();
  const Vec3 corner = m.transformPoint({-0.5, -0.5, -0.5});
  return chordThroughParallelepiped(
      corner, static_cast<double>(d[0]) * m.column(0), static_cast<double>(d[1]) * m.column(1),
      static_cast<double>(d[2]) * m.column(2), origin, normalize(direction), tMin);
}

// Integral over [0, length] of ln(w(t)) for w linear from w0 to w1 (both > 0).
inline double integralLogLinear(double w0, double w1, double lengthMm) {
  if (std::abs(w1 - w0) < 1e-14) return lengthMm * std::log(w0);
  const auto antiderivative = [](double w) { return w * std::log(w) - w; };
  return lengthMm * (antiderivative(w1) - antiderivative(w0)) / (w1 - w0);
}

// Writes `image` as EXR and PNG into the test's temporary folder when the test has failed.
inline void saveIfFailed(const gpu::Image& image, const std::string& name) {
  if (!::testing::Test::HasFailure()) return;
  const auto dir = freshTempDir(name);
  gpu::writeExr(image, dir / (name + ".exr"));
  gpu::writePng(image, dir / (name + ".png"));
  ADD_FAILURE() << "images written to " << dir.string();
}

}  // namespace octoray::test
