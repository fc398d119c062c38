#pragma once
// Small fixed-size linear algebra for volume geometry. Patient space is DICOM LPS in mm;
// index space has voxel centres at integer (i, j, k) with i along a row (columns), j down
// the columns (rows) and k across slices. Transforms are named destination-from-source.

#include <array>
#include <cmath>

namespace octoray {

struct Vec3 {
  double x = 0, y = 0, z = 0;

  double operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
  friend Vec3 operator+(Vec3 a, Vec3 b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
  friend Vec3 operator-(Vec3 a, Vec3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
  friend Vec3 operator*(double s, Vec3 a) { return {s * a.x, s * a.y, s * a.z}; }
  friend Vec3 operator*(Vec3 a, double s) { return s * a; }
};

inline double dot(Vec3 a, Vec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline Vec3 cross(Vec3 a, Vec3 b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline double length(Vec3 a) { return std::sqrt(dot(a, a)); }
inline Vec3 normalize(Vec3 a) {
  const double n = length(a);
  return n > 0 ? (1.0 / n) * a : a;
}

// A 4x4 matrix, row-major; affine transforms keep the last row (0 0 0 1).
struct Mat4 {
  std::array<std::array<double, 4>, 4> m{{{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}, {0, 0, 0, 1}}};

  static Mat4 identity() { return {}; }
  // An affine from three column vectors and a translation.
  static Mat4 fromColumns(Vec3 c0, Vec3 c1, Vec3 c2, Vec3 t);

  Vec3 column(int c) const { return {m[0][c], m[1][c], m[2][c]}; }
  Vec3 transformPoint(Vec3 p) const;
  Vec3 transformVector(Vec3 v) const;
  // Inverse of an affine transform; throws octoray::Error when it is singular.
  Mat4 inverseAffine() const;

  friend Mat4 operator*(const Mat4& a, const Mat4& b);
};

}  // namespace octoray
