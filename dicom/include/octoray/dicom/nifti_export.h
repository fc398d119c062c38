#pragma once
// Writing a VolumeSource as NIfTI-1 (.nii or .nii.gz), streamed slab by slab. The sform holds
// the full index->patient affine converted from LPS to NIfTI's RAS (shear included); the
// qform holds the same transform when it is a rotation times a scale, and is marked unknown
// when a shear (gantry tilt) makes that impossible.

#include <functional>
#include <string>

#include "octoray/dicom/volume_source.h"

namespace octoray {

struct NiftiExportOptions {
  std::function<void(int64_t slicesDone, int64_t slicesTotal)> progress;
};

// Writes `source` to `path` through a temporary file renamed on success, so a failure or an
// interruption never leaves a partial file at `path`. Integer-valued volumes whose values fit
// int16 are written as int16, everything else as float32.
void exportNifti(VolumeSource& source, const std::string& path,
                 const NiftiExportOptions& options = {});

}  // namespace octoray
