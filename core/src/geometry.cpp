#include "octoray/core/geometry.h"

#include <algorithm>

#include "octoray/core/error.h"

namespace octoray {

Mat4 Mat4::fromColumns(Vec3 c0, Vec3 c1, Vec3 c2, Vec3 t) {
  Mat4 r;
  for (int row = 0; row < 3; ++row) {
    r.m[row][0] = c0[row];
    r.m[row][1] = c1[row];
    r.m[row][2] = c2[row];
    r.m[row][3] = t[row];
  }
  return r;
}

Vec3 Mat4::transformPoint(Vec3 p) const {
  return {m[0][0] * p.x + m[0][1] * p.y + m[0][2] * p.z + m[0][3],
          m[1][0] * p.x + m[1][1] * p.y + m[1][2] * p.z + m[1][3],
          m[2][0] * p.x + m[2][1] * p.y + m[2][2] * p.z + m[2][3]};
}

Vec3 Mat4::transformVector(Vec3 v) const {
  return {m[0][0] * v.x + m[0][1] * v.y + m[0][2] * v.z,
          m[1][0] * v.x + m[1][1] * v.y + m[1][2] * v.z,
          m[2][0] * v.x + m[2][1] * v.y + m[2][2] * v.z};
}

Mat4 Mat4::inverseAffine() const {
  // Inverse of the 3x3 linear part by cofactors, then the translation.
  const auto& a = m;
  const double c00 = a[1][1] * a[2][2] - a[1][2] * a[2][1];
  const double c01 = a[1][2] * a[2][0] - a[1][0] * a[2][2];
  const double c02 = a[1][0] * a[2][1] - a[1][1] * a[2][0];
  const double det = a[0][0] * c00 + a[0][1] * c01 + a[0][2] * c02;
  double scale = 0;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) scale = std::max(scale, std::abs(a[r][c]));
  if (!(std::abs(det) > 1e-12 * scale * scale * scale) || !std::isfinite(det)) {
    throw Error("", "singular index-to-patient transform (zero or non-finite spacing)");
  }
  const double s = 1.0 / det;
  Mat4 inv;
  inv.m[0][0] = c00 * s;
  inv.m[1][0] = c01 * s;
  inv.m[2][0] = c02 * s;
  inv.m[0][1] = (a[0][2] * a[2][1] - a[0][1] * a[2][2]) * s;
  inv.m[1][1] = (a[0][0] * a[2][2] - a[0][2] * a[2][0]) * s;
  inv.m[2][1] = (a[0][1] * a[2][0] - a[0][0] * a[2][1]) * s;
  inv.m[0][2] = (a[0][1] * a[1][2] - a[0][2] * a[1][1]) * s;
  inv.m[1][2] = (a[0][2] * a[1][0] - a[0][0] * a[1][2]) * s;
  inv.m[2][2] = (a[0][0] * a[1][1] - a[0][1] * a[1][0]) * s;
  const Vec3 t{a[0][3], a[1][3], a[2][3]};
  const Vec3 invT = inv.transformVector(t);
  inv.m[0][3] = -invT.x;
  inv.m[1][3] = -invT.y;
  inv.m[2][3] = -invT.z;
  return inv;
}

Mat4 operator*(const Mat4& a, const Mat4& b) {
  Mat4 r;
  for (int i = 0; i < 4; ++i) {
    for (int j = 0; j < 4; ++j) {
      double sum = 0;
      for (int k = 0; k < 4; ++k) sum += a.m[i][k] * b.m[k][j];
      r.m[i][j] = sum;
    }
  }
  return r;
}

}  // namespace octoray
