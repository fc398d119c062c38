// What a volume is read from: VolumeInfo::sourceFiles for DICOM series, detached NRRD headers
// and raw files, and the content hash over them (what a store records and octoray-batch
// compares): independent of paths and order, changed by one byte, naming an unreadable file.

#include <gtest/gtest.h>

#include <fstream>

#include "format_test_helpers.h"
#include "octoray/core/error.h"
#include "octoray/dicom/dicom_series.h"
#include "octoray/dicom/dicom_volume.h"
#include "octoray/dicom/synthetic_series.h"
#include "test_paths.h"

namespace octoray {
namespace {

using namespace octoray::formats_test;

TEST(SourceFiles, DicomSeriesListsEveryFileOfTheSeriesOnly) {
  const auto dir = test::freshTempDir("dicom_files");
  dicom::SyntheticSeriesSpec spec;
  spec.sliceCount = 5;
  spec.withLocalizer = true;
  dicom::writeSyntheticSeries(dir, spec);
  const dicom::DicomScan scan = dicom::scanDicom(dir);
  const auto& series = scan.series.at(dicom::defaultSeriesIndex(scan, dir.string()));
  const auto source = dicom::openDicomSeries(series, {});
  const auto& files = source->info().sourceFiles;
  ASSERT_EQ(files.size(), 5u);
  EXPECT_TRUE(std::is_sorted(files.begin(), files.end()));
  for (const auto& f : files) EXPECT_EQ(f.find("LOC"), std::string::npos) << "the localiser is another series";

  // The same series re-read from exactly its files.
  const dicom::DicomScan again = dicom::scanDicomFiles({files.rbegin(), files.rend()});
  ASSERT_EQ(again.series.size(), 1u);
  EXPECT_EQ(again.series[0].seriesUid, series.seriesUid);
  EXPECT_EQ(again.series[0].frames.size(), 5u);
}

TEST(SourceFiles, DetachedHeaderListsHeaderAndData) {
  const auto dir = test::freshTempDir("nhdr_files");
  const std::array<int64_t, 3> dims{8, 6, 3};
  writeFile(dir / "data.raw", encode<int16_t>(dims, false));
  writeFile(dir / "v.nhdr", "NRRD0004\ntype: short\ndimension: 3\nsizes: 8 6 3\nendian: little\n"
                            "encoding: raw\ndata file: data.raw\n");
  const auto source = openVolume((dir / "v.nhdr").string());
  EXPECT_EQ(source->info().sourceFiles,
            (std::vector<std::string>{(dir / "data.raw").string(), (dir / "v.nhdr").string()}));
}

TEST(ContentHash, IgnoresNamesAndOrderAndSeesEveryByte) {
  const auto dir = test::freshTempDir("hash");
  writeFile(dir / "a", "first file");
  writeFile(dir / "b", std::string(3 << 20, 'x'));  // more than one read buffer
  writeFile(dir / "c", "first file");
  const std::string ab = sourceContentHash({(dir / "a").string(), (dir / "b").string()});
  EXPECT_EQ(ab.size(), 32u);
  EXPECT_EQ(ab, sourceContentHash({(dir / "b").string(), (dir / "a").string()}));
  EXPECT_EQ(ab, sourceContentHash({(dir / "c").string(), (dir / "b").string()})) << "contents, not names";
  EXPECT_NE(ab, sourceContentHash({(dir / "a").string()}));
  {
    std::fstream f(dir / "b", std::ios::in | std::ios::out | std::ios::binary);
    f.seekp((3 << 20) - 1);
    f.put('y');
  }
  EXPECT_NE(ab, sourceContentHash({(dir / "a").string(), (dir / "b").string()}));
  expectErrorMentioning([&] { sourceContentHash({(dir / "missing").string()}); }, (dir / "missing").string());
  // The combination of per-file hashes is the same hash.
  EXPECT_EQ(combinedContentHash({fileContentHash((dir / "b").string()), fileContentHash((dir / "a").string())}),
            sourceContentHash({(dir / "a").string(), (dir / "b").string()}));
}

}  // namespace
}  // namespace octoray
