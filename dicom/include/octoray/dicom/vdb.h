#pragma once
// Writing a VolumeSource as an OpenVDB file (.vdb): one sparse float grid named "density",
// streamed slab by slab. Samples >= the threshold are active voxels holding their exact value;
// every other sample is inactive and reads back as the background, -1000 (air in HU). The grid
// transform is the full index->patient affine (shear included): world space is patient LPS in
// mm. The reader (openVdb) is declared in formats.h beside the other readers.

#include <cstdint>
#include <functional>
#include <string>

#include "octoray/dicom/volume_source.h"

namespace octoray {

// Inactive voxels' value: air in Hounsfield units.
inline constexpr float kVdbBackground = -1000.0f;
// The exported grid's name: Blender's volume object reads any float grid, but its Principled
// Volume shader samples the grid named "density" by default.
inline constexpr const char* kVdbGridName = "density";

// Grid metadata written by exportVdb and read by openVdb. Never patient identifiers.
namespace vdb_meta {
inline constexpr const char* kCoordinates = "octoray_coordinates";  // "LPS": world = patient
inline constexpr const char* kUnits = "octoray_units";              // "mm": world units
inline constexpr const char* kValueUnit = "octoray_value_unit";     // "HU", or "" (raw values)
inline constexpr const char* kThreshold = "octoray_threshold";      // double: the active cut
inline constexpr const char* kDescription = "octoray_description";  // series description
inline constexpr const char* kModality = "octoray_modality";        // "CT", "MR", ... or ""
// Vec3i: the index box of the exported volume (inclusive). The reader restores the volume's
// extent from it, where the active voxels alone would give a smaller bounding box.
inline constexpr const char* kIndexMin = "octoray_index_min";
inline constexpr const char* kIndexMax = "octoray_index_max";
}  // namespace vdb_meta

struct VdbExportOptions {
  double thresholdHu = -900;  // samples >= this are active; NaN samples are never active
  std::function<void(int64_t slicesDone, int64_t slicesTotal)> progress;
};

struct VdbExportReport {
  int64_t activeVoxels = 0;  // samples >= the threshold
  uint64_t bytesOnDisk = 0;
};

// Writes `source` to `path` through a temporary file (.NAME.partial-PID beside it) renamed on
// success, so a failure or an interruption never leaves a partial file at `path`. Memory holds
// neither the grid's values nor its topology: one slab of 8 slices, 9 bytes per 8x8x8 block of
// the volume and 9 bytes per leaf (vdb_export.cpp says how). The leaves' values and masks pass
// through a second temporary file beside it (.NAME.spill-PID, about the size of the output),
// removed at the end. The file is the one OpenVDB's io::File writes for the same grid. Throws
// octoray::Error naming `path` when no sample reaches the threshold (the grid would be empty) or
// when writing fails.
VdbExportReport exportVdb(VolumeSource& source, const std::string& path,
                          const VdbExportOptions& options = {});

}  // namespace octoray
