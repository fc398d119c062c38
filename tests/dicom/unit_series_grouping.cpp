// How scanDicom splits and classifies what shares one SeriesInstanceUID.
#include <gdcmReader.h>
#include <gdcmWriter.h>
#include <gtest/gtest.h>

#include <fstream>

#include "octoray/dicom/dicom_series.h"
#include "octoray/dicom/synthetic_series.h"
#include "test_paths.h"

namespace octoray::dicom {
namespace {

// Rewrites string elements of a DICOM file in place (for building awkward exams).
void rewrite(const std::filesystem::path& path, const std::vector<std::pair<gdcm::Tag, std::string>>& values) {
  gdcm::Reader reader;
  reader.SetFileName(path.c_str());
  ASSERT_TRUE(reader.Read()) << path;
  gdcm::DataSet& ds = reader.GetFile().GetDataSet();
  for (const auto& [tag, text] : values) {
    gdcm::DataElement de(tag);
    de.SetVR(ds.GetDataElement(tag).GetVR());
    std::string padded = text;
    if (padded.size() % 2) padded += (tag == gdcm::Tag(0x0020, 0x000e) ? '\0' : ' ');
    de.SetByteValue(padded.data(), static_cast<uint32_t>(padded.size()));
    ds.Replace(de);
  }
  gdcm::Writer writer;
  writer.SetFileName(path.c_str());
  writer.SetFile(reader.GetFile());
  ASSERT_TRUE(writer.Write()) << path;
}

TEST(SeriesGrouping, LocalizerFiledUnderTheAxialUidInTheSameOrientationStaysApart) {
  const auto dir = test::freshTempDir("grouping");
  SyntheticSeriesSpec spec;
  spec.sliceCount = 6;
  spec.withLocalizer = true;
  const SyntheticSeries written = writeSyntheticSeries(dir, spec);
  std::filesystem::path localizer;
  for (const auto& image : written.images) {
    if (image.object == SyntheticObject::Localizer) localizer = image.path;
  }
  ASSERT_FALSE(localizer.empty());
  // The localiser now claims the axial series, an axial orientation and the axial pixel
  // spacing: only its ImageType still tells it apart.
  rewrite(localizer, {{gdcm::Tag(0x0020, 0x000e), written.seriesUid},
                      {gdcm::Tag(0x0020, 0x0037), "1\\0\\0\\0\\1\\0"},
                      {gdcm::Tag(0x0028, 0x0030), "0.5\\0.5"}});

  const DicomScan scan = scanDicom(dir);
  ASSERT_EQ(scan.series.size(), 2u);
  int volumes = 0, localizers = 0;
  for (const auto& s : scan.series) {
    EXPECT_EQ(s.seriesUid, written.seriesUid);
    if (s.kind == SeriesKind::Volume) {
      ++volumes;
      EXPECT_EQ(s.frames.size(), 6u);
    }
    if (s.kind == SeriesKind::Localizer) ++localizers;
  }
  EXPECT_EQ(volumes, 1);
  EXPECT_EQ(localizers, 1);
  EXPECT_EQ(scan.series[defaultSeriesIndex(scan, dir.string())].frames.size(), 6u);
}

// Hidden files are not part of an exam: .DS_Store, a retrieval's temporary (a slice cut
// short) and its completion record are neither read nor reported as skipped.
TEST(SeriesGrouping, HiddenFilesAreIgnored) {
  const auto dir = test::freshTempDir("hidden");
  SyntheticSeriesSpec spec;
  spec.sliceCount = 5;
  const SyntheticSeries written = writeSyntheticSeries(dir, spec);
  std::ofstream(dir / ".DS_Store") << "Bud1 garbage";
  std::ofstream(dir / ".octoray-retrieved.json") << "{}";
  std::filesystem::copy_file(written.files.front(), dir / ".extra.dcm.partial-123");
  std::filesystem::resize_file(dir / ".extra.dcm.partial-123", 400);
  const DicomScan scan = scanDicom(dir);
  EXPECT_EQ(scan.filesExamined, written.files.size());
  EXPECT_TRUE(scan.skipped.empty()) << scan.skipped.front().path;
  ASSERT_EQ(scan.series.size(), 1u);
  EXPECT_EQ(scan.series[0].frames.size(), 5u);
}

}  // namespace
}  // namespace octoray::dicom
