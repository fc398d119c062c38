#pragma once
// The whole volume at full resolution in memory, as float physical values (HU for CT), for
// the CPU reference renderer. Loaded slab by slab from any VolumeSource, or from the leaf
// bricks of an octree store (the samples the GPU renderer will see).
//
// Sampling: voxel centres sit at integer indices; the domain is [-0.5, dim - 0.5] per axis.
// Between centres the value is the trilinear interpolant; between the outermost centres and
// the domain's faces it is clamped (the edge samples extend to the faces), as GL's
// CLAMP_TO_EDGE does on a texture holding the volume.

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "octoray/core/geometry.h"

namespace octoray {
class VolumeSource;
}
namespace octoray::volume {
class StoreReader;
}

namespace octoray::gpu::reference {

class ReferenceVolume {
 public:
  // Throws octoray::Error for empty dims or a value count that does not match.
  ReferenceVolume(std::array<int64_t, 3> dims, const Mat4& patientFromIndex,
                  std::vector<float> values);

  // Reads every slab of `source` (throws octoray::Error from the source, or when the volume
  // does not fit the address space).
  static ReferenceVolume fromSource(VolumeSource& source);
  // Reads every leaf brick of the store and keeps each brick's interior (values in physical
  // units through the store's value mapping).
  static ReferenceVolume fromStore(const volume::StoreReader& store);

  const std::array<int64_t, 3>& dims() const { return dims_; }
  const Mat4& patientFromIndex() const { return patientFromIndex_; }
  float at(int64_t i, int64_t j, int64_t k) const {
    return values_[static_cast<std::size_t>(i + dims_[0] * (j + dims_[1] * k))];
  }
  const std::vector<float>& values() const { return values_; }
  // Trilinear interpolant at index-space point p (clamped as above), in double precision.
  double sample(double i, double j, double k) const;

 private:
  std::array<int64_t, 3> dims_;
  Mat4 patientFromIndex_;
  std::vector<float> values_;
};

}  // namespace octoray::gpu::reference
