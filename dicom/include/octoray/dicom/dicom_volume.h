#pragma once
// From a series of 2D frames to a regular index grid in patient space: slices sorted along
// the slice normal, duplicates and missing slices detected, gantry tilt kept exactly as a
// shear in the affine, uneven slice spacing resampled to a uniform spacing, stored values
// mapped to physical units. The result is a VolumeSource that decodes a slab at a time.

#include <cstddef>
#include <memory>
#include <string>
#include <vector>

#include "octoray/dicom/dicom_series.h"
#include "octoray/dicom/volume_source.h"

namespace octoray::dicom {

struct StackOptions {
  // Output spacing when slices must be resampled; 0 = smallest gap. A spacing that would make
  // more than max(16 x images, 4096) slices is refused (resolveStack throws).
  double sliceSpacingMm = 0;
  // A multi-frame object is decoded a run of frames at a time, each run at most this many bytes
  // of decoded values (at least one frame); a run per thread is kept while its frames are read.
  std::size_t frameRunBytes = std::size_t{8} << 20;
};

// The resolved geometry of a stack of frames.
struct StackGeometry {
  std::vector<FrameRef> slices;      // unique frames sorted by distance along the normal
  std::vector<double> distancesMm;   // each slice's ImagePositionPatient along the normal
  std::vector<FrameRef> duplicates;  // frames dropped because another has the same position
  Vec3 sliceStepMm;                  // patient-space step from one output slice to the next
  double tiltDegrees = 0;            // angle between sliceStepMm and the slice normal
  double minGapMm = 0, maxGapMm = 0, medianGapMm = 0;
  int missingSlices = 0;             // gaps that are whole multiples of the median gap
  bool uniform = true;               // gaps equal within tolerance: no resampling needed
  double outputSpacingMm = 0;        // spacing along the normal of the output grid
  int64_t outputSlices = 0;
  Mat4 patientFromIndex;
  std::vector<std::string> warnings;
};

// Sorts and checks the frames of `series`; throws octoray::Error when they cannot form a
// volume (no geometry, mixed orientation, positions off a line, ...).
StackGeometry resolveStack(const DicomSeries& series, const StackOptions& options = {});

// Opens `series` as a streamed source with values in HU (CT) or rescaled stored values.
std::unique_ptr<VolumeSource> openDicomSeries(const DicomSeries& series,
                                              const StackOptions& options = {});

}  // namespace octoray::dicom
