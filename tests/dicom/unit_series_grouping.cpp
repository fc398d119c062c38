// How scanDicom splits and classifies what shares one SeriesInstanceUID.
#include <gtest/gtest.h>

#include <fstream>

#include "octoray/dicom/dicom_series.h"
#include "octoray/dicom/dicom_volume.h"
#include "octoray/dicom/synthetic_series.h"
#include "dicom_edit.h"
#include "test_paths.h"

namespace octoray::dicom {
namespace {

using test::DicomTag;
// Rewrites string elements of a DICOM file in place (for building awkward exams).
void rewrite(const std::filesystem::path& path, const std::vector<std::pair<DicomTag, std::string>>& values) {
  ASSERT_NO_THROW(test::rewriteDicomStrings(path, values));
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
  rewrite(localizer, {{{0x0020, 0x000e}, written.seriesUid},
                      {{0x0020, 0x0037}, "1\\0\\0\\0\\1\\0"},
                      {{0x0028, 0x0030}, "0.5\\0.5"}});

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

const DicomTag kCenter{0x0028, 0x1050}, kWidth{0x0028, 0x1051}, kExplanation{0x0028, 0x1055},
    kFunction{0x0028, 0x1056};

// What each written file names as its display windows, and the volume opened from them.
struct WindowedSeries {
  std::filesystem::path dir;
  VolumeInfo info;
};
WindowedSeries writeWithWindows(const std::string& name,
                                const std::vector<std::vector<std::pair<DicomTag, std::string>>>& perFile) {
  const auto dir = test::freshTempDir(name);
  SyntheticSeriesSpec spec;
  spec.sliceCount = static_cast<int>(perFile.size());
  const SyntheticSeries written = writeSyntheticSeries(dir, spec);
  EXPECT_EQ(written.images.size(), perFile.size());
  for (std::size_t i = 0; i < perFile.size() && i < written.images.size(); ++i) {
    rewrite(written.images[i].path, perFile[i]);
  }
  const DicomScan scan = scanDicom(dir);
  EXPECT_EQ(scan.series.size(), 1u);
  if (scan.series.empty()) return {};
  return {dir, openDicomSeries(scan.series[0])->info()};
}

// The windows a series names for display (WindowCenter / WindowWidth, in HU after the rescale)
// are what most of its slices name, in their order with their explanations; the volume keeps
// them for the viewer and the store.
TEST(SeriesWindows, TheWindowsMostSlicesNameInTheirOrder) {
  const std::vector<std::pair<DicomTag, std::string>> two = {
      {kCenter, "40\\-600"}, {kWidth, "400\\1500"}, {kExplanation, "SOFT TISSUE\\LUNG"}};
  const std::vector<std::pair<DicomTag, std::string>> other = {{kCenter, "50"}, {kWidth, "350"}};
  const WindowedSeries w = writeWithWindows("windows", {other, two, two, two, other});
  ASSERT_EQ(w.info.windows.size(), 2u);
  EXPECT_EQ(w.info.windows[0].center, 40);
  EXPECT_EQ(w.info.windows[0].width, 400);
  EXPECT_EQ(w.info.windows[0].explanation, "SOFT TISSUE");
  EXPECT_EQ(w.info.windows[1].center, -600);
  EXPECT_EQ(w.info.windows[1].width, 1500);
  EXPECT_EQ(w.info.windows[1].explanation, "LUNG");
  EXPECT_TRUE(w.info.warnings.empty()) << w.info.warnings.front();

  // A window named twice (Philips' "40\\40" / "80\\80") is one; on a tie the first file's wins.
  const std::vector<std::pair<DicomTag, std::string>> twice = {{kCenter, "40\\40"}, {kWidth, "80\\80"}};
  const WindowedSeries tie = writeWithWindows("windows-tie", {twice, other, twice, other});
  ASSERT_EQ(tie.info.windows.size(), 1u);
  EXPECT_EQ(tie.info.windows[0].center, 40);
  EXPECT_EQ(tie.info.windows[0].width, 80);
  EXPECT_EQ(tie.info.windows[0].explanation, "");
}

// An enhanced object names its windows per frame (Frame VOI LUT, per-frame or shared): the
// window most frames name wins, as for single-frame files.
TEST(SeriesWindows, AnEnhancedObjectsFramesVoteWithTheirOwnFrameVoiLut) {
  for (const int own : {3, 2}) {
    SCOPED_TRACE(own);
    const auto dir = test::freshTempDir("windows-enhanced");
    SyntheticSeriesSpec spec;
    spec.sliceCount = 5;
    spec.layout = SyntheticLayout::EnhancedMultiFrame;
    spec.framesWithOwnWindow = own;
    writeSyntheticSeries(dir, spec);
    const DicomScan scan = scanDicom(dir);
    ASSERT_EQ(scan.series.size(), 1u);
    ASSERT_TRUE(scan.series[0].multiFrame);
    const VolumeInfo info = openDicomSeries(scan.series[0])->info();
    ASSERT_EQ(info.windows.size(), 1u);
    EXPECT_EQ(info.windows[0].center, own == 3 ? -600 : 40);
    EXPECT_EQ(info.windows[0].width, own == 3 ? 1500 : 400);
    EXPECT_EQ(info.windows[0].explanation, own == 3 ? "LUNG" : "");
  }
}

// A window that is not a pair of finite numbers, narrower than 1 where the function is LINEAR
// (which allows none, PS3.3 C.11.2.1.2.1) or not above 0 where it is LINEAR_EXACT (which
// allows any above 0), is left out with a warning naming the file; the series is read as
// before. A LINEAR_EXACT window narrower than 1 is kept (the viewer shows it on values that
// are not integers). A VOILUTFunction that is not a defined term is said, and taken as none.
TEST(SeriesWindows, UnusableWindowsAreLeftOutWithAWarningNamingTheFile) {
  struct Case {
    const char* name;
    std::vector<std::pair<DicomTag, std::string>> values;
    std::size_t windowsKept;
    const char* warning;  // none where every window is kept
  };
  const Case cases[] = {
      {"narrow", {{kCenter, "40\\300"}, {kWidth, "0.5\\1500"}}, 1,
       "WindowWidth 0.5 is below 1, the least the LINEAR VOI function allows: that window"},
      {"exact-narrow", {{kCenter, "0.3\\300"}, {kWidth, "0.5\\1500"}, {kFunction, "LINEAR_EXACT"}}, 2, nullptr},
      {"exact-zero", {{kCenter, "40\\300"}, {kWidth, "0\\1500"}, {kFunction, "LINEAR_EXACT"}}, 1,
       "WindowWidth 0 is not above 0: that window is left out"},
      {"junk", {{kCenter, "forty"}, {kWidth, "80"}}, 0,
       "WindowCenter 'forty' / WindowWidth '80' are not finite numbers"},
      {"uneven", {{kCenter, "40\\300"}, {kWidth, "80"}}, 1, "WindowCenter has 2 values and WindowWidth 1"},
      {"undefined-function", {{kCenter, "40"}, {kWidth, "80"}, {kFunction, "LOG"}}, 1,
       "VOILUTFunction 'LOG' is not LINEAR, LINEAR_EXACT or SIGMOID: its windows are taken as LINEAR"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const WindowedSeries w = writeWithWindows(std::string("windows-") + c.name, {c.values, c.values, c.values});
    EXPECT_EQ(w.info.windows.size(), c.windowsKept);
    for (const SourceWindow& kept : w.info.windows) EXPECT_GT(kept.width, 0);
    if (!c.warning) {
      EXPECT_TRUE(w.info.warnings.empty()) << w.info.warnings[0];
      EXPECT_EQ(w.info.windows.front().width, 0.5);
      continue;
    }
    ASSERT_EQ(w.info.warnings.size(), 1u);
    EXPECT_NE(w.info.warnings[0].find(c.warning), std::string::npos) << w.info.warnings[0];
    EXPECT_EQ(w.info.warnings[0].rfind(w.dir.string() + "/", 0), 0u) << w.info.warnings[0];  // names the file
    EXPECT_EQ(w.info.dims[2], 3);
  }
}

// Each window carries the VOI LUT function its file declares (VOILUTFunction), for the viewer
// to show it with: LINEAR_EXACT and SIGMOID as written, "" where the file declares none or
// LINEAR (the default); an undefined term is taken as none.
TEST(SeriesWindows, EachWindowCarriesTheFunctionItsFileDeclares) {
  for (const auto& [declared, kept] : {std::pair<std::string, std::string>{"SIGMOID", "SIGMOID"},
                                       {"LINEAR_EXACT", "LINEAR_EXACT"},
                                       {"LINEAR", ""},
                                       {"", ""},
                                       {"LOG", ""}}) {
    SCOPED_TRACE(declared);
    std::vector<std::pair<DicomTag, std::string>> values = {{kCenter, "40\\-600"}, {kWidth, "80\\1500"}};
    if (!declared.empty()) values.push_back({kFunction, declared});
    const WindowedSeries w = writeWithWindows("windows-function-" + (declared.empty() ? std::string("none") : declared),
                                              {values, values, values});
    ASSERT_EQ(w.info.windows.size(), 2u);
    EXPECT_EQ(w.info.windows[0].function, kept);
    EXPECT_EQ(w.info.windows[1].function, kept);
    EXPECT_EQ(w.info.windows[1].width, 1500);
  }
}

// Files that declare LINEAR and files that declare nothing name the same windows: one choice,
// not two, when the series' slices vote.
TEST(SeriesWindows, DeclaredLinearAndNoneAreOneChoice) {
  const std::vector<std::pair<DicomTag, std::string>> none = {{kCenter, "40"}, {kWidth, "400"}};
  std::vector<std::pair<DicomTag, std::string>> linear = none;
  linear.push_back({kFunction, "LINEAR"});
  const std::vector<std::pair<DicomTag, std::string>> other = {{kCenter, "50"}, {kWidth, "350"}};
  // Two say nothing and two LINEAR (four for 40 / 400), three name another window.
  const WindowedSeries w = writeWithWindows("windows-linear-none", {none, other, linear, other, none, other, linear});
  ASSERT_EQ(w.info.windows.size(), 1u);
  EXPECT_EQ(w.info.windows[0].center, 40);
  EXPECT_EQ(w.info.windows[0].function, "");
}

}  // namespace
}  // namespace octoray::dicom
