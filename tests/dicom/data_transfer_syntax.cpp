// The same real CT pixels in every lossless transfer syntax gdcmconv writes: decoding must
// give the original stored values exactly, and a whole series re-encoded must open to the
// same volume, slab for slab. (gdcmconv cannot write explicit big endian; Debian's pydicom
// files MR_small_bigendian.dcm and rtdose_expb.dcm cover it in data_pydicom.cpp.)

#include <gdcmReader.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "octoray/dicom/dicom_decode.h"
#include "octoray/dicom/dicom_series.h"
#include "octoray/dicom/dicom_volume.h"
#include "philips_data.h"
#include "test_paths.h"

namespace octoray {
namespace {

namespace fs = std::filesystem;

struct Syntax {
  const char* name;
  const char* gdcmconvFlag;
  const char* uid;
};
// gdcmconv's compressors are lossless unless --lossy is given.
constexpr Syntax kLosslessSyntaxes[] = {
    {"implicit", "--implicit", "1.2.840.10008.1.2"},
    {"explicit", "--explicit", "1.2.840.10008.1.2.1"},
    {"raw", "--raw", "1.2.840.10008.1.2.1"},
    {"deflated", "--deflated", "1.2.840.10008.1.2.1.99"},
    {"rle", "--rle", "1.2.840.10008.1.2.5"},
    {"jpeg-lossless", "--jpeg", "1.2.840.10008.1.2.4.70"},
    {"jpeg-ls", "--jpegls", "1.2.840.10008.1.2.4.80"},
    {"j2k", "--j2k", "1.2.840.10008.1.2.4.90"},
};

fs::path fineSeries() { return test::philipsDir() / "S21570/S2020"; }

bool haveGdcmconv() { return std::system("gdcmconv --version > /dev/null 2>&1") == 0; }

std::string transferSyntaxOf(const fs::path& file) {
  gdcm::Reader reader;
  reader.SetFileName(file.c_str());
  if (!reader.ReadUpToTag(gdcm::Tag(0x0008, 0x0016), {})) return "unreadable";
  const char* uid = reader.GetFile().GetHeader().GetDataSetTransferSyntax().GetString();
  return uid ? uid : "";
}

// Re-encodes `files` into `dir` with one gdcmconv flag, in one shell run.
void reencode(const std::vector<fs::path>& files, const fs::path& dir, const char* flag) {
  fs::create_directories(dir);
  std::string script;
  for (const fs::path& f : files) {
    script += fmt::format("gdcmconv {} '{}' '{}' || exit 1; ", flag, f.string(),
                          (dir / f.filename()).string());
  }
  const std::string command = "sh -c \"" + script + "\" > '" + (dir / "gdcmconv.log").string() +
                              "' 2>&1";
  ASSERT_EQ(std::system(command.c_str()), 0) << "gdcmconv " << flag << " failed; see "
                                             << (dir / "gdcmconv.log");
  fs::remove(dir / "gdcmconv.log");
}

TEST(TransferSyntax, FiveSlicesInEveryLosslessSyntaxDecodeToTheOriginalValues) {
  OCTORAY_REQUIRE_PATH(fineSeries());
  if (!haveGdcmconv()) GTEST_SKIP() << "skipped: gdcmconv (package libgdcm-tools) is absent";
  const auto all = philips_test::imageFiles(fineSeries());
  ASSERT_EQ(all.size(), 140u);
  std::vector<fs::path> picked;
  for (std::size_t n = 0; n < 5; ++n) picked.push_back(all[n * (all.size() - 1) / 4]);

  const fs::path root = test::freshTempDir("syntaxes");
  for (const Syntax& syntax : kLosslessSyntaxes) {
    SCOPED_TRACE(syntax.name);
    const fs::path dir = root / syntax.name;
    reencode(picked, dir, syntax.gdcmconvFlag);
    for (const fs::path& original : picked) {
      const fs::path copy = dir / original.filename();
      SCOPED_TRACE(copy.string());
      ASSERT_EQ(transferSyntaxOf(copy), syntax.uid);
      const dicom::DecodedImage expected = dicom::decodeDicomFile(original.string());
      const dicom::DecodedImage got = dicom::decodeDicomFile(copy.string());
      EXPECT_EQ(got.format.transferSyntaxUid, syntax.uid);
      ASSERT_EQ(got.format.rows, expected.format.rows);
      ASSERT_EQ(got.format.columns, expected.format.columns);
      ASSERT_EQ(got.format.frames, expected.format.frames);
      // The data set's BitsStored (0028,0101) rules, not the codestream's precision.
      EXPECT_EQ(got.format.bitsStored, expected.format.bitsStored)
          << "BitsStored reported differs from the file's (0028,0101)";
      EXPECT_EQ(got.format.pixelSigned, expected.format.pixelSigned);
      ASSERT_EQ(got.stored.size(), expected.stored.size());
      std::size_t differing = 0;
      for (std::size_t i = 0; i < got.stored.size(); ++i) differing += got.stored[i] != expected.stored[i];
      EXPECT_EQ(differing, 0u) << "samples differ from the original";
    }
    std::cout << fmt::format("{:<14} {:<24} {} slices identical\n", syntax.name, syntax.uid,
                             picked.size());
  }
}

// The whole 140-slice series in JPEG-LS: scanning, sorting, geometry and every sample must
// match the original series. Takes ~15 s in Debug, most of it gdcmconv.
TEST(TransferSyntax, WholeSeriesInJpegLsOpensToTheSameVolume) {
  OCTORAY_REQUIRE_PATH(fineSeries());
  if (!haveGdcmconv()) GTEST_SKIP() << "skipped: gdcmconv (package libgdcm-tools) is absent";
  const auto start = std::chrono::steady_clock::now();
  const fs::path dir = test::freshTempDir("jpegls");
  reencode(philips_test::imageFiles(fineSeries()), dir, "--jpegls");

  const dicom::DicomScan originalScan = dicom::scanDicom(fineSeries());
  const dicom::DicomScan copyScan = dicom::scanDicom(dir);
  const auto original = dicom::openDicomSeries(
      originalScan.series[dicom::defaultSeriesIndex(originalScan, fineSeries().string())]);
  const auto copy =
      dicom::openDicomSeries(copyScan.series[dicom::defaultSeriesIndex(copyScan, dir.string())]);
  const VolumeInfo& a = original->info();
  const VolumeInfo& b = copy->info();
  ASSERT_EQ(a.dims, b.dims);
  ASSERT_EQ(b.dims[2], 140);
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) {
      EXPECT_EQ(a.patientFromIndex.m[r][c], b.patientFromIndex.m[r][c]) << r << "," << c;
    }
  }
  EXPECT_EQ(a.unit, b.unit);
  EXPECT_EQ(a.resampled, b.resampled);

  const int64_t slab = 8;
  std::vector<float> slabA(static_cast<std::size_t>(slab * a.sliceSamples()));
  std::vector<float> slabB(slabA.size());
  for (int64_t k = 0; k < a.dims[2]; k += slab) {
    const int64_t count = std::min(slab, a.dims[2] - k);
    const auto size = static_cast<std::size_t>(count * a.sliceSamples());
    original->readSlab(k, count, std::span<float>(slabA.data(), size));
    copy->readSlab(k, count, std::span<float>(slabB.data(), size));
    ASSERT_TRUE(std::equal(slabA.begin(), slabA.begin() + static_cast<std::ptrdiff_t>(size),
                           slabB.begin()))
        << "slab at slice " << k << " differs";
  }
  std::cout << fmt::format("140 slices in JPEG-LS: identical volume ({:.1f} s)\n",
                           std::chrono::duration<double>(std::chrono::steady_clock::now() - start)
                               .count());
}

}  // namespace
}  // namespace octoray
