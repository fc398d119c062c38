#include "octoray/dicom/volume_source.h"

#include <cmath>

#include <fmt/format.h>

#include "octoray/core/error.h"

namespace octoray {

void checkSlabRequest(const VolumeInfo& info, int64_t firstSlice, int64_t sliceCount,
                      std::size_t outSize) {
  if (firstSlice < 0 || sliceCount < 0 || firstSlice + sliceCount > info.dims[2]) {
    throw Error(info.sourcePath, fmt::format("slab [{}, {}) is outside the volume's {} slices",
                                             firstSlice, firstSlice + sliceCount, info.dims[2]));
  }
  const auto needed = static_cast<std::size_t>(info.sliceSamples() * sliceCount);
  if (outSize != needed) {
    throw Error(info.sourcePath,
                fmt::format("slab buffer holds {} samples, {} slices need {}", outSize,
                            sliceCount, needed));
  }
}

void checkGeometry(const Mat4& m, const std::string& path) {
  bool finite = true;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 4; ++c) finite = finite && std::isfinite(m.m[r][c]);
  }
  const Vec3 spacing{length(m.column(0)), length(m.column(1)), length(m.column(2))};
  for (const double sp : {spacing.x, spacing.y, spacing.z}) {
    if (!finite || !(sp >= 1e-6 && sp <= 1e6)) {
      throw Error(path, fmt::format("spacing {} x {} x {} mm is outside [1e-6, 1e6] mm or the "
                                    "position is not finite: the geometry is not usable",
                                    spacing.x, spacing.y, spacing.z));
    }
  }
  // A position a kilometre or more from the scanner's origin is damage, and at 1e300 the
  // slice step (a difference of positions) is lost to rounding.
  const Vec3 origin = m.column(3);
  for (const double o : {origin.x, origin.y, origin.z}) {
    if (!(std::abs(o) <= 1e6)) {
      throw Error(path, fmt::format("position ({}, {}, {}) mm is over 1e6 mm from the origin: the "
                                    "geometry is not usable",
                                    origin.x, origin.y, origin.z));
    }
  }
  const double det = dot(m.column(0), cross(m.column(1), m.column(2)));
  if (!std::isfinite(det) || !(std::abs(det) > 1e-9 * spacing.x * spacing.y * spacing.z)) {
    throw Error(path, "the index-to-patient affine is singular (parallel axes)");
  }
}

}  // namespace octoray
