#pragma once
// Synthetic DICOM CT series with exactly known geometry and values: the built-in sample exam
// and the ground truth of the DICOM tests. Every pixel holds an analytic function of its
// PATIENT position (syntheticHu), so a reader's geometry can be checked pixel by pixel
// against the attributes written. Files are encoded by GDCM (gdcm::Writer, and
// gdcm::ImageChangeTransferSyntax for the compressed transfer syntaxes).

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "octoray/core/geometry.h"

namespace octoray::dicom {

// The analytic value field. Linear interpolates exactly (up to storage rounding); Smooth adds
// sinusoids so that wrong geometry cannot hide, with a bounded second derivative.
enum class SyntheticPattern { Linear, Smooth };

// Value (in HU) of the synthetic field at a patient position (LPS, mm).
double syntheticHu(Vec3 patientMm, SyntheticPattern pattern = SyntheticPattern::Smooth);
// Upper bound of |d²hu/ds²| along any unit direction (HU/mm²): linear interpolation over an
// interval of length h is off by at most h²/8 times this bound.
double syntheticHuSecondDerivativeBound(SyntheticPattern pattern);

enum class SyntheticStorage { Int16, UInt16 };

enum class SyntheticTransferSyntax {
  ExplicitVRLittleEndian,  // 1.2.840.10008.1.2.1 (default)
  ImplicitVRLittleEndian,  // 1.2.840.10008.1.2
  ExplicitVRBigEndian,     // 1.2.840.10008.1.2.2 (retired, still met in archives)
  RLELossless,             // 1.2.840.10008.1.2.5
  JPEGLossless,            // 1.2.840.10008.1.2.4.70 (process 14, selection value 1)
  JPEGLSLossless,          // 1.2.840.10008.1.2.4.80
  JPEG2000Lossless,        // 1.2.840.10008.1.2.4.90
};
const char* transferSyntaxUid(SyntheticTransferSyntax syntax);

enum class SyntheticLayout {
  SingleFrameFiles,    // one CT Image Storage file per slice
  EnhancedMultiFrame,  // one Enhanced CT Image Storage object holding every slice as a frame
};

struct SyntheticSeriesSpec {
  // In-plane grid.
  int rows = 16;
  int columns = 16;
  double rowSpacingMm = 0.5;     // PixelSpacing[0]: between rows, along columnDirection
  double columnSpacingMm = 0.5;  // PixelSpacing[1]: between columns, along rowDirection
  Vec3 rowDirection{1, 0, 0};    // ImageOrientationPatient[0..2] (normalised when written)
  Vec3 columnDirection{0, 1, 0};  // ImageOrientationPatient[3..5] (orthogonalised when written)

  // Slice positions: distances along the normal rowDirection x columnDirection. When the list
  // is empty, sliceCount slices sliceSpacingMm apart starting at distance 0.
  std::vector<double> sliceDistancesMm;
  int sliceCount = 8;
  double sliceSpacingMm = 1.25;
  double sliceThicknessMm = 0;  // SliceThickness; 0 = the smallest gap (sliceSpacingMm if one)
  // The patient point where the centre of the slice at distance 0 lies.
  Vec3 centreMm{0, 0, 0};
  // Gantry tilt: each slice's position moves along columnDirection by tan(tilt) * distance;
  // GantryDetectorTilt (0018,1120) records the angle.
  double tiltDegrees = 0;

  // Defects of real exams.
  bool reverseFileOrder = false;  // files and instance numbers run against the position order
  int duplicateSliceIndex = -1;   // this slice (index into the positions) is written twice
  int dropSliceIndex = -1;        // this slice is not written at all

  // Pixel storage and the modality LUT: stored = round((hu - intercept) / slope).
  SyntheticPattern pattern = SyntheticPattern::Smooth;
  SyntheticStorage storage = SyntheticStorage::Int16;
  int bitsStored = 16;             // 16, or fewer (HighBit = bitsStored - 1)
  uint16_t highBitsPattern = 0;    // bits written above HighBit; not part of the value
  double rescaleSlope = 1;
  double rescaleIntercept = -1024;
  bool monochrome1 = false;        // PhotometricInterpretation MONOCHROME1 (values unchanged)
  // PixelPaddingValue: pixels outside the circle inscribed in the slice hold this stored value.
  std::optional<int> pixelPaddingValue;

  SyntheticTransferSyntax transferSyntax = SyntheticTransferSyntax::ExplicitVRLittleEndian;
  SyntheticLayout layout = SyntheticLayout::SingleFrameFiles;
  // Display windows: every file names WindowCenter 40 / WindowWidth 400 (an enhanced object in
  // its shared Frame VOI LUT); in an enhanced object the first `framesWithOwnWindow` frames name
  // `ownWindow` (center, width; "LUNG") in their own per-frame Frame VOI LUT instead.
  int framesWithOwnWindow = 0;
  std::pair<double, double> ownWindow{-600, 1500};

  // Extra objects in the same study and folder.
  bool withLocalizer = false;         // one coronal CT image, ImageType ...\LOCALIZER
  bool withSecondaryCapture = false;  // one Secondary Capture image without geometry

  uint64_t seed = 1;  // all UIDs derive from it: the same spec writes the same files
  std::string patientName = "OCTORAY^SYNTHETIC";
  std::string patientId;  // empty: "SYN" and the seed
  int seriesNumber = 2;
  std::string seriesDescription = "octoray synthetic CT";
};

enum class SyntheticObject { Slice, Localizer, SecondaryCapture };

// One written image (a file, or one frame of the enhanced object).
struct SyntheticImage {
  std::filesystem::path path;
  SyntheticObject object = SyntheticObject::Slice;
  int frameIndex = 0;          // frame inside the file (enhanced multi-frame), else 0
  int instanceNumber = 0;
  int positionIndex = -1;      // index into the slice positions (Slice only)
  double distanceMm = 0;       // position along the slice normal (Slice only)
  Vec3 positionMm;             // ImagePositionPatient exactly as written (parsed back)
  bool duplicate = false;      // the second copy of a duplicated position
};

struct SyntheticSeries {
  std::vector<SyntheticImage> images;  // slices in file order, then localizer, SC
  std::vector<std::filesystem::path> files;  // every file written, in writing order
  std::string studyUid;
  std::string seriesUid;
  std::string localizerSeriesUid;
  std::string secondaryCaptureSeriesUid;
  // Geometry exactly as written (the decimal strings parsed back).
  Vec3 rowDirection;
  Vec3 columnDirection;
  double rowSpacingMm = 0;
  double columnSpacingMm = 0;
  double sliceThicknessMm = 0;
  double tiltDegrees = 0;
  std::string transferSyntaxUid;

  // The slice images only (duplicates included), in file order.
  std::vector<SyntheticImage> slices() const;
  // Patient position of pixel (column, row) of a slice image, from the written attributes.
  Vec3 pixelPositionMm(const SyntheticImage& image, double column, double row) const;
};

// The slice distances of `spec` (explicit list, or count x spacing), before drop/duplicate.
std::vector<double> syntheticSliceDistances(const SyntheticSeriesSpec& spec);

// The value a reader should produce at a pixel: the stored integer mapped back through the
// modality LUT, slope * round((hu - intercept) / slope) + intercept.
double syntheticWrittenHu(const SyntheticSeriesSpec& spec, Vec3 patientMm);

// True when pixel (column, row) lies outside the circle inscribed in the slice, so it holds
// PixelPaddingValue when the spec asks for padding.
bool syntheticIsPadding(const SyntheticSeriesSpec& spec, int column, int row);

// Writes the series into `folder` (created if needed; existing files of the same names are
// replaced). Throws octoray::Error naming the folder or file when the spec is inconsistent
// (e.g. a value that does not fit the storage) or a file cannot be written or encoded.
SyntheticSeries writeSyntheticSeries(const std::filesystem::path& folder,
                                     const SyntheticSeriesSpec& spec);

}  // namespace octoray::dicom
