#include "octoray/dicom/volume_source.h"

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

}  // namespace octoray
