// NIfTI export and import (checked against VTK's own NIfTI reader as an independent oracle),
// TIFF stacks written with OpenCV and by hand, and openVolume's dispatch, including garbage under
// every supported extension.

#include <gtest/gtest.h>

#include <vtkMatrix4x4.h>
#include <vtkNIFTIImageHeader.h>
#include <vtkNIFTIImageReader.h>
#include <vtkNew.h>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include <algorithm>
#include <filesystem>
#include <limits>
#include <map>
#include <random>
#include <utility>

#include <fmt/format.h>

#include "format_test_helpers.h"
#include "octoray/core/error.h"
#include "octoray/dicom/formats.h"
#include "octoray/dicom/nifti_export.h"
#include "test_paths.h"

namespace octoray {
namespace {

namespace fs = std::filesystem;
using namespace formats_test;
using VoxelFunction = std::function<float(int64_t, int64_t, int64_t)>;

// An in-memory source from a function; optionally fails when slice `failAtSlice` is read.
class FunctionSource final : public VolumeSource {
 public:
  FunctionSource(std::array<int64_t, 3> dims, Mat4 patientFromIndex, bool integerValues,
                 VoxelFunction value, int64_t failAtSlice = -1)
      : value_(std::move(value)), failAtSlice_(failAtSlice) {
    info_.dims = dims;
    info_.patientFromIndex = patientFromIndex;
    info_.integerValues = integerValues;
    info_.format = "memory";
    info_.description = "function";
  }
  const VolumeInfo& info() const override { return info_; }
  void readSlab(int64_t firstSlice, int64_t sliceCount, std::span<float> out) override {
    checkSlabRequest(info_, firstSlice, sliceCount, out.size());
    if (failAtSlice_ >= firstSlice && failAtSlice_ < firstSlice + sliceCount) {
      throw Error("memory", "simulated read failure");
    }
    std::size_t n = 0;
    for (int64_t k = firstSlice; k < firstSlice + sliceCount; ++k)
      for (int64_t j = 0; j < info_.dims[1]; ++j)
        for (int64_t i = 0; i < info_.dims[0]; ++i) out[n++] = value_(i, j, k);
  }

 private:
  VolumeInfo info_;
  VoxelFunction value_;
  int64_t failAtSlice_;
};

float integerRamp(int64_t i, int64_t j, int64_t k) {
  return static_cast<float>(i - 3 * j + 100 * k - 500);
}
float fractionalRamp(int64_t i, int64_t j, int64_t k) {
  return static_cast<float>(i) * 0.25f - static_cast<float>(k) * 1.5f +
         static_cast<float>(j) * 1e-3f;
}

// LPS: a rotation about the patient z axis (0.6/0.8) with anisotropic spacing.
Mat4 obliqueAffine() {
  return Mat4::fromColumns({0.3, 0.4, 0}, {-0.6, 0.45, 0}, {0, 0, 2.5}, {-100.5, 20.25, 7});
}
// A gantry tilt: the slice step leans along y.
Mat4 shearedAffine() {
  return Mat4::fromColumns({0.5, 0, 0}, {0, 0.5, 0}, {0, 0.2, 1.25}, {10, -30.5, 60});
}
Mat4 rasFromLps() {
  Mat4 m;
  m.m[0][0] = -1;
  m.m[1][1] = -1;
  return m;
}

vtkNew<vtkNIFTIImageReader> vtkHeaderOf(const fs::path& file) {
  vtkNew<vtkNIFTIImageReader> reader;
  reader->SetFileName(file.string().c_str());
  reader->UpdateInformation();
  return reader;
}

// Overwrites bytes of a plain .nii header (to make qform-only or scaled files).
template <typename T>
void patchHeader(const fs::path& file, std::streamoff offset, T value) {
  std::fstream f(file, std::ios::binary | std::ios::in | std::ios::out);
  f.seekp(offset);
  f.write(reinterpret_cast<const char*>(&value), sizeof(T));
  ASSERT_TRUE(f.good());
}

// ---- NIfTI ----------------------------------------------------------------------------------

TEST(NiftiExport, IntegerObliqueVolumeRoundTripsAsInt16) {
  const auto dir = test::freshTempDir("nifti_int16");
  const std::array<int64_t, 3> dims{13, 11, 19};
  for (const char* name : {"v.nii", "v.nii.gz"}) {
    FunctionSource source(dims, obliqueAffine(), true, integerRamp);
    int64_t lastDone = 0, lastTotal = 0;
    NiftiExportOptions options;
    options.progress = [&](int64_t done, int64_t total) {
      EXPECT_GT(done, lastDone);
      lastDone = done;
      lastTotal = total;
    };
    exportNifti(source, (dir / name).string(), options);
    EXPECT_EQ(lastDone, lastTotal);

    // VTK's reader as an independent oracle for the header.
    auto vtk = vtkHeaderOf(dir / name);
    vtkNIFTIImageHeader* header = vtk->GetNIFTIHeader();
    EXPECT_EQ(header->GetDataType(), 4);  // int16
    EXPECT_EQ(header->GetSFormCode(), 1);
    EXPECT_EQ(header->GetQFormCode(), 1);
    EXPECT_EQ(header->GetXYZTUnits(), 2);  // mm
    const Mat4 ras = rasFromLps() * obliqueAffine();
    vtkMatrix4x4* q = vtk->GetQFormMatrix();  // rotation + offset; VTK scales by pixdim
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) {
        EXPECT_NEAR(q->GetElement(r, c) * header->GetPixDim(c + 1), ras.m[r][c], 1e-6);
      }
      EXPECT_NEAR(q->GetElement(r, 3), ras.m[r][3], 1e-5);
    }

    auto back = openNifti((dir / name).string());
    EXPECT_EQ(back->info().dims, dims);
    EXPECT_EQ(back->info().format, "nifti");
    EXPECT_TRUE(back->info().integerValues);
    expectAffineNear(back->info().patientFromIndex, obliqueAffine(), 1e-6);
    expectValues(*back, 4, integerRamp);
  }
  // Only the finished files are left: no temporary files.
  EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator()), 2);
}

TEST(NiftiExport, ShearedFloatVolumeKeepsFullAffineInSform) {
  const auto dir = test::freshTempDir("nifti_sheared");
  const std::array<int64_t, 3> dims{7, 9, 17};
  for (const char* name : {"s.nii", "s.nii.gz"}) {
    FunctionSource source(dims, shearedAffine(), false, fractionalRamp);
    exportNifti(source, (dir / name).string());
    auto vtk = vtkHeaderOf(dir / name);
    EXPECT_EQ(vtk->GetNIFTIHeader()->GetDataType(), 16);  // float32
    EXPECT_EQ(vtk->GetNIFTIHeader()->GetQFormCode(), 0);  // a shear has no quaternion form
    double row[4];
    vtk->GetNIFTIHeader()->GetSRowY(row);
    EXPECT_NEAR(row[2], -0.2, 1e-7);  // RAS y = -LPS y
    EXPECT_NEAR(row[3], 30.5, 1e-7);

    auto back = openNifti((dir / name).string());
    EXPECT_FALSE(back->info().integerValues);
    expectAffineNear(back->info().patientFromIndex, shearedAffine(), 1e-6);
    expectValues(*back, 5, fractionalRamp);
  }
}

TEST(NiftiExport, IntegersOutsideInt16AreWrittenAsFloat32) {
  const auto dir = test::freshTempDir("nifti_wide");
  auto wide = [](int64_t i, int64_t j, int64_t k) {
    return static_cast<float>(i * 1000 + j * 10000 + k - 20000);  // reaches 40000+
  };
  FunctionSource source({8, 7, 3}, Mat4::identity(), true, wide);
  exportNifti(source, (dir / "w.nii").string());
  EXPECT_EQ(vtkHeaderOf(dir / "w.nii")->GetNIFTIHeader()->GetDataType(), 16);
  expectValues(*openNifti((dir / "w.nii").string()), 3, wide);
}

TEST(NiftiExport, FailedExportLeavesNoFile) {
  const auto dir = test::freshTempDir("nifti_fail");
  for (bool integer : {true, false}) {
    FunctionSource source({6, 6, 30}, Mat4::identity(), integer, integerRamp, 20);
    EXPECT_THROW(exportNifti(source, (dir / "f.nii.gz").string()), Error);
    EXPECT_TRUE(fs::is_empty(dir)) << "a partial or temporary file was left behind";
  }
  FunctionSource huge({40000, 1, 1}, Mat4::identity(), true, integerRamp);
  EXPECT_THROW(exportNifti(huge, (dir / "h.nii").string()), Error);
  FunctionSource ok({2, 2, 2}, Mat4::identity(), true, integerRamp);
  EXPECT_THROW(exportNifti(ok, (dir / "no_such_folder" / "x.nii").string()), Error);
}

TEST(NiftiFormat, QformOnlyFileWithFlippedSlicesAndScaling) {
  const auto dir = test::freshTempDir("nifti_qform");
  // LPS with the slice axis reversed: left-handed in RAS, so the qform needs qfac = -1.
  const Mat4 flipped = Mat4::fromColumns({0.3, 0.4, 0}, {-0.6, 0.45, 0}, {0, 0, -2.5}, {1, 2, 3});
  FunctionSource source({5, 6, 7}, flipped, true, integerRamp);
  const auto file = dir / "q.nii";
  exportNifti(source, file.string());
  patchHeader<int16_t>(file, 254, 0);  // sform_code = 0: only the qform is left
  auto back = openNifti(file.string());
  expectAffineNear(back->info().patientFromIndex, flipped, 1e-6);

  patchHeader<float>(file, 112, 2.0f);   // scl_slope
  patchHeader<float>(file, 116, -1.0f);  // scl_inter
  auto scaled = openNifti(file.string());
  EXPECT_TRUE(scaled->info().integerValues);
  expectValues(*scaled, 7,
               [](int64_t i, int64_t j, int64_t k) { return 2.0f * integerRamp(i, j, k) - 1.0f; });
  patchHeader<float>(file, 112, 0.5f);
  EXPECT_FALSE(openNifti(file.string())->info().integerValues);

  // A field that is not a number counts as 0, as nifti1_io reads it, with a warning: the
  // intercept alone leaves the slope in force, a NaN slope leaves the samples unscaled.
  const auto warned = [](const VolumeSource& v, const std::string& what) {
    return std::any_of(v.info().warnings.begin(), v.info().warnings.end(),
                       [&](const std::string& w) { return w.find(what) != std::string::npos; });
  };
  patchHeader<float>(file, 112, 2.0f);
  patchHeader<float>(file, 116, std::numeric_limits<float>::quiet_NaN());
  auto noIntercept = openNifti(file.string());
  EXPECT_TRUE(warned(*noIntercept, "scl_inter is nan: read as 0"));
  expectValues(*noIntercept, 7,
               [](int64_t i, int64_t j, int64_t k) { return 2.0f * integerRamp(i, j, k); });
  patchHeader<float>(file, 112, std::numeric_limits<float>::infinity());
  auto noSlope = openNifti(file.string());
  EXPECT_TRUE(warned(*noSlope, "scl_slope is inf: the samples are read unscaled"));
  expectValues(*noSlope, 7, [](int64_t i, int64_t j, int64_t k) { return integerRamp(i, j, k); });
}

TEST(NiftiFormat, TruncatedAndJunkFilesThrow) {
  const auto dir = test::freshTempDir("nifti_bad");
  FunctionSource source({10, 10, 10}, Mat4::identity(), false, fractionalRamp);
  exportNifti(source, (dir / "full.nii").string());
  exportNifti(source, (dir / "full.nii.gz").string());
  fs::copy_file(dir / "full.nii", dir / "cut.nii");
  fs::resize_file(dir / "cut.nii", 352 + 1000);
  expectErrorMentioning([&] { openNifti((dir / "cut.nii").string()); }, "cut.nii");
  expectErrorMentioning([&] { openNifti((dir / "cut.nii").string()); },
                        "expected 4000 bytes of data after a 352-byte header, file has 1352");
  fs::copy_file(dir / "full.nii.gz", dir / "cut.nii.gz");
  fs::resize_file(dir / "cut.nii.gz", fs::file_size(dir / "full.nii.gz") / 2);
  expectErrorMentioning(
      [&] {
        auto cut = openNifti((dir / "cut.nii.gz").string());
        std::vector<float> all(1000);
        cut->readSlab(0, 10, all);
      },
      "cut.nii.gz");
  writeFile(dir / "junk.nii", std::string(400, 'j'));
  EXPECT_THROW(openNifti((dir / "junk.nii").string()), Error);
  writeFile(dir / "empty.nii.gz", "");
  EXPECT_THROW(openNifti((dir / "empty.nii.gz").string()), Error);
  // vox_offset inside the header: header bytes would be read as samples.
  fs::copy_file(dir / "full.nii", dir / "offset.nii");
  patchHeader<float>(dir / "offset.nii", 108, 100.0f);
  expectErrorMentioning([&] { openNifti((dir / "offset.nii").string()); },
                        "vox_offset 100 points into the header");
  patchHeader<float>(dir / "offset.nii", 108, std::numeric_limits<float>::quiet_NaN());
  expectErrorMentioning([&] { openNifti((dir / "offset.nii").string()); },
                        "invalid vox_offset (negative or not a number)");
  patchHeader<int16_t>(dir / "full.nii", 70, 1792);  // complex128: not a scalar type
  EXPECT_THROW(openNifti((dir / "full.nii").string()), Error);
}

// ---- TIFF -----------------------------------------------------------------------------------

cv::Mat page16(int width, int height, int64_t k) {
  cv::Mat page(height, width, CV_16U);
  for (int j = 0; j < height; ++j)
    for (int i = 0; i < width; ++i) page.at<uint16_t>(j, i) = typedValue<uint16_t>(i, j, k);
  return page;
}

TEST(TiffStack, FolderOfPagesInNaturalNameOrder) {
  const auto dir = test::freshTempDir("tiff_folder");
  // Slice k is stored under the k-th name in natural order, not in plain string order.
  const char* names[] = {"slice1.tif", "slice2.tif", "slice9.tiff", "slice10.tif", "slice011.TIF"};
  for (int k = 0; k < 5; ++k)
    ASSERT_TRUE(cv::imwrite((dir / names[k]).string(), page16(21, 13, k)));
  auto source = openTiffStack(dir.string(), {0.5, 0.5, 2});
  EXPECT_EQ(source->info().dims, (std::array<int64_t, 3>{21, 13, 5}));
  EXPECT_EQ(source->info().format, "tiff");
  EXPECT_TRUE(source->info().integerValues);
  EXPECT_EQ(source->info().spacingMm().z, 2);
  expectValues(*source, 2, [](int64_t i, int64_t j, int64_t k) {
    return static_cast<float>(typedValue<uint16_t>(i, j, k));
  });
}

// A stack whose file numbers skip one is read, and the jump is said: a slice file is likely
// missing. Complete numbering, or a constant step other than 1, says nothing.
TEST(TiffStack, GapInTheFileNumbersIsAWarning) {
  const auto stack = [](const std::string& name, const std::vector<int>& numbers) {
    const auto dir = test::freshTempDir(name);
    for (int n : numbers) {
      EXPECT_TRUE(cv::imwrite((dir / fmt::format("s{:03d}.tif", n)).string(), page16(8, 8, n)));
    }
    return openTiffStack(dir.string(), {1, 1, 1});
  };
  const auto gap = stack("tiff_gap", {0, 1, 2, 3, 4, 6, 7});
  EXPECT_EQ(gap->info().dims[2], 7);
  ASSERT_EQ(gap->info().warnings.size(), 1u);
  EXPECT_EQ(gap->info().warnings[0], "the file numbers jump from 4 to 6 (s004.tif to s006.tif): a "
                                     "slice file may be missing, and the stack closes the gap");
  EXPECT_TRUE(stack("tiff_whole", {0, 1, 2, 3, 4})->info().warnings.empty());
  EXPECT_TRUE(stack("tiff_step2", {10, 12, 14, 16})->info().warnings.empty());
}

// TIFF files with other entries beside them (notes, a subfolder) and no DICOM series: the TIFF
// stack, which names what it leaves out (it said "no DICOM image series found").
TEST(TiffStack, FolderWithOtherEntriesIsTheStackWithAWarning) {
  const auto dir = test::freshTempDir("tiff_others");
  for (int k = 0; k < 4; ++k) {
    ASSERT_TRUE(cv::imwrite((dir / fmt::format("s{}.tif", k)).string(), page16(8, 6, k)));
  }
  writeFile(dir / "notes.txt", "acquired on the micro-CT, 20 um\n");
  fs::create_directories(dir / "thumbnails");
  writeFile(dir / ".DS_Store", "hidden");
  fs::create_symlink(dir / "moved.tif", dir / "s9.tif");  // dangling: another entry
  auto source = openVolume(dir.string());
  EXPECT_EQ(source->info().format, "tiff");
  EXPECT_EQ(source->info().dims, (std::array<int64_t, 3>{8, 6, 4}));
  ASSERT_EQ(source->info().warnings.size(), 1u);
  EXPECT_EQ(source->info().warnings[0],
            "left out 3 entries that are not a .tif or .tiff file: notes.txt, s9.tif, thumbnails");
  expectValues(*source, 4, [](int64_t i, int64_t j, int64_t k) {
    return static_cast<float>(typedValue<uint16_t>(i, j, k));
  });
}

// An entry that cannot be looked at (a dangling link) does not stop the folder being listed:
// a folder holding only one says what DICOM discovery found, not "cannot list the folder".
TEST(TiffStack, DanglingLinkIsAnEntryNotAListingFailure) {
  const auto dir = test::freshTempDir("tiff_dangling");
  fs::create_symlink(dir / "gone.dcm", dir / "d");
  try {
    openVolume(dir.string());
    ADD_FAILURE() << "a folder of one dangling link opened";
  } catch (const Error& e) {
    EXPECT_EQ(std::string(e.what()),
              dir.string() + ": no DICOM image series found (0 files examined)");
  }
}

// `count` float pages of `columns` x `rows` holding fractionalRamp, for a multi-page TIFF.
std::vector<cv::Mat> fractionalRampPages(int columns, int rows, int count) {
  std::vector<cv::Mat> pages;
  for (int k = 0; k < count; ++k) {
    cv::Mat page(rows, columns, CV_32F);
    for (int j = 0; j < rows; ++j)
      for (int i = 0; i < columns; ++i) page.at<float>(j, i) = fractionalRamp(i, j, k);
    pages.push_back(page);
  }
  return pages;
}

TEST(TiffStack, MultiPageFloatFile) {
  const auto dir = test::freshTempDir("tiff_multi");
  ASSERT_TRUE(cv::imwrite((dir / "stack.tiff").string(), fractionalRampPages(10, 9, 6)));
  auto source = openTiffStack((dir / "stack.tiff").string());
  EXPECT_EQ(source->info().dims, (std::array<int64_t, 3>{10, 9, 6}));
  EXPECT_FALSE(source->info().integerValues);
  expectValues(*source, 4, fractionalRamp);
  expectValues(*source, 1, fractionalRamp);
}

// A multi-page file stays open between slabs on the page read last: slabs asked for in any
// order and again read the right pages, and so do they after a slab that failed (the file cut
// short while open) and after the file is unlinked.
TEST(TiffStack, MultiPageSlabsInAnyOrderAndAfterAFailure) {
  const auto dir = test::freshTempDir("tiff_multi_order");
  const fs::path file = dir / "stack.tif";
  ASSERT_TRUE(cv::imwrite(file.string(), fractionalRampPages(5, 7, 12)));
  auto source = openTiffStack(file.string());
  ASSERT_EQ(source->info().dims, (std::array<int64_t, 3>{5, 7, 12}));
  const auto expectSlab = [&](int64_t first, int64_t count) {
    std::vector<float> slab(static_cast<std::size_t>(35 * count));
    source->readSlab(first, count, slab);
    for (int64_t k = 0; k < count; ++k)
      for (int64_t n = 0; n < 35; ++n) {
        ASSERT_EQ(slab[static_cast<std::size_t>(35 * k + n)],
                  fractionalRamp(n % 5, n / 5, first + k))
            << "slab from " << first << ", page " << first + k << ", sample " << n;
      }
  };
  for (const auto& [first, count] : std::vector<std::pair<int64_t, int64_t>>{
           {0, 3}, {3, 3}, {9, 3}, {2, 4}, {11, 1}, {0, 1}, {6, 6}, {6, 6}, {5, 1}}) {
    expectSlab(first, count);
  }
  // Cut inside the last page: reading it fails by name, the pages before it still read (the
  // file is opened again after a failure).
  fs::resize_file(file, fs::file_size(file) - 60);
  std::vector<float> last(35);
  EXPECT_THROW(source->readSlab(11, 1, last), Error);
  expectSlab(1, 3);
  expectSlab(4, 1);
  // Unlinked: the file open since that slab still reads (it was reopened for every slab).
  fs::remove(file);
  expectSlab(8, 3);
  expectSlab(0, 2);
}

// The tags of a grey page of `type` for tiffBytes: size, samples, uncompressed.
std::vector<TiffEntry> greyPageTags(SampleType type, uint32_t width, uint32_t height) {
  const uint32_t format =
      type == SampleType::Float32 || type == SampleType::Float64                           ? 3
      : type == SampleType::Int8 || type == SampleType::Int16 || type == SampleType::Int32 ? 2
                                                                                           : 1;
  return {{256, 4, {width}},
          {257, 4, {height}},
          {258, 3, {static_cast<uint32_t>(8 * sampleBytes(type))}},
          {259, 3, {1}},
          {262, 3, {1}},
          {277, 3, {1}},
          {339, 3, {format}}};
}

// Rows [y0, y0 + rows) and columns [x0, x0 + columns) of a page encoded row by row with
// `bytes` per sample, as a strip or tile `blockWidth` samples wide and `blockRows` high;
// outside the page the block holds 0xAB bytes, which the reader must not show.
std::string cutBlock(const std::string& page, std::size_t width, std::size_t bytes, std::size_t x0,
                     std::size_t y0, std::size_t columns, std::size_t rows, std::size_t blockWidth,
                     std::size_t blockRows) {
  std::string block(blockWidth * blockRows * bytes, '\xAB');
  for (std::size_t r = 0; r < rows; ++r) {
    block.replace(r * blockWidth * bytes, columns * bytes, page, ((y0 + r) * width + x0) * bytes,
                  columns * bytes);
  }
  return block;
}

// Pages made by hand (not by a TIFF library): every sample type, both byte orders, in strips
// of 5 rows (the last one short) and in 16 x 16 tiles that overhang the page.
TEST(TiffStack, HandMadePagesInEveryTypeByteOrderAndLayout) {
  constexpr uint32_t kWidth = 21, kHeight = 13;
  for (const SampleType type : kAllTypes) {
    for (const bool bigEndian : {false, true}) {
      for (const bool tiled : {false, true}) {
        SCOPED_TRACE(fmt::format("type {}, {} endian, {}", static_cast<int>(type),
                                 bigEndian ? "big" : "little", tiled ? "tiles" : "strips"));
        const auto dir = test::freshTempDir("tiff_hand");
        const std::size_t bytes = sampleBytes(type);
        const std::string volume = encodeAs(type, {kWidth, kHeight, 2}, bigEndian);
        for (int k = 0; k < 2; ++k) {
          const std::string page =
              volume.substr(k * kWidth * kHeight * bytes, kWidth * kHeight * bytes);
          auto tags = greyPageTags(type, kWidth, kHeight);
          std::vector<std::string> blocks;
          if (tiled) {
            tags.push_back({322, 4, {16}});
            tags.push_back({323, 4, {16}});
            for (uint32_t y0 = 0; y0 < kHeight; y0 += 16) {
              for (uint32_t x0 = 0; x0 < kWidth; x0 += 16) {
                blocks.push_back(cutBlock(page, kWidth, bytes, x0, y0, std::min(16u, kWidth - x0),
                                          std::min(16u, kHeight - y0), 16, 16));
              }
            }
          } else {
            tags.push_back({278, 4, {5}});
            for (uint32_t y0 = 0; y0 < kHeight; y0 += 5) {
              const uint32_t rows = std::min(5u, kHeight - y0);
              blocks.push_back(cutBlock(page, kWidth, bytes, 0, y0, kWidth, rows, kWidth, rows));
            }
          }
          writeFile(dir / fmt::format("p{}.tif", k), tiffBytes(tags, blocks, tiled, bigEndian));
        }
        auto source = openTiffStack(dir.string());
        EXPECT_EQ(source->info().dims, (std::array<int64_t, 3>{kWidth, kHeight, 2}));
        // Integer pages are bounded by their storage type, whatever these few pages hold.
        const std::map<SampleType, std::pair<double, double>> bounds = {
            {SampleType::UInt8, {0, 255}},
            {SampleType::Int8, {-128, 127}},
            {SampleType::UInt16, {0, 65535}},
            {SampleType::Int16, {-32768, 32767}},
            {SampleType::UInt32, {0, 4294967295.0}},
            {SampleType::Int32, {-2147483648.0, 2147483647.0}}};
        EXPECT_EQ(source->info().integerValues, bounds.contains(type));
        if (bounds.contains(type)) {
          EXPECT_EQ(source->info().valueLowerBound, bounds.at(type).first);
          EXPECT_EQ(source->info().valueUpperBound, bounds.at(type).second);
        }
        expectValues(*source, 2,
                     [type](int64_t i, int64_t j, int64_t k) { return expectedAs(type, i, j, k); });
      }
    }
  }
}

// Orientation flips rows and columns into place; min-is-white inverts unsigned samples. A
// page with rows and columns swapped, or min-is-white signed samples, is refused by name.
TEST(TiffStack, OrientationAndMinIsWhiteAreHonoured) {
  constexpr uint32_t kWidth = 7, kHeight = 5;
  const std::string page = encode<uint16_t>({kWidth, kHeight, 1}, false);
  const auto stored = [](int64_t i, int64_t j) {
    return static_cast<float>(typedValue<uint16_t>(i, j, 0));
  };
  // In one strip; or in 4 x 4 tiles that overhang the page (`tiled`).
  const auto open = [&](const std::string& name, uint32_t orientation, uint32_t photometric,
                        SampleType type = SampleType::UInt16, bool tiled = false) {
    const auto dir = test::freshTempDir("tiff_orientation");
    auto tags = greyPageTags(type, kWidth, kHeight);
    tags.push_back({274, 3, {orientation}});
    for (auto& tag : tags)
      if (tag.tag == 262) tag.values = {photometric};
    std::vector<std::string> blocks{page};
    if (tiled) {
      tags.push_back({322, 4, {16}});
      tags.push_back({323, 4, {16}});
      blocks = {cutBlock(page, kWidth, 2, 0, 0, kWidth, kHeight, 16, 16)};
    }
    writeFile(dir / name, tiffBytes(tags, blocks, tiled, false));
    return openTiffStack((dir / name).string());
  };
  const auto expectPage = [&](VolumeSource& source, auto expected) {
    expectValues(source, 1, [&](int64_t i, int64_t j, int64_t) { return expected(i, j); });
  };
  constexpr int64_t w = kWidth - 1, h = kHeight - 1;
  expectPage(*open("tl.tif", 1, 1), [&](int64_t i, int64_t j) { return stored(i, j); });
  expectPage(*open("tr.tif", 2, 1), [&](int64_t i, int64_t j) { return stored(w - i, j); });
  expectPage(*open("br.tif", 3, 1), [&](int64_t i, int64_t j) { return stored(w - i, h - j); });
  expectPage(*open("bl.tif", 4, 1), [&](int64_t i, int64_t j) { return stored(i, h - j); });
  expectPage(*open("white.tif", 1, 0), [&](int64_t i, int64_t j) { return 65535 - stored(i, j); });
  // A tile larger than the page, flipped both ways and inverted.
  expectPage(*open("br-white-tiled.tif", 3, 0, SampleType::UInt16, true),
             [&](int64_t i, int64_t j) { return 65535 - stored(w - i, h - j); });
  expectErrorMentioning([&] { open("lt.tif", 5, 1); }, "lt.tif: has orientation 5");
  expectErrorMentioning([&] { open("white16s.tif", 1, 0, SampleType::Int16); },
                        "white16s.tif: is min-is-white with signed or float samples");
}

TEST(TiffStack, ColourAndMismatchedPagesThrowNamingTheFile) {
  const auto dir = test::freshTempDir("tiff_bad");
  ASSERT_TRUE(
      cv::imwrite((dir / "colour.tif").string(), cv::Mat(4, 4, CV_8UC3, cv::Scalar(1, 2, 3))));
  expectErrorMentioning([&] { openTiffStack((dir / "colour.tif").string()); }, "colour.tif");

  const auto folder = dir / "mixed";
  fs::create_directories(folder);
  ASSERT_TRUE(cv::imwrite((folder / "a1.tif").string(), page16(8, 8, 0)));
  ASSERT_TRUE(cv::imwrite((folder / "a2.tif").string(), page16(9, 8, 1)));
  expectErrorMentioning(
      [&] {
        auto source = openTiffStack(folder.string());
        std::vector<float> all(8 * 8 * 2);
        source->readSlab(0, 2, all);
      },
      "a2.tif");
  writeFile(dir / "junk.tif", "II*\0garbage");
  EXPECT_THROW(openTiffStack((dir / "junk.tif").string()), Error);
  EXPECT_THROW(openTiffStack((dir / "none").string()), Error);
}

// ---- openVolume -----------------------------------------------------------------------------

TEST(FormatsOpenVolume, DispatchesByExtensionFolderAndRawOption) {
  const auto dir = test::freshTempDir("open_volume");
  const std::array<int64_t, 3> dims{12, 5, 4};
  writeFile(dir / "v.raw", encode<int16_t>(dims, false));
  OpenOptions raw;
  raw.raw = true;
  raw.rawOptions.dims = dims;
  EXPECT_EQ(openVolume((dir / "v.raw").string(), raw)->info().format, "raw");

  writeFile(dir / "v.NRRD", fmt::format("NRRD0004\ntype: short\ndimension: 3\nsizes: 12 5 4\n"
                                        "endian: little\nencoding: raw\n\n") +
                                encode<int16_t>(dims, false));
  EXPECT_EQ(openVolume((dir / "v.NRRD").string())->info().format, "nrrd");
  writeFile(dir / "v.mha",
            "NDims = 3\nDimSize = 12 5 4\nElementType = MET_SHORT\n"
            "ElementDataFile = LOCAL\n" +
                encode<int16_t>(dims, false));
  EXPECT_EQ(openVolume((dir / "v.mha").string())->info().format, "metaimage");
  FunctionSource source(dims, Mat4::identity(), true, integerRamp);
  exportNifti(source, (dir / "v.nii.gz").string());
  EXPECT_EQ(openVolume((dir / "v.nii.gz").string())->info().format, "nifti");

  const auto tiffs = dir / "tiffs";
  fs::create_directories(tiffs);
  for (int k = 0; k < 3; ++k) {
    ASSERT_TRUE(cv::imwrite((tiffs / fmt::format("p{}.tif", k)).string(), page16(6, 4, k)));
  }
  OpenOptions spaced;
  spaced.tiffSpacingMm = {1, 1, 3};
  auto stack = openVolume(tiffs.string(), spaced);
  EXPECT_EQ(stack->info().format, "tiff");
  EXPECT_EQ(stack->info().dims[2], 3);
  EXPECT_EQ(stack->info().spacingMm().z, 3);
  EXPECT_EQ(openVolume((tiffs / "p1.tif").string())->info().dims[2], 1);
}

TEST(FormatsOpenVolume, MissingUnknownAndGarbageInputsThrow) {
  const auto dir = test::freshTempDir("open_garbage");
  expectErrorMentioning([&] { openVolume((dir / "absent.nii").string()); }, "absent.nii");
  writeFile(dir / "notes.txt", "just some text, not a volume\n");
  expectErrorMentioning([&] { openVolume((dir / "notes.txt").string()); }, "notes.txt");

  std::mt19937 random(1234);
  for (const char* ext :
       {".nrrd", ".nhdr", ".mhd", ".mha", ".nii", ".nii.gz", ".hdr", ".tif", ".tiff", ".dcm", ""}) {
    for (std::size_t size : {0u, 3u, 64u, 348u, 4096u}) {
      std::string bytes(size, '\0');
      for (char& c : bytes) c = static_cast<char>(random());
      const auto file = dir / fmt::format("garbage{}{}", size, ext);
      writeFile(file, bytes);
      EXPECT_THROW(openVolume(file.string()), Error) << file;
    }
  }
}

}  // namespace
}  // namespace octoray
