#pragma once
// Internal: the one slab reader behind every "header + raw samples" format (raw, NRRD,
// MetaImage, NIfTI). A header reader describes where the samples are (RawLayout); this reader
// streams slabs from there, uncompressed by seeking or compressed by inflating forward, and
// converts any sample type and byte order to float physical values.

#include <cstdint>
#include <memory>
#include <string>
#include <utility>

#include "octoray/dicom/formats.h"
#include "octoray/dicom/volume_source.h"

namespace octoray::detail {

enum class Compression {
  None,     // samples stored as is: slabs are read by seeking
  Deflate,  // one gzip (NRRD, .nii.gz) or zlib (MetaImage) stream, detected from its header
};

struct RawLayout {
  std::string dataPath;                  // file holding the samples
  std::array<int64_t, 3> dims{0, 0, 0};  // samples along i, j, k; i fastest
  SampleType sampleType = SampleType::Int16;
  bool bigEndian = false;
  uint64_t fileOffsetBytes = 0;    // where the samples (or the compressed stream) start in the file
  uint64_t streamOffsetBytes = 0;  // bytes to skip inside the decompressed stream (.nii.gz)
  Compression compression = Compression::None;
  double valueScale = 1;  // physical = stored * valueScale + valueOffset
  double valueOffset = 0;
};

// Throws octoray::Error naming `path` when the dims are not positive or the byte count of the
// volume does not fit 64 bits.
uint64_t volumeBytes(const std::array<int64_t, 3>& dims, SampleType type, const std::string& path);

// Whether every physical value is an integer: integer samples mapped by an integer scale and
// offset.
bool integerValued(SampleType type, double valueScale, double valueOffset);

// Converts `count` samples of `type` at `bytes` (byte-swapped first where `swap`) to
// value * scale + offset in `out`.
void convertSamples(SampleType type, const unsigned char* bytes, std::size_t count, bool swap,
                    double scale, double offset, float* out);

// The range of a sample type's values: [lowest, highest] for integers, ±infinity for floats.
std::pair<double, double> sampleTypeRange(SampleType type);

// Throws octoray::Error naming `path` when the index->patient transform is singular or not
// finite (zero spacing, parallel axes, NaN in a header).
void checkAffine(const Mat4& patientFromIndex, const std::string& path);

// A source reading `layout` with metadata `info` (dims must agree). Checks at once that an
// uncompressed file is long enough; a compressed one is checked as it is read.
std::unique_ptr<VolumeSource> openRawLayout(VolumeInfo info, RawLayout layout);

}  // namespace octoray::detail
