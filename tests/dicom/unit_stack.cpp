// Stack resolution and values against synthetic series: every written pixel's patient
// position (from the attributes as written) is mapped through the reader's inverse affine,
// and the volume must hold the written value there: exactly where no resampling happened,
// within a tolerance derived from the interpolation error bound where it did.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "octoray/dicom/dicom_series.h"
#include "octoray/dicom/dicom_volume.h"
#include "octoray/core/error.h"
#include "octoray/dicom/synthetic_series.h"
#include "test_paths.h"

namespace octoray::dicom {
namespace {

constexpr double kIndexTolerance = 1e-6;  // written pixels must land on index-grid points
constexpr float kPaddingHu = -1024.0f;    // padding is documented to become air for CT

struct LoadedStack {
  DicomScan scan;
  DicomSeries series;
  StackGeometry geometry;
  VolumeInfo info;
  std::vector<float> values;  // the whole (small) volume, slice-major, i fastest

  float at(int64_t i, int64_t j, int64_t k) const {
    return values[static_cast<std::size_t>((k * info.dims[1] + j) * info.dims[0] + i)];
  }
};

// Scans `folder`, takes its default (volume) series, resolves and reads it whole.
LoadedStack load(const std::filesystem::path& folder, const StackOptions& options = {}) {
  LoadedStack loaded;
  loaded.scan = scanDicom(folder);
  loaded.series = loaded.scan.series.at(defaultSeriesIndex(loaded.scan, folder.string()));
  loaded.geometry = resolveStack(loaded.series, options);
  auto source = openDicomSeries(loaded.series, options);
  loaded.info = source->info();
  loaded.values.resize(static_cast<std::size_t>(loaded.info.sampleCount()));
  source->readSlab(0, loaded.info.dims[2], loaded.values);
  return loaded;
}

bool hasWarning(const std::vector<std::string>& warnings, const std::string& word) {
  return std::any_of(warnings.begin(), warnings.end(),
                     [&](const std::string& w) { return w.find(word) != std::string::npos; });
}

double nearestInteger(double v) { return std::round(v); }

// The value a reader must produce for one written pixel.
double expectedHu(const SyntheticSeriesSpec& spec, const SyntheticSeries& written,
                  const SyntheticImage& image, int column, int row) {
  if (spec.pixelPaddingValue && syntheticIsPadding(spec, column, row)) return kPaddingHu;
  return syntheticWrittenHu(spec, written.pixelPositionMm(image, column, row));
}

// Every pixel of every written slice: its index must be integral in-plane; along k it must be
// integral too (exactly equal value) unless `resampledToleranceHu` >= 0, in which case a
// fractional k is interpolated linearly between the two output slices around it. Output
// slices that coincide with a written slice (k integral) must reproduce it exactly.
void checkWrittenPixels(const SyntheticSeriesSpec& spec, const SyntheticSeries& written,
                        const LoadedStack& loaded, double resampledToleranceHu = -1) {
  const Mat4 indexFromPatient = loaded.info.patientFromIndex.inverseAffine();
  int failures = 0;
  double worstHu = 0;
  for (const SyntheticImage& image : written.slices()) {
    for (int r = 0; r < spec.rows; ++r) {
      for (int c = 0; c < spec.columns; ++c) {
        const Vec3 index = indexFromPatient.transformPoint(written.pixelPositionMm(image, c, r));
        const double i = nearestInteger(index.x), j = nearestInteger(index.y);
        const double kRound = nearestInteger(index.z);
        const bool kIntegral = std::abs(index.z - kRound) <= kIndexTolerance;
        const bool inPlaneOk = std::abs(index.x - i) <= kIndexTolerance &&
                               std::abs(index.y - j) <= kIndexTolerance && i >= 0 && j >= 0 &&
                               i < static_cast<double>(loaded.info.dims[0]) &&
                               j < static_cast<double>(loaded.info.dims[1]);
        const bool kInRange = index.z >= -kIndexTolerance &&
                              index.z <= static_cast<double>(loaded.info.dims[2] - 1) + kIndexTolerance;
        if (!inPlaneOk || !kInRange || (!kIntegral && resampledToleranceHu < 0)) {
          if (++failures <= 5) {
            ADD_FAILURE() << image.path.filename() << " frame " << image.frameIndex << " pixel (" << c
                          << ", " << r << ") maps to index (" << index.x << ", " << index.y
                          << ", " << index.z << "), volume dims " << loaded.info.dims[0] << "x"
                          << loaded.info.dims[1] << "x" << loaded.info.dims[2];
          }
          continue;
        }
        const double expected = expectedHu(spec, written, image, c, r);
        const auto ii = static_cast<int64_t>(i), jj = static_cast<int64_t>(j);
        if (kIntegral) {
          const float actual = loaded.at(ii, jj, static_cast<int64_t>(kRound));
          if (actual != static_cast<float>(expected) && ++failures <= 5) {
            ADD_FAILURE() << image.path.filename() << " frame " << image.frameIndex << " pixel ("
                          << c << ", " << r << ") at k=" << kRound << ": volume " << actual
                          << ", written " << expected;
          }
          continue;
        }
        const auto k0 = static_cast<int64_t>(std::floor(index.z));
        const double w = index.z - static_cast<double>(k0);
        const double actual = (1 - w) * loaded.at(ii, jj, k0) + w * loaded.at(ii, jj, k0 + 1);
        worstHu = std::max(worstHu, std::abs(actual - expected));
        if (std::abs(actual - expected) > resampledToleranceHu && ++failures <= 5) {
          ADD_FAILURE() << image.path.filename() << " pixel (" << c << ", " << r << ") at k="
                        << index.z << ": interpolated " << actual << ", written " << expected
                        << ", tolerance " << resampledToleranceHu;
        }
      }
    }
  }
  EXPECT_EQ(failures, 0) << "worst interpolation error " << worstHu << " HU";
}

// Bound on |interpolated volume - written value| at a written pixel in a resampled stack:
// the written value and each input sample are rounded to the stored grid (slope/2 each), the
// resampled output is rounded to whole units when the data are integers (0.5), and each of
// the two linear interpolations (input gap hIn, output step hOut, both along the stack line)
// is off by at most h²/8 times the field's second-derivative bound; plus float32 rounding.
double resampledToleranceHu(const SyntheticSeriesSpec& spec, double hInMm, double hOutMm) {
  return spec.rescaleSlope + 0.5 +
         (hInMm * hInMm + hOutMm * hOutMm) / 8 * syntheticHuSecondDerivativeBound(spec.pattern) +
         1e-3;
}

void expectSameVolume(const LoadedStack& a, const LoadedStack& b) {
  ASSERT_EQ(a.info.dims, b.info.dims);
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) {
      EXPECT_NEAR(a.info.patientFromIndex.m[r][c], b.info.patientFromIndex.m[r][c], 1e-9);
    }
  }
  ASSERT_EQ(a.values.size(), b.values.size());
  std::size_t differing = 0;
  for (std::size_t n = 0; n < a.values.size(); ++n) differing += a.values[n] != b.values[n];
  EXPECT_EQ(differing, 0u) << "of " << a.values.size() << " voxels";
}

TEST(StackSynthetic, UniformSeriesIsExact) {
  SyntheticSeriesSpec spec;
  const auto dir = test::freshTempDir("series");
  const SyntheticSeries written = writeSyntheticSeries(dir, spec);
  const LoadedStack loaded = load(dir);
  EXPECT_EQ(loaded.info.dims[2], spec.sliceCount);
  EXPECT_FALSE(loaded.info.resampled);
  EXPECT_EQ(loaded.info.unit, "HU");
  EXPECT_EQ(loaded.series.seriesUid, written.seriesUid);
  checkWrittenPixels(spec, written, loaded);
}

TEST(StackSynthetic, SingleSliceIsOneVoxelThickWithWarning) {
  SyntheticSeriesSpec spec;
  spec.sliceCount = 1;
  const auto dir = test::freshTempDir("series");
  const SyntheticSeries written = writeSyntheticSeries(dir, spec);
  const LoadedStack loaded = load(dir);
  EXPECT_EQ(loaded.info.dims[2], 1);
  // DicomSeries carries no SliceThickness, so resolveStack uses 1 mm (or the override).
  EXPECT_NEAR(loaded.geometry.outputSpacingMm, 1.0, 1e-12);
  EXPECT_NEAR(loaded.info.spacingMm().z, 1.0, 1e-9);
  EXPECT_TRUE(hasWarning(loaded.info.warnings, "single slice"));
  checkWrittenPixels(spec, written, loaded);

  StackOptions options;
  options.sliceSpacingMm = 2.5;
  EXPECT_NEAR(resolveStack(loaded.series, options).outputSpacingMm, 2.5, 1e-12);
}

TEST(StackSynthetic, TwoSlices) {
  SyntheticSeriesSpec spec;
  spec.sliceCount = 2;
  spec.sliceSpacingMm = 3;
  const auto dir = test::freshTempDir("series");
  const SyntheticSeries written = writeSyntheticSeries(dir, spec);
  const LoadedStack loaded = load(dir);
  EXPECT_EQ(loaded.info.dims[2], 2);
  EXPECT_NEAR(loaded.info.spacingMm().z, 3.0, 1e-9);
  checkWrittenPixels(spec, written, loaded);
}

TEST(StackSynthetic, ReversedFileOrderIsSortedByPosition) {
  SyntheticSeriesSpec spec;
  spec.reverseFileOrder = true;
  const auto dir = test::freshTempDir("series");
  const SyntheticSeries written = writeSyntheticSeries(dir, spec);
  const LoadedStack loaded = load(dir);
  EXPECT_EQ(loaded.info.dims[2], spec.sliceCount);
  EXPECT_FALSE(loaded.info.resampled);
  // Instance 1 holds the last position: it must end up as the last slice along the normal.
  EXPECT_EQ(loaded.geometry.slices.back().instanceNumber, 1);
  checkWrittenPixels(spec, written, loaded);
}

TEST(StackSynthetic, NormalAgainstPositionOrder) {
  // rowDir x colDir = (1,0,0) x (0,-1,0) = -z, while z grows with the instance number.
  SyntheticSeriesSpec spec;
  spec.columnDirection = {0, -1, 0};
  spec.sliceDistancesMm = {0, -1.25, -2.5, -3.75, -5, -6.25};
  const auto dir = test::freshTempDir("series");
  const SyntheticSeries written = writeSyntheticSeries(dir, spec);
  ASSERT_LT(written.slices().front().positionMm.z, written.slices().back().positionMm.z);
  const LoadedStack loaded = load(dir);
  EXPECT_EQ(loaded.info.dims[2], 6);
  EXPECT_FALSE(loaded.info.resampled);
  EXPECT_NEAR(std::abs(loaded.info.tiltDegrees), 0.0, 1e-6);
  checkWrittenPixels(spec, written, loaded);
}

TEST(StackSynthetic, ObliqueOrientation) {
  constexpr double kDeg = 3.14159265358979323846 / 180;
  SyntheticSeriesSpec spec;
  spec.rowDirection = {std::cos(20 * kDeg), std::sin(20 * kDeg), 0};
  spec.columnDirection = {-std::sin(20 * kDeg) * std::cos(35 * kDeg),
                          std::cos(20 * kDeg) * std::cos(35 * kDeg), std::sin(35 * kDeg)};
  spec.rowSpacingMm = 0.7;
  spec.columnSpacingMm = 0.45;
  spec.centreMm = {12.5, -40, 77};
  const auto dir = test::freshTempDir("series");
  const SyntheticSeries written = writeSyntheticSeries(dir, spec);
  const LoadedStack loaded = load(dir);
  EXPECT_FALSE(loaded.info.resampled);
  EXPECT_NEAR(loaded.info.spacingMm().x, 0.45, 1e-9);
  EXPECT_NEAR(loaded.info.spacingMm().y, 0.7, 1e-9);
  checkWrittenPixels(spec, written, loaded);
}

TEST(StackSynthetic, GantryTiltKeptAsExactShear) {
  SyntheticSeriesSpec spec;
  spec.tiltDegrees = 15;
  spec.sliceCount = 10;
  const auto dir = test::freshTempDir("series");
  const SyntheticSeries written = writeSyntheticSeries(dir, spec);
  const LoadedStack loaded = load(dir);
  EXPECT_FALSE(loaded.info.resampled);
  EXPECT_NEAR(loaded.info.tiltDegrees, 15.0, 1e-6);
  EXPECT_TRUE(hasWarning(loaded.info.warnings, "tilt"));
  // Column 2 is the step between consecutive slices, in-plane shift included.
  const auto slices = written.slices();
  const Vec3 step = loaded.info.patientFromIndex.column(2);
  const Vec3 expectedStep = slices[1].positionMm - slices[0].positionMm;
  EXPECT_NEAR(length(step - expectedStep), 0.0, 1e-6);
  checkWrittenPixels(spec, written, loaded);
}

TEST(StackSynthetic, DuplicatePositionDroppedWithWarning) {
  SyntheticSeriesSpec spec;
  spec.duplicateSliceIndex = 3;
  const auto dir = test::freshTempDir("series");
  const SyntheticSeries written = writeSyntheticSeries(dir, spec);
  ASSERT_EQ(written.slices().size(), static_cast<std::size_t>(spec.sliceCount + 1));
  const LoadedStack loaded = load(dir);
  EXPECT_EQ(loaded.info.dims[2], spec.sliceCount);
  ASSERT_EQ(loaded.geometry.duplicates.size(), 1u);
  EXPECT_EQ(loaded.geometry.duplicates[0].instanceNumber, 5);  // the second copy
  EXPECT_TRUE(hasWarning(loaded.info.warnings, "duplicate"));
  EXPECT_FALSE(loaded.info.resampled);
  checkWrittenPixels(spec, written, loaded);
}

TEST(StackSynthetic, MissingSliceResampledWithWarning) {
  SyntheticSeriesSpec spec;
  spec.pattern = SyntheticPattern::Linear;
  spec.dropSliceIndex = 3;
  const auto dir = test::freshTempDir("series");
  const SyntheticSeries written = writeSyntheticSeries(dir, spec);
  const LoadedStack loaded = load(dir);
  EXPECT_EQ(loaded.geometry.missingSlices, 1);
  EXPECT_TRUE(hasWarning(loaded.info.warnings, "missing"));
  EXPECT_TRUE(loaded.info.resampled);
  ASSERT_EQ(loaded.info.dims[2], spec.sliceCount);  // the grid keeps the usual 1.25 mm step
  EXPECT_NEAR(loaded.info.spacingMm().z, spec.sliceSpacingMm, 1e-9);
  // Written slices sit on output slices: exact.
  checkWrittenPixels(spec, written, loaded);
  // The missing slice is interpolated across a 2.5 mm gap: linear field, so only storage
  // rounding (slope/2) and output rounding (0.5) remain.
  const SyntheticImage before = written.slices()[2];  // a copy: slices() returns a new vector
  const double toleranceHu = spec.rescaleSlope / 2 + 0.5 + 1e-3;
  for (int r = 0; r < spec.rows; ++r) {
    for (int c = 0; c < spec.columns; ++c) {
      const Vec3 p = written.pixelPositionMm(before, c, r) + spec.sliceSpacingMm * Vec3{0, 0, 1};
      EXPECT_NEAR(loaded.at(c, r, 3), syntheticHu(p, spec.pattern), toleranceHu);
    }
  }
}

TEST(StackSynthetic, VariableGapsResampledToSmallestGap) {
  for (SyntheticPattern pattern : {SyntheticPattern::Linear, SyntheticPattern::Smooth}) {
    SCOPED_TRACE(pattern == SyntheticPattern::Linear ? "linear" : "smooth");
    SyntheticSeriesSpec spec;
    spec.pattern = pattern;
    spec.sliceDistancesMm = {0, 1, 2.5, 3.5, 5, 6};  // gaps 1, 1.5, 1, 1.5, 1
    const auto dir = test::freshTempDir(pattern == SyntheticPattern::Linear ? "linear" : "smooth");
    const SyntheticSeries written = writeSyntheticSeries(dir, spec);
    const LoadedStack loaded = load(dir);
    EXPECT_TRUE(loaded.info.resampled);
    EXPECT_TRUE(hasWarning(loaded.info.warnings, "resampled"));
    EXPECT_NEAR(loaded.geometry.minGapMm, 1.0, 1e-9);
    EXPECT_NEAR(loaded.geometry.maxGapMm, 1.5, 1e-9);
    EXPECT_NEAR(loaded.info.spacingMm().z, 1.0, 1e-9);
    EXPECT_EQ(loaded.info.dims[2], 7);  // 6 mm span on a 1 mm grid
    checkWrittenPixels(spec, written, loaded, resampledToleranceHu(spec, 1.5, 1.0));
  }
}

TEST(StackSynthetic, VariableGapsWithSpacingOverride) {
  SyntheticSeriesSpec spec;
  spec.sliceDistancesMm = {0, 1, 2.5, 3.5, 5, 6};
  const auto dir = test::freshTempDir("series");
  const SyntheticSeries written = writeSyntheticSeries(dir, spec);
  StackOptions options;
  options.sliceSpacingMm = 0.75;
  const LoadedStack loaded = load(dir, options);
  EXPECT_TRUE(loaded.info.resampled);
  EXPECT_NEAR(loaded.info.spacingMm().z, 0.75, 1e-9);
  EXPECT_EQ(loaded.info.dims[2], 9);  // 6 mm span on a 0.75 mm grid
  checkWrittenPixels(spec, written, loaded, resampledToleranceHu(spec, 1.5, 0.75));
}

// Evenly spaced slices resampled because --slice-spacing asked for it: the warning says so,
// not that the spacing "varies from 2.000 to 2.000 mm".
TEST(StackSynthetic, EvenSlicesWithSpacingOverrideSayWhy) {
  SyntheticSeriesSpec spec;
  spec.sliceCount = 4;
  spec.sliceSpacingMm = 2;
  const auto dir = test::freshTempDir("series");
  writeSyntheticSeries(dir, spec);
  StackOptions options;
  options.sliceSpacingMm = 1;
  const LoadedStack loaded = load(dir, options);
  EXPECT_TRUE(loaded.info.resampled);
  EXPECT_EQ(loaded.info.dims[2], 7);
  EXPECT_TRUE(hasWarning(loaded.info.warnings, "the slices are 2.000 mm apart; --slice-spacing; "
                                               "resampled to 7 slices 1.0000 mm apart"));
  EXPECT_FALSE(hasWarning(loaded.info.warnings, "varies"));
}

TEST(StackSynthetic, SignedUnsignedAndNonIntegerRescale) {
  struct Case {
    const char* name;
    SyntheticStorage storage;
    double slope, intercept;
  };
  for (const Case& c : {Case{"int16", SyntheticStorage::Int16, 1, 0},
                        Case{"uint16", SyntheticStorage::UInt16, 1, -1024},
                        Case{"uint16-slope", SyntheticStorage::UInt16, 0.5, -1024.25},
                        Case{"int16-slope", SyntheticStorage::Int16, 2.5, 7}}) {
    SCOPED_TRACE(c.name);
    SyntheticSeriesSpec spec;
    spec.storage = c.storage;
    spec.rescaleSlope = c.slope;
    spec.rescaleIntercept = c.intercept;
    const auto dir = test::freshTempDir(c.name);
    const SyntheticSeries written = writeSyntheticSeries(dir, spec);
    const LoadedStack loaded = load(dir);
    EXPECT_EQ(loaded.info.integerValues, c.slope == std::round(c.slope) &&
                                             c.intercept == std::round(c.intercept));
    checkWrittenPixels(spec, written, loaded);
  }
}

TEST(StackSynthetic, BitsAboveHighBitAreIgnored) {
  struct Case {
    const char* name;
    SyntheticStorage storage;
    double intercept;
    uint16_t highBits;
    SyntheticTransferSyntax syntax;
  };
  for (const Case& c :
       {Case{"u12", SyntheticStorage::UInt16, -1024, 0xA, SyntheticTransferSyntax::ExplicitVRLittleEndian},
        Case{"s12", SyntheticStorage::Int16, 0, 0x5, SyntheticTransferSyntax::ExplicitVRLittleEndian},
        Case{"s12-be", SyntheticStorage::Int16, 0, 0xF, SyntheticTransferSyntax::ExplicitVRBigEndian},
        Case{"s12-rle", SyntheticStorage::Int16, 0, 0x9, SyntheticTransferSyntax::RLELossless}}) {
    SCOPED_TRACE(c.name);
    SyntheticSeriesSpec spec;
    spec.storage = c.storage;
    spec.bitsStored = 12;
    spec.highBitsPattern = c.highBits;
    spec.rescaleIntercept = c.intercept;
    spec.transferSyntax = c.syntax;
    const auto dir = test::freshTempDir(c.name);
    const SyntheticSeries written = writeSyntheticSeries(dir, spec);
    try {
      checkWrittenPixels(spec, written, load(dir));
    } catch (const Error& e) {
      ADD_FAILURE() << e.what();  // report and go on with the other cases
    }
  }
}

TEST(StackSynthetic, Monochrome1KeepsHu) {
  SyntheticSeriesSpec spec;
  spec.monochrome1 = true;
  const auto dir = test::freshTempDir("series");
  const SyntheticSeries written = writeSyntheticSeries(dir, spec);
  const LoadedStack loaded = load(dir);
  EXPECT_EQ(loaded.series.photometric, "MONOCHROME1");
  EXPECT_TRUE(hasWarning(loaded.info.warnings, "MONOCHROME1"));
  checkWrittenPixels(spec, written, loaded);  // no inversion: values are HU as written
}

TEST(StackSynthetic, PaddingBecomesAir) {
  for (SyntheticStorage storage : {SyntheticStorage::Int16, SyntheticStorage::UInt16}) {
    const bool isSigned = storage == SyntheticStorage::Int16;
    SCOPED_TRACE(isSigned ? "signed" : "unsigned");
    SyntheticSeriesSpec spec;
    spec.storage = storage;
    spec.pixelPaddingValue = isSigned ? -2000 : 0;
    spec.rescaleIntercept = isSigned ? 0 : -1024;
    const auto dir = test::freshTempDir(isSigned ? "signed" : "unsigned");
    const SyntheticSeries written = writeSyntheticSeries(dir, spec);
    ASSERT_TRUE(syntheticIsPadding(spec, 0, 0));
    checkWrittenPixels(spec, written, load(dir));
  }
}

TEST(StackSynthetic, EnhancedMultiFrameEqualsSingleFiles) {
  SyntheticSeriesSpec spec;
  spec.tiltDegrees = -7;
  spec.reverseFileOrder = true;
  const auto singleDir = test::freshTempDir("single");
  const auto enhancedDir = test::freshTempDir("enhanced");
  writeSyntheticSeries(singleDir, spec);
  spec.layout = SyntheticLayout::EnhancedMultiFrame;
  const SyntheticSeries written = writeSyntheticSeries(enhancedDir, spec);
  ASSERT_EQ(written.files.size(), 1u);
  const LoadedStack enhanced = load(enhancedDir);
  EXPECT_TRUE(enhanced.series.multiFrame);
  EXPECT_EQ(enhanced.series.frames.size(), static_cast<std::size_t>(spec.sliceCount));
  EXPECT_NEAR(enhanced.info.tiltDegrees, -7.0, 1e-6);
  checkWrittenPixels(spec, written, enhanced);
  expectSameVolume(enhanced, load(singleDir));
}

// A multi-frame object is decoded a run of frames at a time (here 3 frames a run: 13 frames
// make five runs, the last short), in every transfer syntax, frames with the slices or against
// them: the same volume as the single-frame files, and the same slices read one at a time
// from the last to the first.
TEST(StackSynthetic, MultiFrameObjectsAreReadARunOfFramesAtATime) {
  SyntheticSeriesSpec spec;
  spec.columns = 20;
  spec.rows = 12;
  spec.sliceCount = 13;
  const auto referenceDir = test::freshTempDir("runs_reference");
  writeSyntheticSeries(referenceDir, spec);
  const LoadedStack reference = load(referenceDir);
  StackOptions options;
  options.frameRunBytes = 3 * 20 * 12 * sizeof(double);
  spec.layout = SyntheticLayout::EnhancedMultiFrame;
  for (SyntheticTransferSyntax syntax :
       {SyntheticTransferSyntax::ExplicitVRLittleEndian,
        SyntheticTransferSyntax::ImplicitVRLittleEndian,
        SyntheticTransferSyntax::ExplicitVRBigEndian, SyntheticTransferSyntax::RLELossless,
        SyntheticTransferSyntax::JPEGLossless, SyntheticTransferSyntax::JPEGLSLossless,
        SyntheticTransferSyntax::JPEG2000Lossless}) {
    for (bool reversed : {false, true}) {
      SCOPED_TRACE(std::string(transferSyntaxUid(syntax)) + (reversed ? " reversed" : ""));
      spec.transferSyntax = syntax;
      spec.reverseFileOrder = reversed;
      const auto dir = test::freshTempDir(std::string("runs") + transferSyntaxUid(syntax) +
                                          (reversed ? "r" : ""));
      const SyntheticSeries written = writeSyntheticSeries(dir, spec);
      ASSERT_EQ(written.files.size(), 1u);
      const LoadedStack loaded = load(dir, options);
      EXPECT_TRUE(loaded.series.multiFrame);
      checkWrittenPixels(spec, written, loaded);
      expectSameVolume(loaded, reference);
      auto source = openDicomSeries(loaded.series, options);
      const auto sliceSamples = static_cast<std::size_t>(loaded.info.sliceSamples());
      std::vector<float> slice(sliceSamples);
      for (int64_t k = loaded.info.dims[2] - 1; k >= 0; --k) {
        source->readSlab(k, 1, slice);
        ASSERT_TRUE(
            std::equal(slice.begin(), slice.end(),
                       loaded.values.begin() + static_cast<std::ptrdiff_t>(k * sliceSamples)))
            << "slice " << k;
      }
    }
  }
}

TEST(StackSynthetic, LocalizerAndSecondaryCaptureAreNotTheDefault) {
  SyntheticSeriesSpec spec;
  spec.withLocalizer = true;
  spec.withSecondaryCapture = true;
  const auto dir = test::freshTempDir("series");
  const SyntheticSeries written = writeSyntheticSeries(dir, spec);
  const DicomScan scan = scanDicom(dir);
  ASSERT_EQ(scan.series.size(), 3u);
  auto kindOf = [&](const std::string& uid) {
    for (const DicomSeries& s : scan.series) {
      if (s.seriesUid == uid) return s.kind;
    }
    ADD_FAILURE() << "series " << uid << " not found";
    return SeriesKind::NoGeometry;
  };
  EXPECT_EQ(kindOf(written.seriesUid), SeriesKind::Volume);
  EXPECT_EQ(kindOf(written.localizerSeriesUid), SeriesKind::Localizer);
  EXPECT_EQ(kindOf(written.secondaryCaptureSeriesUid), SeriesKind::SecondaryCapture);
  EXPECT_EQ(scan.series.at(defaultSeriesIndex(scan, dir.string())).seriesUid, written.seriesUid);
}

TEST(StackSynthetic, CompressedTransferSyntaxesDecodeIdentically) {
  for (SyntheticStorage storage : {SyntheticStorage::Int16, SyntheticStorage::UInt16}) {
    SyntheticSeriesSpec spec;
    spec.storage = storage;
    spec.sliceCount = 4;
    const std::string storageName = storage == SyntheticStorage::Int16 ? "s" : "u";
    const auto referenceDir = test::freshTempDir(storageName + "reference");
    writeSyntheticSeries(referenceDir, spec);
    const LoadedStack reference = load(referenceDir);
    for (SyntheticTransferSyntax syntax :
         {SyntheticTransferSyntax::ImplicitVRLittleEndian,
          SyntheticTransferSyntax::ExplicitVRBigEndian, SyntheticTransferSyntax::RLELossless,
          SyntheticTransferSyntax::JPEGLossless, SyntheticTransferSyntax::JPEGLSLossless,
          SyntheticTransferSyntax::JPEG2000Lossless}) {
      SCOPED_TRACE(storageName + " " + transferSyntaxUid(syntax));
      spec.transferSyntax = syntax;
      const auto dir = test::freshTempDir(storageName + transferSyntaxUid(syntax));
      const SyntheticSeries written = writeSyntheticSeries(dir, spec);
      LoadedStack loaded;
      try {
        loaded = load(dir);
      } catch (const Error& e) {
        ADD_FAILURE() << e.what();  // report and go on with the other syntaxes
        continue;
      }
      ASSERT_EQ(loaded.series.frames.size(), 4u);
      EXPECT_EQ(loaded.series.frames[0].transferSyntaxUid, transferSyntaxUid(syntax));
      checkWrittenPixels(spec, written, loaded);
      expectSameVolume(loaded, reference);
    }
  }
}

TEST(StackSynthetic, ScanSkipsTextAndTruncatedFileAndLoadsTheRest) {
  SyntheticSeriesSpec spec;
  spec.sliceCount = 6;
  const auto dir = test::freshTempDir("series");
  const SyntheticSeries written = writeSyntheticSeries(dir, spec);
  std::ofstream(dir / "notes.txt") << "not a DICOM file\n";
  // The last slice cut inside its pixel data.
  const auto cut = dir / "CT0006.dcm";
  std::filesystem::resize_file(cut, std::filesystem::file_size(cut) - 100);

  const DicomScan scan = scanDicom(dir);
  for (const auto& name : {"notes.txt", "CT0006.dcm"}) {
    const auto it = std::find_if(scan.skipped.begin(), scan.skipped.end(), [&](const SkippedFile& s) {
      return std::filesystem::path(s.path).filename() == name;
    });
    EXPECT_NE(it, scan.skipped.end()) << name << " was not reported as skipped";
    if (it != scan.skipped.end()) {
      EXPECT_FALSE(it->reason.empty()) << name;
    }
  }
  ASSERT_EQ(scan.series.size(), 1u);
  EXPECT_EQ(scan.series[0].frames.size(), 5u);

  const LoadedStack loaded = load(dir);
  EXPECT_EQ(loaded.info.dims[2], 5);
  EXPECT_FALSE(loaded.info.resampled);
  const Mat4 indexFromPatient = loaded.info.patientFromIndex.inverseAffine();
  for (const SyntheticImage& image : written.slices()) {
    if (image.path.filename() == "CT0006.dcm") continue;  // skipped: not in the volume
    const Vec3 index = indexFromPatient.transformPoint(written.pixelPositionMm(image, 3, 5));
    ASSERT_NEAR(index.z, std::round(index.z), kIndexTolerance);
    EXPECT_EQ(loaded.at(3, 5, static_cast<int64_t>(std::round(index.z))),
              static_cast<float>(expectedHu(spec, written, image, 3, 5)));
  }
}

// A file cut inside its header must be skipped, not end the process: run the scan in a child
// process so that a crash there (e.g. a library assertion) fails this test only.
TEST(StackSynthetic, ScanSurvivesFilesCutInsideTheHeader) {
  GTEST_FLAG_SET(death_test_style, "threadsafe");
  SyntheticSeriesSpec spec;
  spec.sliceCount = 3;
  const auto dir = test::freshTempDir("series");
  writeSyntheticSeries(dir, spec);
  for (const uintmax_t bytes : {150u, 300u, 700u, 1000u}) {
    const auto cut = dir / ("cut" + std::to_string(bytes) + ".dcm");
    std::filesystem::copy_file(dir / "CT0003.dcm", cut);
    std::filesystem::resize_file(cut, bytes);
  }
  EXPECT_EXIT(
      {
        const DicomScan scan = scanDicom(dir);
        const bool ok = scan.skipped.size() == 4 && scan.series.size() == 1 &&
                        scan.series[0].frames.size() == 3;
        std::exit(ok ? 0 : 2);
      },
      ::testing::ExitedWithCode(0), "");
}

TEST(SyntheticSeries, SameSeedSameUidsAndValidUids) {
  SyntheticSeriesSpec spec;
  spec.sliceCount = 2;
  const SyntheticSeries a = writeSyntheticSeries(test::freshTempDir("a"), spec);
  const SyntheticSeries b = writeSyntheticSeries(test::freshTempDir("b"), spec);
  spec.seed = 2;
  const SyntheticSeries c = writeSyntheticSeries(test::freshTempDir("c"), spec);
  EXPECT_EQ(a.seriesUid, b.seriesUid);
  EXPECT_EQ(a.studyUid, b.studyUid);
  EXPECT_NE(a.seriesUid, c.seriesUid);
  EXPECT_NE(a.seriesUid, a.studyUid);
  for (const std::string& uid : {a.seriesUid, a.studyUid, c.seriesUid}) {
    EXPECT_LE(uid.size(), 64u) << uid;
    EXPECT_EQ(uid.find_first_not_of("0123456789."), std::string::npos) << uid;
    EXPECT_EQ(uid.rfind("2.25.", 0), 0u) << uid;
  }
}

TEST(SyntheticSeries, RejectsInconsistentSpecs) {
  const auto dir = test::freshTempDir("series");
  SyntheticSeriesSpec unsignedNoIntercept;
  unsignedNoIntercept.storage = SyntheticStorage::UInt16;
  unsignedNoIntercept.rescaleIntercept = 0;
  unsignedNoIntercept.centreMm = {0, 0, -50};  // values well below 0 HU: unrepresentable
  EXPECT_THROW(writeSyntheticSeries(dir, unsignedNoIntercept), Error);

  SyntheticSeriesSpec garbageJpeg;
  garbageJpeg.bitsStored = 12;
  garbageJpeg.highBitsPattern = 0x3;
  garbageJpeg.transferSyntax = SyntheticTransferSyntax::JPEGLossless;
  EXPECT_THROW(writeSyntheticSeries(dir, garbageJpeg), Error);

  SyntheticSeriesSpec badDrop;
  badDrop.dropSliceIndex = 99;
  EXPECT_THROW(writeSyntheticSeries(dir, badDrop), Error);
}

TEST(SyntheticSeries, SecondDerivativeBoundHolds) {
  // Finite differences along a few directions stay under the stated bound.
  const double bound = syntheticHuSecondDerivativeBound(SyntheticPattern::Smooth);
  const double h = 0.01;
  for (const Vec3 u : {Vec3{1, 0, 0}, Vec3{0, 1, 0}, Vec3{0, 0, 1}, normalize(Vec3{1, 2, -3})}) {
    for (double t = -60; t <= 60; t += 1.7) {
      const Vec3 p = t * Vec3{0.3, -0.5, 0.8};
      const double d2 = (syntheticHu(p + h * u) - 2 * syntheticHu(p) + syntheticHu(p - h * u)) / (h * h);
      EXPECT_LE(std::abs(d2), bound + 1e-3);
    }
  }
  EXPECT_EQ(syntheticHuSecondDerivativeBound(SyntheticPattern::Linear), 0.0);
}

}  // namespace
}  // namespace octoray::dicom
