// Real Philips CT (dcm_qa_ct): series discovery and classification, and the geometry and
// values of every axial series checked pixel by pixel against each file's own attributes,
// read here independently of the scanner with gdcm::Reader. dcm2niix, where installed, is a
// second, independent opinion on the same positions (data_philips_dcm2niix.cpp).

#include <gdcmAttribute.h>
#include <gdcmImageReader.h>
#include <gdcmReader.h>
#include <gdcmWriter.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <optional>
#include <random>
#include <set>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "octoray/dicom/dicom_decode.h"
#include "octoray/dicom/dicom_series.h"
#include "octoray/dicom/dicom_volume.h"
#include "octoray/core/error.h"
#include "philips_data.h"
#include "test_paths.h"

namespace octoray {
namespace {

using namespace philips_test;
using dicom::DicomSeries;
using dicom::SeriesKind;

// One slice's attributes, read straight from its file (not through the scanner).
struct SliceAttributes {
  Vec3 positionMm;                        // ImagePositionPatient
  Vec3 rowDirection, columnDirection;     // ImageOrientationPatient[0..2], [3..5]
  double rowSpacingMm = 0, columnSpacingMm = 0;  // PixelSpacing[0], [1]
  double slope = 1, intercept = 0;
  int rows = 0, columns = 0;
  std::optional<double> gantryTiltDegrees;  // GantryDetectorTilt (0018,1120)
};

SliceAttributes readAttributes(const fs::path& path) {
  gdcm::Reader reader;
  reader.SetFileName(path.c_str());
  if (!reader.ReadUpToTag(gdcm::Tag(0x7fe0, 0x0010), std::set<gdcm::Tag>{})) {
    throw Error(path.string(), "test could not read the attributes");
  }
  const gdcm::DataSet& ds = reader.GetFile().GetDataSet();
  auto require = [&](const gdcm::Tag& tag) {
    if (!ds.FindDataElement(tag)) throw Error(path.string(), "test: attribute missing");
  };
  SliceAttributes a;
  require(gdcm::Tag(0x0020, 0x0032));
  gdcm::Attribute<0x0020, 0x0032> ipp;
  ipp.SetFromDataSet(ds);
  a.positionMm = {ipp[0], ipp[1], ipp[2]};
  require(gdcm::Tag(0x0020, 0x0037));
  gdcm::Attribute<0x0020, 0x0037> iop;
  iop.SetFromDataSet(ds);
  a.rowDirection = {iop[0], iop[1], iop[2]};
  a.columnDirection = {iop[3], iop[4], iop[5]};
  require(gdcm::Tag(0x0028, 0x0030));
  gdcm::Attribute<0x0028, 0x0030> spacing;
  spacing.SetFromDataSet(ds);
  a.rowSpacingMm = spacing[0];
  a.columnSpacingMm = spacing[1];
  if (ds.FindDataElement(gdcm::Tag(0x0028, 0x1053))) {
    gdcm::Attribute<0x0028, 0x1053> slope;
    slope.SetFromDataSet(ds);
    a.slope = slope.GetValue();
  }
  if (ds.FindDataElement(gdcm::Tag(0x0028, 0x1052))) {
    gdcm::Attribute<0x0028, 0x1052> intercept;
    intercept.SetFromDataSet(ds);
    a.intercept = intercept.GetValue();
  }
  gdcm::Attribute<0x0028, 0x0010> rows;
  rows.SetFromDataSet(ds);
  gdcm::Attribute<0x0028, 0x0011> columns;
  columns.SetFromDataSet(ds);
  a.rows = rows.GetValue();
  a.columns = columns.GetValue();
  if (ds.FindDataElement(gdcm::Tag(0x0018, 0x1120))) {
    gdcm::Attribute<0x0018, 0x1120> tilt;
    tilt.SetFromDataSet(ds);
    a.gantryTiltDegrees = tilt.GetValue();
  }
  return a;
}

TEST_F(PhilipsData, ScanFindsTheAxialSeriesOfBothSessions) {
  for (const AxialCase& c : kAxialCases) {
    SCOPED_TRACE(c.folder);
    const auto index = seriesIn(scan(), test::philipsDir() / c.folder);
    ASSERT_TRUE(index) << "no series found in " << c.folder;
    const DicomSeries& series = scan().series[*index];
    EXPECT_EQ(series.kind, SeriesKind::Volume) << series.kindReason;
    EXPECT_EQ(series.frames.size(), static_cast<std::size_t>(c.images));
    EXPECT_EQ(series.modality, "CT");
    EXPECT_TRUE(series.hasGeometry);
  }
  const auto index = seriesIn(scan(), test::philipsDir() / "S21570/S2020");
  ASSERT_TRUE(index);
  const DicomSeries& fine = scan().series[*index];
  EXPECT_EQ(fine.rows, 512);
  EXPECT_EQ(fine.columns, 512);
  EXPECT_DOUBLE_EQ(fine.rowSpacingMm, 0.451171875);
  EXPECT_DOUBLE_EQ(fine.columnSpacingMm, 0.451171875);
}

// S1000 is one localiser. S4010 mixes grey survey screenshots and colour summary pages under
// one SeriesInstanceUID, so the scanner may split it or skip the colour pages; whatever it
// does, nothing from these folders may be offered as a volume, and every file is accounted for.
TEST_F(PhilipsData, LocalisersAndSummariesAreNotVolumes) {
  for (const char* session : {"S21570", "S21610"}) {
    for (const char* folder : {"S1000", "S4010"}) {
      const fs::path dir = test::philipsDir() / session / folder;
      SCOPED_TRACE(dir.string());
      const auto indices = seriesTouching(scan(), dir);
      ASSERT_FALSE(indices.empty()) << "the images of " << dir.string() << " belong to no series";
      std::size_t framesHere = 0;
      for (const std::size_t index : indices) {
        const DicomSeries& series = scan().series[index];
        framesHere += series.frames.size();
        EXPECT_NE(series.kind, SeriesKind::Volume) << series.kindReason;
        EXPECT_FALSE(series.kindReason.empty());
        if (std::string(folder) == "S1000") {
          EXPECT_EQ(series.kind, SeriesKind::Localizer) << series.kindReason;
        } else {
          EXPECT_TRUE(series.kind == SeriesKind::SecondaryCapture ||
                      series.kind == SeriesKind::Derived)
              << dicom::toString(series.kind) << ": " << series.kindReason;
        }
      }
      const auto skippedHere = std::count_if(
          scan().skipped.begin(), scan().skipped.end(), [&](const dicom::SkippedFile& f) {
            return isUnder(f.path, dir) && fs::path(f.path).filename() != "DIRFILE";
          });
      EXPECT_EQ(framesHere + static_cast<std::size_t>(skippedHere), imageFiles(dir).size())
          << "files of " << dir.string() << " neither in a series nor skipped";
    }
  }
}

TEST_F(PhilipsData, DirectoryFilesAreSkippedWithAReason) {
  std::vector<fs::path> dirFiles;
  for (const auto& entry : fs::recursive_directory_iterator(test::philipsDir())) {
    if (entry.path().filename() == "DIRFILE") dirFiles.push_back(entry.path());
  }
  ASSERT_FALSE(dirFiles.empty());
  for (const fs::path& dirFile : dirFiles) {
    const auto it = std::find_if(scan().skipped.begin(), scan().skipped.end(),
                                 [&](const dicom::SkippedFile& s) {
                                   return fs::weakly_canonical(s.path) ==
                                          fs::weakly_canonical(dirFile);
                                 });
    ASSERT_NE(it, scan().skipped.end()) << dirFile.string() << " is not reported as skipped";
    EXPECT_FALSE(it->reason.empty()) << dirFile.string();
  }
}

// Files a DICOMDIR lists (following Philips' nested DIRFILEs) that are absent, as paths
// relative to `root`; read with plain gdcm::Reader, independently of the scanner.
void collectMissing(const fs::path& dirFile, const fs::path& root, std::set<fs::path>& seen,
                    std::vector<std::string>& missing) {
  if (!seen.insert(fs::weakly_canonical(dirFile)).second) return;
  gdcm::Reader reader;
  reader.SetFileName(dirFile.c_str());
  ASSERT_TRUE(reader.Read()) << dirFile.string();
  const gdcm::DataSet& ds = reader.GetFile().GetDataSet();
  const gdcm::Tag recordsTag(0x0004, 0x1220);
  if (!ds.FindDataElement(recordsTag)) return;
  auto records = ds.GetDataElement(recordsTag).GetValueAsSQ();
  if (!records) return;
  for (gdcm::SequenceOfItems::SizeType n = 1; n <= records->GetNumberOfItems(); ++n) {
    const gdcm::DataSet& record = records->GetItem(n).GetNestedDataSet();
    const gdcm::Tag fileIdTag(0x0004, 0x1500);
    if (!record.FindDataElement(fileIdTag)) continue;
    const gdcm::ByteValue* bytes = record.GetDataElement(fileIdTag).GetByteValue();
    if (!bytes) continue;
    std::string id(bytes->GetPointer(), bytes->GetLength());
    while (!id.empty() && (id.back() == ' ' || id.back() == '\0')) id.pop_back();
    std::replace(id.begin(), id.end(), '\\', '/');
    const fs::path file = root / id;
    if (!fs::exists(file)) {
      missing.push_back(id);
    } else if (file.filename() == "DIRFILE") {
      collectMissing(file, root, seen, missing);
    }
  }
}

TEST_F(PhilipsData, DicomdirFilesThatAreMissingAreReportedByName) {
  std::vector<std::string> missing;
  std::set<fs::path> seen;
  collectMissing(test::philipsDir() / "DICOMDIR", test::philipsDir(), seen, missing);
  ASSERT_FALSE(missing.empty()) << "the data set is expected to lack series S2030's files";
  for (const std::string& id : missing) {
    std::string backslashed = id;
    std::replace(backslashed.begin(), backslashed.end(), '/', '\\');
    const bool named = std::any_of(scan().warnings.begin(), scan().warnings.end(),
                                   [&](const std::string& w) {
                                     return w.find(id) != std::string::npos ||
                                            w.find(backslashed) != std::string::npos;
                                   });
    EXPECT_TRUE(named) << "no warning names the missing file " << id;
  }
  for (const std::string& w : scan().warnings) std::cout << "[scan warning] " << w << "\n";
}

// Rewrites the first record of `dicomdir` that names a file so that it names `fileId`
// (components separated by '\\').
void redirectFirstRecord(const fs::path& dicomdir, const std::string& fileId) {
  gdcm::Reader reader;
  reader.SetFileName(dicomdir.c_str());
  ASSERT_TRUE(reader.Read());
  gdcm::DataSet& ds = reader.GetFile().GetDataSet();
  const gdcm::Tag recordsTag(0x0004, 0x1220), fileIdTag(0x0004, 0x1500);
  gdcm::DataElement records = ds.GetDataElement(recordsTag);
  gdcm::SmartPointer<gdcm::SequenceOfItems> items = records.GetValueAsSQ();
  ASSERT_TRUE(items);
  bool done = false;
  for (gdcm::SequenceOfItems::SizeType n = 1; n <= items->GetNumberOfItems() && !done; ++n) {
    gdcm::DataSet& record = items->GetItem(n).GetNestedDataSet();
    if (!record.FindDataElement(fileIdTag)) continue;
    gdcm::DataElement id(fileIdTag);
    id.SetVR(gdcm::VR::CS);
    std::string value = fileId;
    if (value.size() % 2) value += ' ';
    id.SetByteValue(value.data(), static_cast<uint32_t>(value.size()));
    record.Replace(id);
    done = true;
  }
  ASSERT_TRUE(done);
  // Lengths are recomputed on writing: the edited record no longer has its old length.
  for (gdcm::SequenceOfItems::SizeType n = 1; n <= items->GetNumberOfItems(); ++n) {
    items->GetItem(n).SetVLToUndefined();
  }
  items->SetLengthToUndefined();
  records.SetValue(*items);
  records.SetVLToUndefined();
  ds.Replace(records);
  gdcm::Writer writer;
  writer.SetFileName(dicomdir.c_str());
  writer.SetFile(reader.GetFile());
  ASSERT_TRUE(writer.Write());
}

TEST(DicomdirConfinement, RecordsLeadingOutOfTheFolderAreIgnoredWithAWarning) {
  OCTORAY_REQUIRE_PATH(test::philipsDir());
  const fs::path dir = test::freshTempDir("dicomdir_escape");
  fs::copy(test::philipsDir(), dir / "media", fs::copy_options::recursive);
  // A real CT slice outside the media folder: what a crafted record would make us read.
  fs::copy_file(test::philipsDir() / "S21570/S2020/I10", dir / "secret.dcm");
  fs::create_directory_symlink(dir, dir / "media/link");
  for (const std::string& id : {std::string("..\\secret.dcm"), std::string("link\\secret.dcm")}) {
    SCOPED_TRACE(id);
    fs::copy_file(test::philipsDir() / "DICOMDIR", dir / "media/DICOMDIR", fs::copy_options::overwrite_existing);
    redirectFirstRecord(dir / "media/DICOMDIR", id);
    const DicomScan scan = dicom::scanDicom(dir / "media/DICOMDIR");
    for (const auto& series : scan.series) {
      for (const auto& frame : series.frames) {
        EXPECT_EQ(fs::weakly_canonical(frame.path).string().find("secret"), std::string::npos) << frame.path;
      }
    }
    const bool warned = std::any_of(scan.warnings.begin(), scan.warnings.end(), [](const std::string& w) {
      return w.find("outside the DICOMDIR's folder") != std::string::npos && w.find("secret.dcm") != std::string::npos;
    });
    EXPECT_TRUE(warned) << fmt::format("{}", fmt::join(scan.warnings, "\n"));
  }
}

TEST_F(PhilipsData, DefaultSeriesIsTheFineAxialSeries) {
  const std::size_t chosen = dicom::defaultSeriesIndex(scan(), test::philipsDir().string());
  ASSERT_LT(chosen, scan().series.size());
  EXPECT_EQ(scan().series[chosen].frames.size(), 140u);
  EXPECT_TRUE(isUnder(scan().series[chosen].frames.front().path,
                      test::philipsDir() / "S21570/S2020"));
}

// decodeDicomFile against GDCM's own decoder, masked here: the stored values the geometry
// checks below build on.
TEST_F(PhilipsData, DecodedStoredValuesMatchGdcmImageReader) {
  for (const AxialCase& c : kAxialCases) {
    const auto files = imageFiles(test::philipsDir() / c.folder);
    ASSERT_FALSE(files.empty());
    for (const fs::path& file : {files.front(), files[files.size() / 2], files.back()}) {
      SCOPED_TRACE(file.string());
      gdcm::ImageReader reader;
      reader.SetFileName(file.c_str());
      ASSERT_TRUE(reader.Read());
      const gdcm::Image& image = reader.GetImage();
      const gdcm::PixelFormat& pf = image.GetPixelFormat();
      ASSERT_EQ(pf.GetBitsAllocated(), 16);
      ASSERT_EQ(pf.GetSamplesPerPixel(), 1);
      std::vector<char> buffer(image.GetBufferLength());
      ASSERT_TRUE(image.GetBuffer(buffer.data()));
      const dicom::DecodedImage decoded = dicom::decodeDicomFile(file.string());
      ASSERT_EQ(decoded.stored.size(), buffer.size() / 2);
      const int shift = pf.GetHighBit() + 1 - pf.GetBitsStored();
      const uint32_t mask = (1u << pf.GetBitsStored()) - 1;
      for (std::size_t i = 0; i < decoded.stored.size(); ++i) {
        uint16_t raw;
        std::memcpy(&raw, buffer.data() + 2 * i, 2);
        int64_t expected = (raw >> shift) & mask;
        if (pf.GetPixelRepresentation() == 1 && (expected >> (pf.GetBitsStored() - 1))) {
          expected -= int64_t{1} << pf.GetBitsStored();
        }
        ASSERT_EQ(decoded.stored[i], static_cast<double>(expected)) << "sample " << i;
      }
    }
  }
}

// Every original slice's pixels, placed by the slice's own attributes, must land on the
// volume's grid (i = column, j = row) and hold the pixel's HU there. Where slices were
// resampled, a pixel between output slices is a linear blend of at most the slices around
// it, so it must lie within its neighbours' values (tolerance derived below).
struct SliceCheck {
  int slicesChecked = 0;
  int pixelsChecked = 0;
  int exactSlices = 0;
  double maxIndexErrorInPlane = 0;
  double maxValueError = 0;
};

SliceCheck checkSlicesAgainstAttributes(const LoadedVolume& volume,
                                        const std::vector<fs::path>& files,
                                        int pixelsPerSlice) {
  SliceCheck result;
  std::mt19937 rng(20261122);
  // Decoded HU of every file, kept for neighbour look-ups in the resampled case.
  struct Slice {
    fs::path path;
    SliceAttributes attributes;
    std::vector<double> hu;
    double k = 0;
  };
  std::vector<Slice> slices;
  for (const fs::path& file : files) {
    Slice s{file, readAttributes(file), {}, 0};
    const auto decoded = dicom::decodeDicomFile(file.string());
    EXPECT_EQ(decoded.format.rows, s.attributes.rows);
    EXPECT_EQ(decoded.format.columns, s.attributes.columns);
    s.hu.resize(decoded.stored.size());
    for (std::size_t i = 0; i < s.hu.size(); ++i) {
      s.hu[i] = s.attributes.slope * decoded.stored[i] + s.attributes.intercept;
    }
    s.k = volume.indexFromPatient.transformPoint(s.attributes.positionMm).z;
    slices.push_back(std::move(s));
  }
  std::sort(slices.begin(), slices.end(), [](const Slice& a, const Slice& b) { return a.k < b.k; });

  std::set<int64_t> slicesHit;
  for (std::size_t n = 0; n < slices.size(); ++n) {
    const Slice& s = slices[n];
    const SliceAttributes& a = s.attributes;
    SCOPED_TRACE(s.path.string());
    const bool onGrid = std::abs(s.k - std::round(s.k)) <= 1e-4;
    if (!volume.info.resampled) {
      EXPECT_TRUE(onGrid) << "slice maps to k = " << s.k << ", between grid slices";
      EXPECT_TRUE(slicesHit.insert(std::llround(s.k)).second) << "two files map to k = " << s.k;
    }
    if (onGrid) ++result.exactSlices;
    std::uniform_int_distribution<int> column(0, a.columns - 1), row(0, a.rows - 1);
    for (int p = 0; p < pixelsPerSlice; ++p) {
      const int c = column(rng), r = row(rng);
      // PS3.3 C.7.6.2.1.1: column c along IOP[0..2] by PixelSpacing[1], row r along
      // IOP[3..5] by PixelSpacing[0].
      const Vec3 patient = a.positionMm + (c * a.columnSpacingMm) * a.rowDirection +
                           (r * a.rowSpacingMm) * a.columnDirection;
      const Vec3 index = volume.indexFromPatient.transformPoint(patient);
      const double inPlaneError = std::max(std::abs(index.x - c), std::abs(index.y - r));
      result.maxIndexErrorInPlane = std::max(result.maxIndexErrorInPlane, inPlaneError);
      EXPECT_LE(inPlaneError, 1e-4) << "pixel (" << c << "," << r << ") maps to (" << index.x
                                    << "," << index.y << "," << index.z << ")";
      if (inPlaneError > 1e-4 || !volume.inside(index)) {
        ADD_FAILURE() << "pixel (" << c << "," << r << ") maps outside the grid or off it";
        return result;
      }
      const std::size_t pixel = static_cast<std::size_t>(r) * a.columns + c;
      const double expected = s.hu[pixel];
      if (onGrid) {
        const float got = volume.at(c, r, std::llround(index.z));
        result.maxValueError = std::max(result.maxValueError, std::abs(got - expected));
        EXPECT_EQ(got, expected) << "pixel (" << c << "," << r << ") at k = " << index.z;
      } else {
        // Off the output grid (resampled stacks only). The output slices around index.z are
        // linear blends of the original slices around them, rounded to whole HU; linear
        // interpolation between them stays in the range of this slice and its two
        // neighbours, widened by the rounding: tolerance = max |neighbour - this| + 0.5.
        double tolerance = 0.5;
        if (n > 0) tolerance = std::max(tolerance, std::abs(slices[n - 1].hu[pixel] - expected) + 0.5);
        if (n + 1 < slices.size()) {
          tolerance = std::max(tolerance, std::abs(slices[n + 1].hu[pixel] - expected) + 0.5);
        }
        const double got = volume.sample({static_cast<double>(c), static_cast<double>(r), index.z});
        result.maxValueError = std::max(result.maxValueError, std::abs(got - expected));
        EXPECT_LE(std::abs(got - expected), tolerance)
            << "pixel (" << c << "," << r << ") at k = " << index.z;
      }
      ++result.pixelsChecked;
    }
    ++result.slicesChecked;
  }
  return result;
}

TEST_P(PhilipsAxial, EveryOriginalSliceLandsOnTheGridWithItsHounsfieldUnits) {
  const AxialCase& c = GetParam();
  const LoadedVolume& volume = PhilipsData::volume(c.folder);
  const auto files = imageFiles(test::philipsDir() / c.folder);
  ASSERT_EQ(files.size(), static_cast<std::size_t>(c.images));
  // Every series here is evenly spaced: nothing may be resampled, tilted or not.
  EXPECT_FALSE(volume.info.resampled);
  EXPECT_EQ(volume.info.dims[2], c.images);
  EXPECT_EQ(volume.info.unit, "HU");
  const SliceCheck check = checkSlicesAgainstAttributes(volume, files, 200);
  EXPECT_EQ(check.slicesChecked, c.images);
  EXPECT_EQ(check.exactSlices, c.images);
  std::cout << fmt::format("[{}] {} slices x 200 pixels: max in-plane index error {:.2e}, max "
                           "value error {} HU, tilt {:.3f} deg\n",
                           c.folder, check.slicesChecked, check.maxIndexErrorInPlane,
                           check.maxValueError, volume.info.tiltDegrees);
}

// The display window the volume keeps is the files' own: every file of these series names one
// WindowCenter / WindowWidth, written twice (pydicom reads [40, 40] / [80, 80]); read here with
// gdcm::Attribute, file by file, and kept once.
TEST_P(PhilipsAxial, KeepsTheWindowEveryFileNames) {
  const AxialCase& c = GetParam();
  const LoadedVolume& volume = PhilipsData::volume(c.folder);
  std::set<std::pair<double, double>> named;
  for (const fs::path& file : imageFiles(test::philipsDir() / c.folder)) {
    gdcm::Reader reader;
    reader.SetFileName(file.c_str());
    ASSERT_TRUE(reader.ReadUpToTag(gdcm::Tag(0x7fe0, 0x0010), std::set<gdcm::Tag>{})) << file;
    const gdcm::DataSet& ds = reader.GetFile().GetDataSet();
    gdcm::Attribute<0x0028, 0x1050> center;
    center.SetFromDataSet(ds);
    gdcm::Attribute<0x0028, 0x1051> width;
    width.SetFromDataSet(ds);
    ASSERT_EQ(center.GetNumberOfValues(), 2u) << file;
    ASSERT_EQ(width.GetNumberOfValues(), 2u) << file;
    for (unsigned i = 0; i < 2; ++i) named.insert({center[i], width[i]});
  }
  ASSERT_EQ(named.size(), 1u);
  ASSERT_EQ(volume.info.windows.size(), 1u);
  EXPECT_EQ(volume.info.windows[0].center, named.begin()->first);
  EXPECT_EQ(volume.info.windows[0].width, named.begin()->second);
  EXPECT_EQ(volume.info.windows[0].center, 40);
  EXPECT_EQ(volume.info.windows[0].width, 80);
  EXPECT_EQ(volume.info.windows[0].explanation, "");
}

// The sign of tiltDegrees: resolveStack signs the angle between the slice step and the
// normal by the step's component along the column direction (IOP[3..5]). On these Philips
// files that equals GantryDetectorTilt (0018,1120): −18.5 for S21610/S2010 and +16.5 for
// S21610/S3010, where the slice step is +z and the column direction has z = −0.317 / +0.284.
TEST_P(PhilipsAxial, TiltMatchesGantryDetectorTilt) {
  const AxialCase& c = GetParam();
  const LoadedVolume& volume = PhilipsData::volume(c.folder);
  const auto files = imageFiles(test::philipsDir() / c.folder);
  const SliceAttributes first = readAttributes(files.front());
  ASSERT_TRUE(first.gantryTiltDegrees);
  if (!c.tilted) {
    EXPECT_NEAR(volume.info.tiltDegrees, 0.0, 1e-3);
    EXPECT_NEAR(*first.gantryTiltDegrees, 0.0, 1e-9);
    return;
  }
  EXPECT_GT(std::abs(volume.info.tiltDegrees), 10.0);
  EXPECT_NEAR(volume.info.tiltDegrees, *first.gantryTiltDegrees, 0.05);
  if (std::string(c.folder) == "S21610/S2010") {
    EXPECT_NEAR(std::abs(volume.info.tiltDegrees), 18.5, 0.05);
  }
  // A shear, not a rotation: the slice step leaves the normal but i and j stay in-plane.
  const Vec3 normal = normalize(cross(first.rowDirection, first.columnDirection));
  EXPECT_NEAR(dot(volume.info.patientFromIndex.column(0), normal), 0.0, 1e-9);
  EXPECT_NEAR(dot(volume.info.patientFromIndex.column(1), normal), 0.0, 1e-9);
}

INSTANTIATE_TEST_SUITE_P(Philips, PhilipsAxial, ::testing::ValuesIn(kAxialCases),
                         [](const auto& testInfo) {
                           std::string name = testInfo.param.folder;
                           std::replace(name.begin(), name.end(), '/', '_');
                           return name;
                         });

// A stack with one slice taken out has one double gap: it must be resampled to the smallest
// gap, every remaining slice must still hold its exact values (they sit on the new grid),
// and the slice put back in the gap is the mean of its neighbours, to rounding (0.5 HU).
TEST_F(PhilipsData, StackWithAMissingSliceIsResampledLinearly) {
  const fs::path source = test::philipsDir() / "S21570/S2010";
  auto files = imageFiles(source);
  std::sort(files.begin(), files.end(), [](const fs::path& a, const fs::path& b) {
    return readAttributes(a).positionMm.z < readAttributes(b).positionMm.z;
  });
  const fs::path removed = files[files.size() / 2];
  const fs::path dir = test::freshTempDir("gap");
  std::vector<fs::path> kept;
  for (const fs::path& f : files) {
    if (f == removed) continue;
    fs::create_symlink(f, dir / f.filename());
    kept.push_back(f);
  }
  const DicomScan gapScan = dicom::scanDicom(dir);
  const std::size_t index = dicom::defaultSeriesIndex(gapScan, dir.string());
  auto volumeSource = dicom::openDicomSeries(gapScan.series[index]);
  const LoadedVolume volume = loadVolume(*volumeSource);
  EXPECT_TRUE(volume.info.resampled);
  EXPECT_EQ(volume.info.dims[2], static_cast<int64_t>(files.size()));
  EXPECT_NEAR(volume.info.spacingMm().z, 5.0, 1e-6);
  const SliceCheck check = checkSlicesAgainstAttributes(volume, kept, 200);
  EXPECT_EQ(check.exactSlices, static_cast<int>(kept.size()));

  // The interpolated slice, against its neighbours and (for information) the true slice.
  const auto below = dicom::decodeDicomFile(files[files.size() / 2 - 1].string());
  const auto above = dicom::decodeDicomFile(files[files.size() / 2 + 1].string());
  const auto truth = dicom::decodeDicomFile(removed.string());
  const SliceAttributes a = readAttributes(removed);
  const Vec3 k = volume.indexFromPatient.transformPoint(a.positionMm);
  ASSERT_NEAR(k.z, std::round(k.z), 1e-4);
  double sumSquares = 0;
  for (int r = 0; r < a.rows; ++r) {
    for (int c = 0; c < a.columns; ++c) {
      const std::size_t p = static_cast<std::size_t>(r) * a.columns + c;
      const double mean = a.slope * 0.5 * (below.stored[p] + above.stored[p]) + a.intercept;
      const double got = volume.at(c, r, std::llround(k.z));
      ASSERT_LE(std::abs(got - mean), 0.5) << "(" << c << "," << r << ")";
      const double d = got - (a.slope * truth.stored[p] + a.intercept);
      sumSquares += d * d;
    }
  }
  std::cout << fmt::format("interpolated slice vs the removed original: RMS {:.1f} HU\n",
                           std::sqrt(sumSquares / (a.rows * a.columns)));
}

}  // namespace
}  // namespace octoray
