#pragma once
// A deterministic synthetic CT-like volume of any size, computed slab by slab: skull shell,
// brain-like soft tissue, air cavities, vessels, fine high-frequency detail and noise, in HU.
// Scale tests and benchmarks need no download and no large memory.
//
// As a scanner's images, it is band-limited: the painted anatomy (hard tissue boundaries)
// plus correlated noise is convolved with a Gaussian point-spread function of
// psfSigmaVoxels (default 1 voxel) on every axis, so boundaries carry a partial-volume ramp
// and the noise has the blotchy texture of reconstructed CT; white noise (+-11 HU) is added
// after. psfSigmaVoxels = 0 gives the old hard-edged phantom (white noise only), whose
// surfaces show terraces at any rendering step.

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "octoray/dicom/volume_source.h"

namespace octoray::volume {

struct PhantomOptions {
  std::array<int64_t, 3> dims{256, 256, 256};
  uint64_t seed = 1;
  Vec3 spacingMm{0.5, 0.5, 0.5};
  double psfSigmaVoxels = 1.0;  // 0: hard edges; at most 4
};

// A VolumeSource whose samples are a pure function of (index, seed): any slab can be asked for
// in any order and gives the same values. Values are integer HU in [-1024, 3071].
std::unique_ptr<VolumeSource> makePhantom(const PhantomOptions& options);

// Writes the phantom as a detached NRRD header (`path`, .nhdr or .nrrd) with raw int16
// little-endian data beside it (`path` with extension .raw), generated slab by slab, through
// temporary names renamed on success.
void writePhantomNrrd(const PhantomOptions& options, const std::string& path,
                      const std::function<void(int64_t slicesDone, int64_t slicesTotal)>& progress = {});

}  // namespace octoray::volume
