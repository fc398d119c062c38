#pragma once
// VolumeSource: the one interface every input format is read through. A source describes a
// regular index grid in patient space (VolumeInfo) and yields its samples a slab of slices at
// a time, in physical units (Hounsfield units for CT), so no caller ever needs the whole
// volume in memory.

#include <cstdint>
#include <limits>
#include <memory>
#include <span>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "octoray/core/geometry.h"

namespace octoray {

// A display window the source itself names (DICOM's WindowCenter / WindowWidth, PS3.3
// C.11.2.1.2), in the volume's unit: the modality LUT is applied before it, so a CT's are in HU.
// Readers and viewers show values in [center - width / 2, center + width / 2] from black to white.
struct SourceWindow {
  double center = 0;
  double width = 1;          // > 0
  std::string explanation;  // WindowCenterWidthExplanation ("BRAIN", "LUNG", ...) or ""
  // The VOI LUT function the file declares for it (VOILUTFunction, PS3.3 C.11.2.1.3):
  // "LINEAR_EXACT" or "SIGMOID"; "" where it declares none or LINEAR, the default (a viewer then
  // maps integer values with LINEAR and others with LINEAR_EXACT: sourceVoiFunction).
  std::string function;
};

// SourceWindow::function for a declared VOILUTFunction: "" for none or "LINEAR", the term
// itself for "LINEAR_EXACT" and "SIGMOID", nothing for any other text (not a defined term).
std::optional<std::string> sourceVoiFunction(std::string_view declared);

struct VolumeInfo {
  std::array<int64_t, 3> dims{0, 0, 0};  // samples along i (columns), j (rows), k (slices)
  Mat4 patientFromIndex;                 // index -> patient (LPS, mm); may contain shear
  std::string format;                    // "dicom", "raw", "nrrd", "metaimage", "nifti", "tiff", "vdb"
  std::string sourcePath;                // the file or folder the volume came from
  // Every file the samples are read from (a DICOM series' files, a header and its data file,
  // a TIFF folder's pages), sorted: what sourceContentHash() covers. Empty for sources that
  // are not files (the phantom, test volumes).
  std::vector<std::string> sourceFiles;
  std::string modality;                  // DICOM modality ("CT", "MR", ...) or empty
  std::string description;               // series description or file name
  std::string seriesUid;                 // DICOM SeriesInstanceUID or empty
  std::string unit;                      // "HU" for CT after rescale, else "" (raw values)
  // The windows the source names for display, in its order (the first is its default); empty
  // where it names none (every format but DICOM).
  std::vector<SourceWindow> windows;
  bool integerValues = true;             // every sample is an integer (exactly in float)
  // Every sample lies in [valueLowerBound, valueUpperBound], known from the storage type
  // (e.g. int16 raw data, or DICOM's BitsStored and rescale); NaN when unknown. Lets the
  // octree store keep 16-bit samples for integer data.
  double valueLowerBound = std::numeric_limits<double>::quiet_NaN();
  double valueUpperBound = std::numeric_limits<double>::quiet_NaN();
  double tiltDegrees = 0;                // angle between slice step and slice normal
  bool resampled = false;                // slices were interpolated to a uniform spacing
  std::vector<std::string> warnings;     // everything the reader had to decide or repair

  int64_t sliceSamples() const { return dims[0] * dims[1]; }
  int64_t sampleCount() const { return dims[0] * dims[1] * dims[2]; }
  // Length of each index axis in patient space: the sample spacing in mm.
  Vec3 spacingMm() const {
    return {length(patientFromIndex.column(0)), length(patientFromIndex.column(1)),
            length(patientFromIndex.column(2))};
  }
};

class VolumeSource {
 public:
  virtual ~VolumeSource() = default;
  virtual const VolumeInfo& info() const = 0;

  // Fills `out` (exactly sliceSamples() * sliceCount floats, slice-major, i fastest) with
  // slices [firstSlice, firstSlice + sliceCount). Thread-compatible, not thread-safe.
  virtual void readSlab(int64_t firstSlice, int64_t sliceCount, std::span<float> out) = 0;
};

// Checks that an index->patient affine is usable: finite, invertible, every spacing in
// [1e-6, 1e6] mm, the first voxel within 1e6 mm of the origin. Throws octoray::Error naming `path` otherwise. Every reader of geometry
// (DICOM stacks, the store builder, the store reader, the validators) applies it, so what one
// refuses none accepts.
void checkGeometry(const Mat4& patientFromIndex, const std::string& path);

// A hash of the contents of `files` (XXH3-128 of each file's bytes, combined in sorted order of
// those digests so neither the paths nor their order matter), as 32 hex digits. Identifies the
// data a store was built from (the store's provenance, octoray-batch's skip test). Throws
// octoray::Error naming the file that cannot be read.
std::string sourceContentHash(const std::vector<std::string>& files);
// Its parts: one file's XXH3-128 (32 hex digits), and the combination of such hashes
// (sourceContentHash(files) == combinedContentHash(fileContentHash of each file)).
std::string fileContentHash(const std::string& file);
std::string combinedContentHash(std::vector<std::string> fileHashes);

// Whether a volume's values are Hounsfield units, what its default windows and transfer
// functions follow. The source says yes with unit "HU" or DICOM modality "CT", and no with any
// other modality. Where it says nothing (NRRD, NIfTI, MetaImage, raw or TIFF without units),
// integer values reaching down to air, a minimum from -3100 to -900, are taken as CT, as
// clinicians' CT exports in those formats are; `guessed` (optional) is set in that case.
bool holdsHounsfieldUnits(const std::string& unit, const std::string& modality, bool integerValues,
                          double minimum, bool* guessed = nullptr);

// Checks a slab request against the volume; throws octoray::Error naming `path` if invalid.
void checkSlabRequest(const VolumeInfo& info, int64_t firstSlice, int64_t sliceCount,
                      std::size_t outSize);

}  // namespace octoray
