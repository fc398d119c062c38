// The viewer's datasets without a window: opening a volume in the background into the
// content-keyed cache, a slice it could not read named in its warnings, and a series arriving
// from a PACS shown slice by slice in the preview as its files land, then imported
// (unit_viewer.cpp has the MPR, presets, sessions, scripts and measurements).
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <memory>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "memory_volume.h"
#include "octoray/dicom/formats.h"
#include "octoray/dicom/synthetic_series.h"
#include "octoray/viewer/dataset.h"
#include "octoray/viewer/mpr.h"
#include "octoray/viewer/session.h"
#include "dicom_edit.h"
#include "test_paths.h"

namespace octoray::viewer {
namespace {

TEST(ViewerDataset, StoreCacheKeyDependsOnContentNotPath) {
  test::MemoryVolume a({20, 20, 10}, [](int64_t i, int64_t, int64_t) { return static_cast<float>(i); });
  test::MemoryVolume b({20, 20, 10}, [](int64_t i, int64_t, int64_t) { return static_cast<float>(i); });
  test::MemoryVolume c({20, 20, 10}, [](int64_t i, int64_t, int64_t k) { return static_cast<float>(i + (k == 9)); });
  EXPECT_EQ(storeCacheKey(a), storeCacheKey(b));
  EXPECT_NE(storeCacheKey(a), storeCacheKey(c));  // the last slice differs
}

// A slice the viewer could not read is named in the dataset's warnings (the Data panel lists
// them), not silently interpolated over.
TEST(ViewerDataset, UnreadableSliceIsNamedInTheWarnings) {
  const auto dir = test::freshTempDir("viewer_left_out");
  dicom::SyntheticSeriesSpec spec;
  spec.sliceCount = 8;
  const dicom::SyntheticSeries written = dicom::writeSyntheticSeries(dir / "series", spec);
  const std::filesystem::path cut = written.slices()[4].path;
  std::filesystem::resize_file(cut, 300);
  Dataset dataset((dir / "series").string(), dir / "cache");
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  while (dataset.state() == Dataset::State::Importing && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  ASSERT_EQ(dataset.state(), Dataset::State::Ready) << dataset.error();
  const std::vector<std::string> warnings = dataset.warnings();
  const bool named = std::any_of(warnings.begin(), warnings.end(), [&](const std::string& w) {
    return w.find(cut.string()) != std::string::npos;
  });
  EXPECT_TRUE(named) << ::testing::PrintToString(warnings);
}

// ---- a series arriving from a PACS -----------------------------------------------------------

// The retrieval's way of landing a file: complete under a hidden name, then renamed.
void land(const std::filesystem::path& from, const std::filesystem::path& to) {
  const std::filesystem::path temporary = to.parent_path() / ("." + to.filename().string() + ".partial");
  std::filesystem::copy_file(from, temporary, std::filesystem::copy_options::overwrite_existing);
  std::filesystem::rename(temporary, to);
}

// The listing a PACS gives for `written` (positions and orientation as written), in slice
// order, with the files to land in `folder`.
std::shared_ptr<IncomingSeries> listingOf(const dicom::SyntheticSeries& written, const std::filesystem::path& folder) {
  auto incoming = std::make_shared<IncomingSeries>();
  incoming->folder = folder;
  incoming->description = "arriving";
  std::vector<dicom::SyntheticImage> slices = written.slices();
  std::sort(slices.begin(), slices.end(), [](const auto& a, const auto& b) { return a.distanceMm < b.distanceMm; });
  const Vec3 r = written.rowDirection, c = written.columnDirection;
  for (const auto& s : slices) {
    const Vec3 p = s.positionMm;
    incoming->slices.push_back({folder / s.path.filename(), std::array<double, 3>{p.x, p.y, p.z},
                                std::array<double, 6>{r.x, r.y, r.z, c.x, c.y, c.z}});
  }
  std::filesystem::create_directories(folder);
  return incoming;
}

template <typename Done>
bool waitFor(Done done, int seconds = 60) {
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(seconds);
  while (!done()) {
    if (std::chrono::steady_clock::now() > deadline) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return true;
}

// One sample of the preview at index position q: a 1 x 1 view centred there.
double previewAt(const PreviewVolume& preview, Vec3 q) {
  SliceRequest req;
  req.plane.right = {1, 0, 0};
  req.plane.down = {0, 1, 0};
  req.plane.normal = {0, 0, 1};
  req.plane.mmPerPixel = 0.1;
  req.plane.origin = preview.grid().patientFromIndex.transformPoint(q) - Vec3{0.05, 0.05, 0};
  return preview.slice(req).hu.at(0);
}

// The slices of a series being retrieved appear in the preview as their files land, at the
// place the server's listing gives them, with the values the import reads; the others stay
// empty (NaN), never interpolated. The grid is the import's (a tilted stack: a shear), a slice
// listed with another orientation stays out, and the import starts once the retrieval is
// complete.
TEST(ViewerDataset, AnIncomingSeriesShowsEachSliceAsItLands) {
  const auto dir = test::freshTempDir("viewer_incoming");
  dicom::SyntheticSeriesSpec spec;
  spec.rows = 24;
  spec.columns = 20;
  spec.sliceCount = 12;
  spec.tiltDegrees = 15;
  spec.reverseFileOrder = true;
  const dicom::SyntheticSeries written = dicom::writeSyntheticSeries(dir / "source", spec);
  auto incoming = listingOf(written, dir / "incoming");
  // A coronal image listed in the series (a scout that is not marked LOCALIZER): it lands
  // first, and the preview takes its grid from the next file, an axial slice.
  dicom::SyntheticSeriesSpec scoutSpec;
  scoutSpec.sliceCount = 1;
  scoutSpec.columnDirection = {0, 0, -1};
  scoutSpec.seed = 7;
  const dicom::SyntheticSeries scout = dicom::writeSyntheticSeries(dir / "scout", scoutSpec);
  const Vec3 sp = scout.slices().front().positionMm;
  incoming->slices.push_back({dir / "incoming/scout.dcm", std::array<double, 3>{sp.x, sp.y, sp.z},
                              std::array<double, 6>{1, 0, 0, 0, 0, -1}});
  Dataset dataset(incoming, dir / "cache");
  EXPECT_EQ(dataset.state(), Dataset::State::Importing);
  EXPECT_EQ(dataset.preview(), nullptr);  // nothing has landed
  land(scout.slices().front().path, incoming->slices.back().file);
  ASSERT_TRUE(waitFor([&] { return dataset.status() == "retrieving 1/13 slices"; })) << dataset.status();
  EXPECT_EQ(dataset.preview(), nullptr);

  for (std::size_t s = 0; s < 5; ++s) land(dir / "source" / incoming->slices[s].file.filename(), incoming->slices[s].file);
  ASSERT_TRUE(waitFor([&] { return dataset.preview() && dataset.preview()->fraction() >= 5.0 / 12; }))
      << dataset.status() << " " << ::testing::PrintToString(dataset.warnings());
  EXPECT_EQ(dataset.state(), Dataset::State::Importing);
  EXPECT_NE(dataset.status().find("retrieving"), std::string::npos) << dataset.status();
  const PreviewVolume& preview = *dataset.preview();
  EXPECT_DOUBLE_EQ(preview.fraction(), 5.0 / 12);

  // The grid is the one the import of the whole series makes.
  auto source = openVolume((dir / "source").string());
  const VolumeInfo& info = source->info();
  ASSERT_EQ(preview.grid().dims, info.dims);
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 4; ++c) EXPECT_NEAR(preview.grid().patientFromIndex.m[r][c], info.patientFromIndex.m[r][c], 1e-6);
  }
  // Landed slices hold the import's values (between two landed slices: their interpolation).
  std::vector<float> slab(static_cast<std::size_t>(info.sliceSamples() * info.dims[2]));
  source->readSlab(0, info.dims[2], slab);
  auto value = [&](int64_t i, int64_t j, int64_t k) {
    return static_cast<double>(slab[static_cast<std::size_t>((k * info.dims[1] + j) * info.dims[0] + i)]);
  };
  for (int64_t k = 0; k < 4; ++k) {
    for (const auto& [i, j] : {std::pair{3, 5}, std::pair{10, 17}, std::pair{19, 0}}) {
      EXPECT_NEAR(previewAt(preview, {static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)}), value(i, j, k), 1e-3)
          << i << "," << j << "," << k;
    }
    const double half = previewAt(preview, {7, 9, k + 0.5});
    EXPECT_NEAR(half, 0.5 * (value(7, 9, k) + value(7, 9, k + 1)), 1e-3);
  }
  // Slices not landed yet are empty, and so is the gap between the last landed one and them.
  EXPECT_TRUE(std::isnan(previewAt(preview, {7, 9, 4.5})));
  EXPECT_TRUE(std::isnan(previewAt(preview, {7, 9, 8})));
  EXPECT_TRUE(std::isnan(previewAt(preview, {7, 9, 11})));

  // The last slice lands before the middle ones: it shows alone.
  land(dir / "source" / incoming->slices[11].file.filename(), incoming->slices[11].file);
  ASSERT_TRUE(waitFor([&] { return preview.fraction() >= 6.0 / 12; }));
  EXPECT_TRUE(std::isnan(previewAt(preview, {7, 9, 10.5})));
  EXPECT_NEAR(previewAt(preview, {7, 9, 11}), value(7, 9, 11), 1e-3);

  // The rest arrives; the retrieval says it is complete; the import runs and reuses nothing.
  for (std::size_t s = 5; s < 11; ++s) land(dir / "source" / incoming->slices[s].file.filename(), incoming->slices[s].file);
  EXPECT_TRUE(dataset.warnings().empty()) << ::testing::PrintToString(dataset.warnings());
  EXPECT_EQ(dataset.state(), Dataset::State::Importing);  // not before the retrieval ends
  incoming->state = IncomingSeries::State::Complete;
  ASSERT_TRUE(waitFor([&] { return dataset.state() != Dataset::State::Importing; }, 120)) << dataset.status();
  ASSERT_EQ(dataset.state(), Dataset::State::Ready) << dataset.error();
  EXPECT_DOUBLE_EQ(preview.fraction(), 1.0);
  ASSERT_NE(dataset.store(), nullptr);
  EXPECT_EQ(dataset.store()->header().dims[2], 12);
}

// The display windows of a series arriving from a PACS: the first landed file's while it
// arrives (all the preview has), the import's (most slices' choice) once it is ready.
TEST(ViewerDataset, AnIncomingSeriesNamesItsFirstFilesWindowsUntilImported) {
  const auto dir = test::freshTempDir("viewer_incoming_windows");
  dicom::SyntheticSeriesSpec spec;
  spec.rows = 16;
  spec.columns = 16;
  spec.sliceCount = 6;
  const dicom::SyntheticSeries written = dicom::writeSyntheticSeries(dir / "source", spec);
  auto incoming = listingOf(written, dir / "incoming");
  const auto sourceOf = [&](std::size_t s) { return dir / "source" / incoming->slices[s].file.filename(); };
  for (std::size_t s = 0; s < 2; ++s) {  // the first two to land name a lung window
    test::rewriteDicomStrings(sourceOf(s), {{{0x0028, 0x1050}, "-600"}, {{0x0028, 0x1051}, "1500"},
                                            {{0x0028, 0x1055}, "LUNG"}});
  }
  Dataset dataset(incoming, dir / "cache");
  EXPECT_TRUE(dataset.windows().empty());  // nothing has landed
  land(sourceOf(0), incoming->slices[0].file);
  ASSERT_TRUE(waitFor([&] { return dataset.preview() != nullptr; })) << dataset.status();
  std::vector<SourceWindow> windows = dataset.windows();
  ASSERT_EQ(windows.size(), 1u);
  EXPECT_EQ(windows[0].center, -600);
  EXPECT_EQ(windows[0].width, 1500);
  EXPECT_EQ(windows[0].explanation, "LUNG");
  for (std::size_t s = 1; s < 6; ++s) land(sourceOf(s), incoming->slices[s].file);
  incoming->state = IncomingSeries::State::Complete;
  ASSERT_TRUE(waitFor([&] { return dataset.state() != Dataset::State::Importing; }, 120)) << dataset.status();
  ASSERT_EQ(dataset.state(), Dataset::State::Ready) << dataset.error();
  windows = dataset.windows();
  ASSERT_EQ(windows.size(), 1u);
  EXPECT_EQ(windows[0].center, 40);  // octoray-sample-series' window, in four of the six
  EXPECT_EQ(windows[0].width, 400);
  EXPECT_EQ(windows[0].explanation, "");
  // The store keeps it: opened as a store, the same.
  const Dataset store(dataset.storePath(), dir / "cache");
  ASSERT_EQ(store.windows().size(), 1u);
  EXPECT_EQ(store.windows()[0].width, 400);
}

// The listings that give no grid say why, by the import's rules; a file of another
// orientation does not end the attempt.
TEST(ViewerDataset, IncomingGridFollowsTheImportsRules) {
  const auto dir = test::freshTempDir("viewer_incoming_rules");
  dicom::SyntheticSeriesSpec spec;
  spec.sliceCount = 4;
  const dicom::SyntheticSeries written = dicom::writeSyntheticSeries(dir / "source", spec);
  const VolumeInfo one = openVolume(written.slices().front().path.string())->info();
  auto grid = [&](const std::vector<double>& zs, std::string& why, bool& listingFails) {
    IncomingSeries s;
    for (double z : zs) s.slices.push_back({"x.dcm", std::array<double, 3>{-3.75, -3.75, z}, std::array<double, 6>{1, 0, 0, 0, 1, 0}});
    return incomingGrid(s, one, why, listingFails);
  };
  std::string why;
  bool listingFails = false;
  EXPECT_TRUE(grid({0, 1.25, 2.5, 3.75}, why, listingFails).has_value()) << why;
  // DS strings round positions: gaps within max(5 um, 0.1 %) are even, as resolveStack has it.
  EXPECT_TRUE(grid({0, 1.25, 2.502, 3.75}, why, listingFails).has_value()) << why;
  EXPECT_FALSE(grid({0, 1.25, 2.51, 3.75}, why, listingFails).has_value());
  EXPECT_TRUE(listingFails);
  EXPECT_EQ(why, "the slices are not evenly spaced (gaps 1.240 to 1.260 mm): the import resamples them");
  EXPECT_FALSE(grid({0, 1.25, 1.25, 2.5}, why, listingFails).has_value());
  EXPECT_EQ(why, "two instances share a slice position (the import keeps one)");
  IncomingSeries unplaced;
  unplaced.slices.push_back({"x.dcm", std::nullopt, std::nullopt});
  EXPECT_FALSE(incomingGrid(unplaced, one, why, listingFails).has_value());
  EXPECT_EQ(why, "the PACS did not list the slices' positions");
  // A listing of sagittal slices, and an axial file: the file is the odd one, not the listing.
  IncomingSeries sagittal;
  for (double x : {0.0, 1.0, 2.0}) {
    sagittal.slices.push_back({"x.dcm", std::array<double, 3>{x, 0, 0}, std::array<double, 6>{0, 1, 0, 0, 0, -1}});
  }
  EXPECT_FALSE(incomingGrid(sagittal, one, why, listingFails).has_value());
  EXPECT_FALSE(listingFails);
}

// Slices added one by one, in any order, to a downsampled preview give the box filter that
// fill() gives reading the volume in order.
TEST(ViewerPreview, SlicesAddedOutOfOrderEqualTheFilledPreview) {
  test::MemoryVolume volume({41, 30, 21}, [](int64_t i, int64_t j, int64_t k) {
    return static_cast<float>(std::sin(0.3 * i) * 100 + j * j - 7 * k);
  });
  const uint64_t budget = 41 * 30 * 21 * 4 / 4;  // factor 2
  PreviewVolume filled(volume.info(), budget), added(volume.info(), budget);
  ASSERT_EQ(added.factor(), 2);
  std::atomic<bool> cancel{false};
  filled.fill(volume, cancel);
  std::vector<float> slice(41 * 30);
  for (int64_t k : {20, 3, 0, 19, 2, 1, 4}) {
    volume.readSlab(k, 1, slice);
    added.addSlice(k, slice);
  }
  // Preview slices 0, 1 (sources 0-3) and 10 (source 20, the last, alone) are complete; 2 lacks 5.
  EXPECT_NEAR(added.fraction(), 3.0 / 11, 1e-12);
  Session s;
  s.crosshair = filled.grid().centre();
  SliceRequest req;
  req.plane = mprPlane(ViewId::Sagittal, s, filled.grid(), 64, 64);
  const Slice a = filled.slice(req), b = added.slice(req);
  int compared = 0, empty = 0;
  for (std::size_t p = 0; p < a.hu.size(); ++p) {
    if (std::isnan(b.hu[p])) {
      ++empty;
      continue;
    }
    EXPECT_NEAR(b.hu[p], a.hu[p], 1e-3) << p;
    ++compared;
  }
  EXPECT_GT(compared, 100);
  EXPECT_GT(empty, 100);
  for (int64_t k = 5; k < 19; ++k) {
    volume.readSlab(k, 1, slice);
    added.addSlice(k, slice);
  }
  EXPECT_DOUBLE_EQ(added.fraction(), 1.0);
  const Slice c = added.slice(req);
  for (std::size_t p = 0; p < a.hu.size(); ++p) {
    if (!std::isnan(a.hu[p])) {
      EXPECT_NEAR(c.hu[p], a.hu[p], 1e-3) << p;
    }
  }
}

// A retrieval that fails is the dataset's error.
TEST(ViewerDataset, AnIncomingSeriesThatFailsSaysSo) {
  const auto dir = test::freshTempDir("viewer_incoming_bad");
  dicom::SyntheticSeriesSpec spec;
  spec.sliceDistancesMm = {0, 1, 2, 4, 5};
  const dicom::SyntheticSeries written = dicom::writeSyntheticSeries(dir / "source", spec);
  auto incoming = listingOf(written, dir / "incoming");
  Dataset dataset(incoming, dir / "cache");
  land(dir / "source" / incoming->slices[0].file.filename(), incoming->slices[0].file);
  ASSERT_TRUE(waitFor([&] { return !dataset.warnings().empty(); })) << dataset.status();
  EXPECT_EQ(dataset.warnings().front(),
            "no preview while the series arrives: the slices are not evenly spaced (gaps 1.000 to 2.000 mm): the import "
            "resamples them");
  EXPECT_EQ(dataset.preview(), nullptr);
  incoming->fail("dicom://PACS@127.0.0.1:4242: the association was aborted");
  ASSERT_TRUE(waitFor([&] { return dataset.state() != Dataset::State::Importing; }));
  EXPECT_EQ(dataset.state(), Dataset::State::Failed);
  EXPECT_NE(dataset.error().find("the association was aborted"), std::string::npos) << dataset.error();
  EXPECT_NE(dataset.error().find((dir / "incoming").string()), std::string::npos) << dataset.error();
}

}  // namespace
}  // namespace octoray::viewer
