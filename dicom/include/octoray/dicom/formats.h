#pragma once
// Non-DICOM inputs behind the same VolumeSource interface: raw volumes described on the
// command line, NRRD and MetaImage (header + raw or compressed data), NIfTI-1/2, TIFF stacks
// (a folder of single-page TIFFs, or one multi-page TIFF) and OpenVDB grids. And openVolume(),
// which picks the reader from what a path is.

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "octoray/dicom/dicom_volume.h"
#include "octoray/dicom/volume_source.h"

namespace octoray {

enum class SampleType { UInt8, Int8, UInt16, Int16, UInt32, Int32, Float32, Float64 };
// Parses "uint8", "int16", "float32", ... (also NRRD/MetaImage spellings such as "short",
// "MET_SHORT"); throws octoray::Error for anything else.
SampleType parseSampleType(const std::string& name);
std::size_t sampleBytes(SampleType type);

struct RawOptions {
  std::array<int64_t, 3> dims{0, 0, 0};
  SampleType sampleType = SampleType::Int16;
  bool bigEndian = false;
  Vec3 spacingMm{1, 1, 1};
  Vec3 originMm{0, 0, 0};
  uint64_t headerBytes = 0;  // bytes to skip before the first sample
};

std::unique_ptr<VolumeSource> openRawVolume(const std::string& path, const RawOptions& options);
std::unique_ptr<VolumeSource> openNrrd(const std::string& path);
std::unique_ptr<VolumeSource> openMetaImage(const std::string& path);
std::unique_ptr<VolumeSource> openNifti(const std::string& path);
// A TIFF stack: a multi-page file, or a folder whose .tif/.tiff files (in natural order:
// s2 before s10) are its slices. Anything else in the folder is left out with a warning.
std::unique_ptr<VolumeSource> openTiffStack(const std::string& path, Vec3 spacingMm = {1, 1, 1});
// A folder's visible entries (hidden ones such as .DS_Store and macOS's ._s001.tif are not
// counted), split into regular files with a .tif or .tiff extension and everything else, each
// in natural order. Throws octoray::Error naming the folder when it cannot be listed.
struct TiffFolder {
  std::string path;
  std::vector<std::string> tiffNames, otherNames;
};
TiffFolder listTiffFolder(const std::string& folder);
// The TIFF stack of a folder listed by listTiffFolder, which must hold a TIFF file.
std::unique_ptr<VolumeSource> openTiffStack(const TiffFolder& folder, Vec3 spacingMm);
// The "density" float grid, else the first float or double grid, over its active voxels'
// bounding box (or the index box octoray's export recorded); the grid's transform must be
// linear and becomes patientFromIndex. Inactive voxels read as the background (vdb.h).
// A grid whose leaves hold more than `wholeGridBytes` of values is never in memory whole: its
// topology (about 1/20 of its values) is read first and kept, then its leaves' values a leaf
// at a time, each once per pass: all of them at open, for the value range, then those of one
// band of slices (at most about a quarter of that limit) at a time as slabs are read; a file
// written to after it was opened is then an error. Only a file that records where its grids
// are (every file io::File writes) can be read so; one without (io::Stream's) is read whole at
// any size.
inline constexpr uint64_t kVdbWholeGridBytes = uint64_t{1} << 30;
std::unique_ptr<VolumeSource> openVdb(const std::string& path,
                                      uint64_t wholeGridBytes = kVdbWholeGridBytes);

struct OpenOptions {
  std::string series;          // DICOM: table index or SeriesInstanceUID; empty = default
  dicom::StackOptions stack;   // DICOM: resampling choice
  bool raw = false;            // treat the path as a raw volume described by `rawOptions`
  RawOptions rawOptions;
  Vec3 tiffSpacingMm{1, 1, 1};
};

// Opens any supported input: a DICOM folder, DICOMDIR or file; .nrrd/.nhdr; .mhd/.mha;
// .nii/.nii.gz; .tif/.tiff or a folder of them; .vdb; or a raw file when options.raw is set.
std::unique_ptr<VolumeSource> openVolume(const std::string& path, const OpenOptions& options = {});

}  // namespace octoray
