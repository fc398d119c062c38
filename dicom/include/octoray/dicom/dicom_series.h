#pragma once
// Discovery of image series in a folder (searched recursively) or a DICOMDIR, and their
// classification. Reading headers only: pixel data is decoded later, slab by slab.

#include <cstddef>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "octoray/core/geometry.h"
#include "octoray/dicom/volume_source.h"

namespace octoray::dicom {

enum class SeriesKind {
  Volume,            // original axial (or oblique) stack: what a volume is built from
  Localizer,         // scout / topogram (ImageType LOCALIZER, or a lone orthogonal view)
  SecondaryCapture,  // screenshots, exam summaries (Secondary Capture SOP classes)
  Derived,           // ImageType DERIVED: reformats, MIPs, summaries
  NoGeometry,        // images without ImagePositionPatient / ImageOrientationPatient
};
const char* toString(SeriesKind kind);

// One 2D image of a series: a single-frame file, or one frame of a multi-frame object.
struct FrameRef {
  std::string path;
  int frameIndex = 0;         // index of the frame inside a multi-frame file
  int instanceNumber = 0;     // InstanceNumber (for messages and duplicate choice only)
  Vec3 positionMm;            // ImagePositionPatient of this frame (centre of first pixel)
  double rescaleSlope = 1;    // modality LUT of this frame
  double rescaleIntercept = 0;
  std::string transferSyntaxUid;
};

struct DicomSeries {
  std::string seriesUid;
  int seriesNumber = 0;
  std::string modality;
  std::string description;
  std::string sopClassUid;
  std::vector<std::string> imageType;  // ImageType values, e.g. ORIGINAL PRIMARY AXIAL
  SeriesKind kind = SeriesKind::Volume;
  std::string kindReason;              // why it was classified so (for --list)
  // Why a geometry attribute its first image has could not be used (not finite numbers, or
  // too few), or "": said where the series has no geometry.
  std::string geometryProblem;
  bool multiFrame = false;             // frames come from enhanced multi-frame objects

  int rows = 0;
  int columns = 0;
  double rowSpacingMm = 0;      // PixelSpacing[0]: distance between rows (along columnDirection)
  double columnSpacingMm = 0;   // PixelSpacing[1]: distance between columns (along rowDirection)
  Vec3 rowDirection{1, 0, 0};   // ImageOrientationPatient[0..2]: direction of increasing column
  Vec3 columnDirection{0, 1, 0};  // ImageOrientationPatient[3..5]: direction of increasing row
  bool hasGeometry = false;
  int bitsAllocated = 0;
  int bitsStored = 0;         // of the first image (0 when absent)
  bool pixelSigned = false;   // PixelRepresentation == 1
  std::string photometric;
  // The display windows most of the series' frames name (WindowCenter / WindowWidth, or an
  // enhanced object's Frame VOI LUT), and what was wrong with any that were left out.
  std::vector<SourceWindow> windows;
  std::string windowWarning;

  std::vector<FrameRef> frames;  // in discovery order; geometry is resolved by DicomVolume

  Vec3 sliceNormal() const { return normalize(cross(rowDirection, columnDirection)); }
};

struct SkippedFile {
  std::string path;
  std::string reason;
};

struct DicomScan {
  std::vector<DicomSeries> series;       // sorted by series number, then UID
  std::vector<SkippedFile> skipped;      // files that are not usable images, and why
  std::vector<std::string> warnings;     // e.g. DICOMDIR entries whose files are missing
  std::size_t filesExamined = 0;
};

struct ScanOptions {
  // Called after each file header is read with (files done, files total).
  std::function<void(std::size_t, std::size_t)> progress;
};

// Who and when, for a viewer's patient corner (never written into a store: see the store's
// provenance). Empty strings where the file has no value. Throws octoray::Error naming the
// file when it cannot be parsed.
struct PatientIdentity {
  std::string name, id, birthDate, studyDate, studyDescription, studyUid;
};
PatientIdentity readPatientIdentity(const std::string& file);

// Whether `file` is a DICOM Part 10 file: "DICM" after its 128-byte preamble. Reads 132 bytes;
// false for anything that cannot be read.
bool isDicomPart10(const std::filesystem::path& file);

// Scans `path`: a folder (recursively), a DICOMDIR file, or a single DICOM file. A folder
// holding a DICOMDIR is still searched file by file, and the DICOMDIR's list is checked
// against what is present. Throws octoray::Error only when `path` itself cannot be read.
DicomScan scanDicom(const std::filesystem::path& path, const ScanOptions& options = {});

// Reads exactly `files` (sorted, duplicates dropped) and groups them into series as scanDicom
// does: what re-opens one series of an earlier scan from its list of files.
DicomScan scanDicomFiles(std::vector<std::string> files, const ScanOptions& options = {});

// The series a user most likely wants: the Volume series with the most frames. Throws
// octoray::Error naming `path` when there is no volumetric series.
std::size_t defaultSeriesIndex(const DicomScan& scan, const std::string& path);

// Warnings naming every file of the scan that could belong to series `chosen` but is not in
// its volume: images of the same SeriesInstanceUID split off into another part (different
// orientation, size or spacing), and files that could not be read at all (they may be its
// slices). Empty when nothing is left out. What --inspect, --export, -o and the viewer show.
std::vector<std::string> filesLeftOut(const DicomScan& scan, std::size_t chosen);

// Finds a series by 0-based table index ("2") or SeriesInstanceUID; throws when absent.
std::size_t findSeries(const DicomScan& scan, const std::string& indexOrUid,
                       const std::string& path);

}  // namespace octoray::dicom
