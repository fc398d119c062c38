// The viewer's library without a window: the session JSON, scripts, MPR planes and slices
// over a store's bricks (against a volume whose values are a known linear function of the
// index, which trilinear interpolation and the octree's box filter both reproduce exactly),
// slabs, window/level, presets and measurements, and the import preview's slices and histogram
// (unit_viewer_dataset.cpp: opening and importing datasets, series arriving from a PACS).
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <thread>
#include <limits>
#include <numbers>
#include <random>

#include "memory_volume.h"
#include "octoray/core/error.h"
#include "octoray/transfer/transfer_function_io.h"
#include "octoray/viewer/dataset.h"
#include "octoray/viewer/measure.h"
#include "octoray/viewer/mpr.h"
#include "octoray/viewer/presets.h"
#include "octoray/viewer/script.h"
#include "octoray/viewer/session.h"
#include "octoray/volume/store_builder.h"
#include "test_paths.h"

namespace octoray::viewer {
namespace {

using nlohmann::json;

double linear(Vec3 q) { return q.x + 2 * q.y + 3 * q.z + 100; }

std::string buildLinearStore(const std::string& name, int border = 1) {
  const auto dir = test::freshTempDir(name);
  test::MemoryVolume volume({70, 60, 40}, [](int64_t i, int64_t j, int64_t k) {
    return static_cast<float>(linear({static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)}));
  });
  const std::string path = (dir / "linear.octoray").string();
  volume::BuildOptions options;
  options.brickSize = 16;
  options.border = border;
  volume::buildStore(volume, path, options);
  return path;
}

Session sessionFor(const Grid& grid) {
  Session s;
  s.tf = transfer::findPreset("bone");
  s.crosshair = grid.centre();
  return s;
}

// Slices until complete, letting the loader bring the bricks in between.
Slice sliceUntilComplete(StoreSlicer& slicer, const SliceRequest& req, Slice* first = nullptr) {
  for (int attempt = 0; attempt < 200; ++attempt) {
    slicer.beginFrame();
    Slice s = slicer.slice(req);
    slicer.endFrame();
    if (attempt == 0 && first) *first = s;
    if (s.complete()) return s;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
    slicer.bricksArrived();
  }
  ADD_FAILURE() << "slice never completed";
  return {};
}

TEST(ViewerMpr, StandardPlanesFollowTheRadiologicalConvention) {
  Vec3 r, d, n;
  viewAxes(ViewId::Axial, Mat4::identity(), r, d, n);
  EXPECT_EQ(orientationLabel(r), "L");  // patient's left on the screen's right
  EXPECT_EQ(orientationLabel(d), "P");  // anterior at the top
  EXPECT_EQ(orientationLabel(n), "S");
  viewAxes(ViewId::Coronal, Mat4::identity(), r, d, n);
  EXPECT_EQ(orientationLabel(r), "L");
  EXPECT_EQ(orientationLabel(d), "I");
  viewAxes(ViewId::Sagittal, Mat4::identity(), r, d, n);
  EXPECT_EQ(orientationLabel(r), "P");
  EXPECT_EQ(orientationLabel(-1.0 * r), "A");
  EXPECT_EQ(orientationLabel(d), "I");
  EXPECT_EQ(orientationLabel(normalize(Vec3{1, -0.5, 0})), "LA");
}

TEST(ViewerMpr, PlanePassesThroughTheCrosshairAndFitsTheVolume) {
  const Grid grid({100, 80, 50}, Mat4::fromColumns({0.5, 0, 0}, {0, 0.5, 0}, {0, 0.3, 2.0}, {-20, 10, 300}));
  Session s;
  s.crosshair = grid.centre() + Vec3{3, -4, 7};
  for (ViewId v : {ViewId::Axial, ViewId::Coronal, ViewId::Sagittal}) {
    const MprPlane p = mprPlane(v, s, grid, 400, 300);
    EXPECT_NEAR(dot(s.crosshair - p.origin, p.normal), 0.0, 1e-9) << viewName(v);
    const double fit = std::max(grid.extentAlong(p.right) / 400, grid.extentAlong(p.down) / 300);
    EXPECT_NEAR(p.mmPerPixel, fit, 1e-12) << viewName(v);
    // pixelOf inverts at().
    const auto px = p.pixelOf(p.at(123.25, 77.5));
    EXPECT_NEAR(px[0], 123.25, 1e-9);
    EXPECT_NEAR(px[1], 77.5, 1e-9);
  }
  // Zoom 2 halves the pixel size; pan moves the view centre along the screen axes.
  s.mprViews[0] = {2.0, 10.0, -5.0};
  const MprPlane zoomed = mprPlane(ViewId::Axial, s, grid, 400, 300);
  Session unzoomed;
  unzoomed.crosshair = s.crosshair;
  const MprPlane plain = mprPlane(ViewId::Axial, unzoomed, grid, 400, 300);
  EXPECT_NEAR(zoomed.mmPerPixel, 0.5 * plain.mmPerPixel, 1e-12);
  const Vec3 shift = zoomed.at(200, 150) - plain.at(200, 150);
  EXPECT_NEAR(shift.x, 10.0, 1e-9);
  EXPECT_NEAR(shift.y, -5.0, 1e-9);
  // The slice step along the axial normal of a sheared (tilted) grid is the k axis' z step.
  EXPECT_NEAR(grid.sliceStepMm({0, 0, 1}), 2.0, 1e-12);
}

TEST(ViewerMpr, WindowGreyIsDicomLinearVoi) {
  const WindowLevel wl{80, 40};
  EXPECT_EQ(windowGrey(0.0, wl), 0);    // c - 0.5 - (w - 1) / 2 = 0
  EXPECT_EQ(windowGrey(79.0, wl), 255);  // just below c - 0.5 + (w - 1) / 2 = 79 is still in
  EXPECT_EQ(windowGrey(79.5, wl), 255);
  EXPECT_EQ(windowGrey(40.0, wl), 129);  // ((40 - 39.5) / 79 + 0.5) * 255 = 129.1
  EXPECT_EQ(windowGrey(std::nan(""), wl), 0);
  EXPECT_LT(windowGrey(20.0, wl), windowGrey(60.0, wl));
  // LINEAR takes a window below 1 as 1: a step at level - 0.5, so every value of [0.1, 0.5]
  // is white.
  EXPECT_EQ(windowGrey(-0.3, WindowLevel{0.4, 0.3}), 0);
  EXPECT_EQ(windowGrey(0.1, WindowLevel{0.4, 0.3}), 255);
}

// LINEAR_EXACT (PS3.3 C.11.2.1.3.2): level +- window / 2 mapped linearly, for any window above
// 0; what a volume whose values are not integers is shown with.
TEST(ViewerMpr, WindowGreyLinearExactTakesAnyPositiveWindow) {
  const WindowLevel wl{0.4, 0.3};  // [0.1, 0.5]
  const VoiFunction exact = VoiFunction::LinearExact;
  EXPECT_EQ(windowGrey(0.1, wl, exact), 0);
  EXPECT_EQ(windowGrey(0.5, wl, exact), 255);
  EXPECT_EQ(windowGrey(0.7, wl, exact), 255);
  EXPECT_EQ(windowGrey(0.3, wl, exact), 128);  // (0 / 0.4 + 0.5) * 255 = 127.5, half up
  EXPECT_EQ(windowGrey(0.2, wl, exact), 64);   // (-0.1 / 0.4 + 0.5) * 255 = 63.75
  EXPECT_EQ(windowGrey(std::nan(""), wl, exact), 0);
  // CT's window, exact: 40 +- 40 HU.
  EXPECT_EQ(windowGrey(0.0, WindowLevel{80, 40}, exact), 0);
  EXPECT_EQ(windowGrey(60.0, WindowLevel{80, 40}, exact), 191);  // 0.75 * 255 = 191.25
}

// SIGMOID (PS3.3 C.11.2.1.3.1): 255 / (1 + exp(-4 (x - level) / window)), rounded; level
// mid-grey, no clipping at level +- window/2.
TEST(ViewerMpr, WindowGreySigmoidRollsOffInsteadOfClipping) {
  const WindowLevel wl{80, 40};
  const VoiFunction sigmoid = VoiFunction::Sigmoid;
  EXPECT_EQ(windowGrey(40.0, wl, sigmoid), 128);   // 127.5, half up
  EXPECT_EQ(windowGrey(80.0, wl, sigmoid), 225);   // 255 / (1 + e^-2) = 224.60
  EXPECT_EQ(windowGrey(0.0, wl, sigmoid), 30);     // 255 / (1 + e^2) = 30.40
  EXPECT_EQ(windowGrey(60.0, wl, sigmoid), 186);   // 255 / (1 + e^-1) = 186.42
  EXPECT_EQ(windowGrey(-1000.0, wl, sigmoid), 0);  // e^50: 255 / huge
  EXPECT_EQ(windowGrey(3000.0, wl, sigmoid), 255);
  EXPECT_EQ(windowGrey(std::nan(""), wl, sigmoid), 0);
  // Where LINEAR clips at level +- window/2, SIGMOID still separates values beyond it.
  EXPECT_EQ(windowGrey(80.0, wl), 255);
  EXPECT_EQ(windowGrey(100.0, wl), 255);
  EXPECT_LT(windowGrey(80.0, wl, sigmoid), windowGrey(100.0, wl, sigmoid));
  EXPECT_STREQ(voiFunctionName(sigmoid), "SIGMOID");
  // The volume's function: the one its file declares, else by its values.
  EXPECT_EQ(voiFunction("SIGMOID", true), VoiFunction::Sigmoid);
  EXPECT_EQ(voiFunction("SIGMOID", false), VoiFunction::Sigmoid);
  EXPECT_EQ(voiFunction("LINEAR_EXACT", true), VoiFunction::LinearExact);
  EXPECT_EQ(voiFunction("", true), VoiFunction::Linear);
  EXPECT_EQ(voiFunction("", false), VoiFunction::LinearExact);
  EXPECT_STREQ(voiFunctionName(VoiFunction::LinearExact), "LINEAR_EXACT");
  EXPECT_STREQ(voiFunctionName(VoiFunction::Linear), "LINEAR");
}

TEST(ViewerMpr, SlicesOfALinearVolumeAreExactAndNeverBlankWhileLoading) {
  const std::string path = buildLinearStore("viewer-linear");
  const volume::StoreReader store(path);
  volume::BrickCache cache(256u << 20);
  StoreSlicer slicer(store, cache);
  const Grid& grid = slicer.grid();
  Session s = sessionFor(grid);
  s.mprRotation = Mat4::fromColumns(normalize({1, 0.2, 0}), normalize(cross({0, 0, 1}, normalize({1, 0.2, 0}))), {0, 0, 1}, {});
  for (ViewId v : {ViewId::Axial, ViewId::Coronal, ViewId::Sagittal}) {
    SliceRequest req;
    req.plane = mprPlane(v, s, grid, 96, 80);
    req.level = store.layout().leafLevel();
    Slice first;
    const Slice slice = sliceUntilComplete(slicer, req, &first);
    ASSERT_EQ(slice.hu.size(), 96u * 80u);
    int inside = 0;
    for (int y = 0; y < 80; ++y) {
      for (int x = 0; x < 96; ++x) {
        const Vec3 q = grid.indexFromPatient.transformPoint(req.plane.at(x + 0.5, y + 0.5));
        const bool in = q.x >= -0.5 && q.y >= -0.5 && q.z >= -0.5 && q.x <= 69.5 && q.y <= 59.5 && q.z <= 39.5;
        const float value = slice.hu[static_cast<std::size_t>(y * 96 + x)];
        if (!in) {
          EXPECT_TRUE(std::isnan(value));
          continue;
        }
        ++inside;
        // Inside the sample grid the interpolant is the linear function itself; in the half
        // voxel beyond the outermost samples, the edge value is held.
        const Vec3 c{std::clamp(q.x, 0.0, 69.0), std::clamp(q.y, 0.0, 59.0), std::clamp(q.z, 0.0, 39.0)};
        ASSERT_NEAR(value, linear(c), 2e-3) << viewName(v) << " pixel " << x << "," << y;
        // The first, partly loaded slice already shows data everywhere inside.
        EXPECT_FALSE(std::isnan(first.hu[static_cast<std::size_t>(y * 96 + x)]));
      }
    }
    EXPECT_GT(inside, 1000) << viewName(v);
  }
}

TEST(ViewerMpr, SlabModesCombineAlongTheNormal) {
  const std::string path = buildLinearStore("viewer-slab");
  const volume::StoreReader store(path);
  volume::BrickCache cache(256u << 20);
  StoreSlicer slicer(store, cache);
  const Grid& grid = slicer.grid();
  Session s = sessionFor(grid);
  SliceRequest req;
  req.plane = mprPlane(ViewId::Axial, s, grid, 64, 64);
  req.level = store.layout().leafLevel();
  const Slice centre = sliceUntilComplete(slicer, req);
  req.slabMm = 8;  // 4 slices of 2 mm; the value grows along +z, so MIP is the top sample
  req.slab = SlabMode::Mip;
  const Slice mip = sliceUntilComplete(slicer, req);
  req.slab = SlabMode::MinIp;
  const Slice minip = sliceUntilComplete(slicer, req);
  req.slab = SlabMode::Mean;
  const Slice mean = sliceUntilComplete(slicer, req);
  const int n = mip.slabSamples;
  EXPECT_GE(n, 16);  // at most half the smallest spacing apart
  // Along the axial normal the sheared k axis moves 2 mm per slice, the index grows 1/2 per
  // mm in k, so the linear value changes by 3 * 0.5 = 1.5 per mm (and y by -0.1*... via j).
  const std::size_t p = 32 * 64 + 32;
  const Vec3 q0 = grid.indexFromPatient.transformPoint(req.plane.at(32.5, 32.5));
  const Vec3 qTop = grid.indexFromPatient.transformPoint(req.plane.at(32.5, 32.5) + (4.0 - 4.0 / n) * req.plane.normal);
  const Vec3 qBottom = grid.indexFromPatient.transformPoint(req.plane.at(32.5, 32.5) - (4.0 - 4.0 / n) * req.plane.normal);
  EXPECT_NEAR(centre.hu[p], linear(q0), 2e-3);
  EXPECT_NEAR(mip.hu[p], std::max(linear(qTop), linear(qBottom)), 2e-3);
  EXPECT_NEAR(minip.hu[p], std::min(linear(qTop), linear(qBottom)), 2e-3);
  EXPECT_NEAR(mean.hu[p], linear(q0), 2e-3);  // symmetric samples of a linear function
}

TEST(ViewerMpr, TargetLevelFollowsThePixelSize) {
  const std::string path = buildLinearStore("viewer-level");
  const volume::StoreReader store(path);
  volume::BrickCache cache(64u << 20);
  StoreSlicer slicer(store, cache);
  const int leaf = store.layout().leafLevel();
  EXPECT_EQ(slicer.targetLevel(0.1), leaf);
  EXPECT_EQ(slicer.targetLevel(4.0), leaf);      // largest spacing 2.0025 mm: 4.005 mm one level up
  EXPECT_EQ(slicer.targetLevel(4.1), leaf - 1);  // the next level's 4.005 mm voxels fit a 4.1 mm pixel
  EXPECT_EQ(slicer.targetLevel(1e6), 0);
}

TEST(ViewerPreview, PreviewSlicesEqualTheSource) {
  test::MemoryVolume volume({40, 30, 20}, [](int64_t i, int64_t j, int64_t k) {
    return static_cast<float>(linear({static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)}));
  });
  PreviewVolume preview(volume.info(), 64u << 20);
  EXPECT_EQ(preview.factor(), 1);
  std::atomic<bool> cancel{false};
  preview.fill(volume, cancel);
  EXPECT_DOUBLE_EQ(preview.fraction(), 1.0);
  Session s;
  s.crosshair = preview.grid().centre();
  SliceRequest req;
  req.plane = mprPlane(ViewId::Coronal, s, preview.grid(), 50, 40);
  const Slice slice = preview.slice(req);
  const Vec3 q = preview.grid().indexFromPatient.transformPoint(req.plane.at(25.5, 20.5));
  EXPECT_NEAR(slice.hu[20 * 50 + 25], linear(q), 1e-3);
  // A budget too small for the full volume halves the resolution.
  PreviewVolume small(volume.info(), 40 * 30 * 20 * 4 / 4);
  EXPECT_EQ(small.factor(), 2);
}

// The preview's histogram, read while a volume arrives, reads at most 4 Mi samples: all of
// the slices shown where they hold fewer, every n-th row in order where they hold more; the
// auto window it gives is within a bin of the exact one.
TEST(ViewerPreview, HistogramReadsAtMostItsBudgetOfSamples) {
  const std::array<int64_t, 3> dims{256, 256, 80};  // 5.2 Mi samples
  auto value = [](int64_t i, int64_t j, int64_t k) { return static_cast<float>(i + j + 3 * k); };
  test::MemoryVolume volume(dims, value);
  PreviewVolume preview(volume.info(), 64u << 20);
  ASSERT_EQ(preview.factor(), 1);
  // The exact histogram of slices [0, slices), over the same range the preview finds.
  auto exact = [&](int64_t slices, double lo, double hi) {
    std::vector<int> counts(256, 0);
    for (int64_t k = 0; k < slices; ++k) {
      for (int64_t j = 0; j < dims[1]; ++j) {
        for (int64_t i = 0; i < dims[0]; ++i) {
          ++counts[static_cast<std::size_t>(std::clamp(static_cast<int>((value(i, j, k) - lo) / (hi - lo) * 256), 0, 255))];
        }
      }
    }
    return counts;
  };
  std::vector<float> slice(static_cast<std::size_t>(dims[0] * dims[1]));
  auto add = [&](int64_t k) {
    for (int64_t j = 0; j < dims[1]; ++j) {
      for (int64_t i = 0; i < dims[0]; ++i) slice[static_cast<std::size_t>(j * dims[0] + i)] = value(i, j, k);
    }
    preview.addSlice(k, slice);
  };
  // Half the slices: 2.6 Mi samples, all read.
  for (int64_t k = 0; k < 40; ++k) add(k);
  double lo = 0, hi = 0;
  std::vector<int> counts = preview.histogram(256, lo, hi);
  EXPECT_EQ(lo, 0);
  EXPECT_EQ(hi, 255 + 255 + 3 * 39);
  EXPECT_EQ(counts, exact(40, lo, hi));
  // All of them: every second row, 2.6 Mi samples of 5.2 Mi.
  for (int64_t k = 40; k < dims[2]; ++k) add(k);
  counts = preview.histogram(256, lo, hi);
  int64_t read = 0;
  for (const int c : counts) read += c;
  EXPECT_EQ(read, dims[0] * dims[1] * dims[2] / 2);
  EXPECT_LE(read, static_cast<int64_t>(PreviewVolume::kHistogramSamples));
  EXPECT_EQ(lo, 0);
  EXPECT_EQ(hi, 255 + 254 + 3 * 79);  // the largest value of the even rows
  const WindowLevelPreset got = autoWindowLevel(counts, lo, hi);
  const WindowLevelPreset want = autoWindowLevel(exact(dims[2], lo, hi), lo, hi);
  const double bin = (hi - lo) / 256;
  EXPECT_NEAR(got.level - got.window / 2, want.level - want.window / 2, bin);
  EXPECT_NEAR(got.level + got.window / 2, want.level + want.window / 2, bin);
}

TEST(ViewerMeasure, DistanceAngleAndRoi) {
  Measurement d{MeasureKind::Distance, ViewId::Axial, {{0, 0, 0}, {3, 4, 0}}};
  EXPECT_DOUBLE_EQ(distanceMm(d), 5.0);
  Measurement a{MeasureKind::Angle, ViewId::Axial, {{1, 0, 0}, {0, 0, 0}, {0, 2, 0}}};
  EXPECT_NEAR(angleDegrees(a), 90.0, 1e-12);
  Measurement r{MeasureKind::Rectangle, ViewId::Axial, {{10, 10, 5}, {0, 4, 5}}};  // any corner order
  const auto pts = roiSamplePositions(r, 1.0);
  EXPECT_EQ(pts.size(), 10u * 6u);
  for (const Vec3& p : pts) {
    EXPECT_GT(p.x, 0);
    EXPECT_LT(p.x, 10);
    EXPECT_GT(p.y, 4);
    EXPECT_LT(p.y, 10);
    EXPECT_EQ(p.z, 5);
  }
  std::vector<double> values{1, 2, 3, 4, std::nan("")};
  const RoiStats st = roiStats(r, values);
  EXPECT_EQ(st.samples, 4);
  EXPECT_DOUBLE_EQ(st.mean, 2.5);
  EXPECT_DOUBLE_EQ(st.sd, std::sqrt(1.25));
  EXPECT_DOUBLE_EQ(st.areaMm2, 60.0);
  Measurement e{MeasureKind::Ellipse, ViewId::Axial, {{0, 0, 0}, {20, 10, 0}}};
  EXPECT_NEAR(roiStats(e, {}).areaMm2, std::numbers::pi * 10 * 5, 1e-9);
  const auto inside = roiSamplePositions(e, 0.5);
  EXPECT_NEAR(static_cast<double>(inside.size()) * 0.25, std::numbers::pi * 50, 3.0);
}

TEST(ViewerSession, JsonRoundTripsEveryField) {
  Session s;
  s.source = "/data/head";
  s.layout = Layout::OnePlusThree;
  s.mainView = ViewId::Coronal;
  s.tf = transfer::findPreset("lung");
  s.preset = "lung";
  s.mode = gpu::RaycastMode::Mip;
  s.isoValue = -400;
  s.lodPixels = 2;
  s.preintegration = true;
  s.wl = {1500, -600};
  s.wlPreset = "lung";
  s.crosshair = {1.5, -2.25, 700};
  s.mprRotation = Mat4::fromColumns({0, 1, 0}, {-1, 0, 0}, {0, 0, 1}, {});
  s.slab = SlabMode::Mean;
  s.slabMm = 12;
  s.mprViews[2] = {3, 4, -5};
  s.measurements.push_back({MeasureKind::Angle, ViewId::Sagittal, {{1, 2, 3}, {4, 5, 6}, {7, 8, 10}}, {0, 1, 0}, {0, 0, -1}});
  s.patientInfo = true;
  const Session back = sessionFromJson(sessionToJson(s), "s.json");
  EXPECT_EQ(sessionToJson(back), sessionToJson(s));
  EXPECT_EQ(back.measurements.at(0).points.at(2).z, 10);
  EXPECT_TRUE(back.preintegration);
}

// quality.preintegration came after version 1's first sessions: one without it still loads,
// drawn as it was (post-classified); one of the wrong type is named.
TEST(ViewerSession, PreintegrationIsOptionalAndChecked) {
  Session s;
  s.tf = transfer::findPreset("bone");
  s.preintegration = true;
  json j = sessionToJson(s);
  ASSERT_TRUE(j["quality"].contains("preintegration"));
  EXPECT_TRUE(sessionFromJson(j, "s.json").preintegration);
  j["quality"].erase("preintegration");
  EXPECT_FALSE(sessionFromJson(j, "old.json").preintegration);
  j["quality"]["preintegration"] = "yes";
  try {
    sessionFromJson(j, "bad.json");
    ADD_FAILURE() << "accepted a string";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("quality.preintegration"), std::string::npos) << e.what();
  }
}

TEST(ViewerSession, BadFieldsAreNamed) {
  Session base;
  base.tf = transfer::findPreset("bone");
  const json good = sessionToJson(base);
  auto expectError = [&](json j, const std::string& field) {
    try {
      sessionFromJson(j, "bad.json");
      ADD_FAILURE() << "accepted a bad " << field;
    } catch (const Error& e) {
      EXPECT_EQ(e.path(), "bad.json");
      EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
    }
  };
  json j = good;
  j["windowLevel"]["window"] = -5;
  expectError(j, "windowLevel.window");
  j = good;
  j["mprRotation"][0] = {2, 0, 0};
  expectError(j, "mprRotation");
  j = good;
  j["surprise"] = 1;
  expectError(j, "surprise");
  j = good;
  j["layout"] = "nine-up";
  expectError(j, "layout");
  j = good;
  j["measurements"] = json::array({{{"kind", "distance"}, {"view", "axial"}, {"points", {{0, 0, 0}}},
                                    {"right", {1, 0, 0}}, {"down", {0, 1, 0}}}});
  expectError(j, "measurements[0].points");
  j = good;
  j["camera"]["eye"] = j["camera"]["target"];
  expectError(j, "camera");
}

TEST(ViewerScript, ParsesStepsAndNamesBadOnes) {
  const json script = json::parse(R"({"format": "octoray-view-script", "version": 1, "events": [
    {"type": "drag", "button": "middle", "from": [10, 20], "to": {"view": "axial", "fraction": [0.5, 0.5]}, "steps": 3},
    {"type": "key", "key": "PageUp", "wait": 0},
    {"type": "click", "at": {"view": "coronal", "patient": [1, 2, 3]}, "mods": ["shift", "ctrl"]},
    {"type": "screenshot", "path": "a.png", "view": "3d"},
    {"type": "action", "name": "layout", "value": "one-up"}]})");
  const auto steps = parseScript(script, "s.json");
  ASSERT_EQ(steps.size(), 5u);
  EXPECT_EQ(steps[0].button, MouseButton::Middle);
  EXPECT_EQ(steps[0].steps, 3);
  EXPECT_EQ(*steps[0].to.view, ViewId::Axial);
  EXPECT_EQ(steps[1].wait, 0);
  EXPECT_EQ(steps[2].mods, kShift | kCtrl);
  EXPECT_EQ(steps[2].at.patient->z, 3);
  EXPECT_EQ(*steps[3].view, ViewId::Volume);
  for (const char* bad : {R"([{"type": "teleport"}])", R"([{"type": "drag", "from": [1, 2]}])",
                          R"([{"type": "click", "at": {"view": "side", "pixel": [1, 2]}}])",
                          R"([{"type": "click", "at": {"view": "3d", "patient": [1, 2, 3]}}])",
                          R"([{"type": "key"}])", R"([{"type": "move", "at": [1, 2], "colour": 1}])",
                          R"([{"type": "screenshot", "path": "a.png", "patientInfo": 1}])"}) {
    try {
      parseScript(json::parse(bad), "s.json");
      ADD_FAILURE() << "accepted " << bad;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("s.json: script step 0"), std::string::npos) << e.what();
    }
  }
}

// Fields of the wrong type are named, never a JSON type error (fuzz/regressions/fuzz_json_documents).
TEST(ViewerScript, AFormatOfTheWrongTypeIsRefusedByName) {
  for (const char* bad : {R"({"format": ["octoray-view-script"], "events": []})", R"({"format": 1, "events": []})"}) {
    try {
      parseScript(json::parse(bad), "s.json");
      ADD_FAILURE() << "accepted " << bad;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("s.json: expected {\"format\": \"octoray-view-script\""), std::string::npos)
          << e.what();
    }
  }
}

TEST(ViewerPresets, ShippedTableHasKeysOneToNineWithSources) {
  const auto presets = loadWindowLevelPresets(defaultWindowLevelPresetsPath());
  ASSERT_EQ(presets.size(), 9u);
  for (std::size_t i = 0; i < presets.size(); ++i) {
    EXPECT_EQ(presets[i].key, static_cast<int>(i) + 1);
    EXPECT_FALSE(presets[i].source.empty()) << presets[i].name;
  }
  EXPECT_EQ(presets[0].name, "brain");
  EXPECT_EQ(presets[0].window, 80);
  EXPECT_EQ(presets[0].level, 40);
}

// A preset table with a field of the wrong type is refused by name (a "source" of 6 escaped
// as a JSON type error before: fuzz/regressions/fuzz_json_documents).
TEST(ViewerPresets, FieldsOfTheWrongTypeAreRefusedByName) {
  const auto dir = test::freshTempDir("wl_presets");
  const auto load = [&](const std::string& preset, const std::string& format = "\"octoray-window-level-presets\"") {
    const auto path = dir / "presets.json";
    std::ofstream(path) << "{\"format\": " << format << ", \"presets\": [" << preset << "]}";
    return loadWindowLevelPresets(path);
  };
  EXPECT_EQ(load(R"({"name": "a", "window": 80, "level": 40, "key": 3, "source": "s"})").front().key, 3);
  EXPECT_EQ(load(R"({"name": "a", "window": 80, "level": 40})").front().source, "");
  const auto refused = [&](const std::string& preset, const std::string& what, const std::string& format = "\"octoray-window-level-presets\"") {
    try {
      load(preset, format);
      ADD_FAILURE() << "accepted " << preset;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("presets.json"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
    }
  };
  refused(R"({"name": "a", "window": 80, "level": 40, "source": 6})", "presets[0]: source must be a string");
  refused(R"({"name": "a", "window": 80, "level": 40, "key": "1"})", "key must be an integer");
  refused(R"({"name": "a", "window": 80, "level": 40, "key": 1.5})", "key must be an integer");
  refused(R"({"name": "a", "window": 80, "level": 40, "key": 12})",
          "key must be an integer 1-9 (or 0 for none)");
  refused(R"({"name": "a", "window": 80, "level": 40})", "expected {", "7");
}

// The windows a volume's file names become presets "file", "file 2", ... in its order, the
// window its width and the level its center, the explanation in the source; none, none.
TEST(ViewerPresets, TheFilesWindowsArePresetsInItsOrder) {
  EXPECT_TRUE(fileWindowLevelPresets({}).empty());
  const auto presets = fileWindowLevelPresets({{40, 80, "", ""}, {-600, 1500, "LUNG", ""}, {300, 1500, "BONE", ""}});
  ASSERT_EQ(presets.size(), 3u);
  EXPECT_EQ(presets[0].name, "file");
  EXPECT_EQ(presets[1].name, "file 2");
  EXPECT_EQ(presets[2].name, "file 3");
  EXPECT_EQ((presets[0].window), 80);
  EXPECT_EQ((presets[0].level), 40);
  EXPECT_EQ((presets[1].window), 1500);
  EXPECT_EQ((presets[1].level), -600);
  EXPECT_EQ(presets[0].key, 0);
  EXPECT_EQ(presets[0].source, "the file's WindowCenter / WindowWidth");
  EXPECT_EQ(presets[1].source, "the file's WindowCenter / WindowWidth: LUNG");
}

// Auto window/level: the 0.1st and 99.9th percentiles of the histogram, interpolated inside
// their bins (100 bins of width 10 over [0, 1000)).
TEST(ViewerPresets, AutoWindowLevelSpansTheMiddleOfTheValues) {
  // 10,000 values spread evenly over bins 20-69 (200-700), and 10 outliers in each of the
  // first and the last bin: 0.1 % of the 10,020 samples is 10.02, so the percentiles leave the
  // outliers out and fall 0.02 samples into the spread's end bins.
  std::vector<int> histogram(100, 0);
  for (int b = 20; b < 70; ++b) histogram[static_cast<std::size_t>(b)] = 200;
  histogram[0] = histogram[99] = 10;
  WindowLevelPreset wl = autoWindowLevel(histogram, 0, 1000);
  EXPECT_EQ(wl.name, "auto");
  EXPECT_NEAR(wl.level - 0.5 * wl.window, 200 + 10 * 0.02 / 200, 1e-9);
  EXPECT_NEAR(wl.level + 0.5 * wl.window, 700 - 10 * 0.02 / 200, 1e-9);
  // The outliers moved into the spread's end bins (210 samples each): 10.02 samples into them.
  histogram[0] = histogram[99] = 0;
  histogram[20] += 10;
  histogram[69] += 10;
  wl = autoWindowLevel(histogram, 0, 1000);
  EXPECT_NEAR(wl.level - 0.5 * wl.window, 200 + 10 * 10.02 / 210, 1e-9);
  EXPECT_NEAR(wl.level + 0.5 * wl.window, 700 - 10 * 10.02 / 210, 1e-9);
  EXPECT_NEAR(wl.level, 450, 1e-9);
  // Nearly every value in one bin (a mask's zeros; a constant volume, whose range is one
  // unit): the whole range, never zero. No samples: the whole range too.
  std::vector<int> one(256, 0);
  one[40] = 5000;
  wl = autoWindowLevel(one, -1024, 3071);
  EXPECT_EQ(wl.window, 4095);
  EXPECT_EQ(wl.level, 1023.5);
  std::vector<int> mask(256, 0);
  mask[0] = 99950;
  mask[255] = 50;
  wl = autoWindowLevel(mask, 0, 1);
  EXPECT_EQ(wl.window, 1);
  EXPECT_EQ(wl.level, 0.5);
  EXPECT_EQ(windowGrey(0, {wl.window, wl.level}), 0);
  EXPECT_EQ(windowGrey(1, {wl.window, wl.level}), 255);
  wl = autoWindowLevel(one, 7, 8);
  EXPECT_EQ(wl.window, 1);
  wl = autoWindowLevel(std::vector<int>(256, 0), 127, 2145);
  EXPECT_EQ(wl.window, 2018);
  EXPECT_EQ(wl.level, 1136);
}

// An ROI's statistics carry the volume's unit, and none where it has none (an MR series).
// Labels carry about a thousandth of the range; controls step by about a hundredth of it.
TEST(ViewerPresets, ValueLabelsAndStepsFollowTheRange) {
  EXPECT_EQ(valueDecimals(4095), 0);   // CT's HU
  EXPECT_EQ(valueDecimals(100), 0);
  EXPECT_EQ(valueDecimals(99.9), 1);
  EXPECT_EQ(valueDecimals(1), 2);
  EXPECT_EQ(valueDecimals(0.44), 3);   // values in [0, 0.44]
  EXPECT_EQ(valueDecimals(0.003), 5);  // an ADC map in mm^2/s
  EXPECT_EQ(valueDecimals(0), 0);
  EXPECT_EQ(valueDecimals(std::nan("")), 0);
  EXPECT_EQ(valueDecimals(std::numeric_limits<double>::infinity()), 0);
  EXPECT_DOUBLE_EQ(valueStep(4095), 10);
  EXPECT_DOUBLE_EQ(valueStep(0.44), 0.001);
  EXPECT_DOUBLE_EQ(valueStep(0.003), 1e-5);
  EXPECT_EQ(valueStep(-1), 1);
}

TEST(ViewerMeasure, RoiStatisticsNameTheVolumesUnitOrNone) {
  const Measurement r{MeasureKind::Rectangle, ViewId::Axial, {{0, 0, 0}, {10, 5, 0}}};
  const RoiStats st = roiStats(r, {30, 40, 50});
  EXPECT_EQ(describe(r, &st, "HU"), "mean 40.0 SD 8.2 HU, min 30 max 50, 50.0 mm\u00b2");
  EXPECT_EQ(describe(r, &st, ""), "mean 40.0 SD 8.2, min 30 max 50, 50.0 mm\u00b2");
  // Values that are not integers (here in [0, 1]) keep the decimals they need.
  const RoiStats fractions = roiStats(r, {0.125, 0.25, 0.5});
  EXPECT_EQ(describe(r, &fractions, "", 3), "mean 0.2917 SD 0.1559, min 0.125 max 0.500, 50.0 mm\u00b2");
  EXPECT_EQ(unitSuffix("HU"), " HU");
  EXPECT_EQ(unitSuffix(""), "");
}

}  // namespace
}  // namespace octoray::viewer
