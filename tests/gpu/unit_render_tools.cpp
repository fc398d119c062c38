// octoray-render and octoray-compare as a user runs them: a store and a NRRD of the same
// phantom render the same image, --json reports what was done, bad input exits 1 naming the
// file, usage errors exit 2.

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <filesystem>
#include <fstream>
#include <limits>
#include <string>
#include <utility>

#include <fmt/format.h>

#include "octoray/dicom/formats.h"
#include "octoray/gpu/image_io.h"
#include "octoray/gpu/image_metrics.h"
#include "octoray/volume/phantom.h"
#include "octoray/volume/store_builder.h"
#include "octoray/volume/store_reader.h"
#include "run_process.h"
#include "test_paths.h"

namespace octoray::test {
namespace {

std::string slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

class RenderTools : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!std::filesystem::exists(toolPath("octoray-render"))) GTEST_SKIP() << "tool not built";
    dir = freshTempDir("tools");
    volume::PhantomOptions phantom;
    phantom.dims = {40, 40, 36};
    phantom.spacingMm = {1.5, 1.5, 1.8};
    nrrd = (dir / "phantom.nhdr").string();
    volume::writePhantomNrrd(phantom, nrrd);
    store = (dir / "phantom.octoray").string();
    volume::buildStore(*volume::makePhantom(phantom), store);
  }
  std::filesystem::path dir;
  std::string nrrd, store;
};

TEST_F(RenderTools, StoreAndSourceRenderTheSameImage) {
  const std::string render = toolPath("octoray-render").string();
  const std::vector<std::string> common{"--preset",  "bone",       "--size",      "48x40",
                                        "--azimuth", "30",         "--elevation", "10",
                                        "--json",    "--reference"};
  std::vector<std::string> a{
      render, store, "-o", (dir / "a.png").string(), "--exr", (dir / "a.exr").string()};
  a.insert(a.end(), common.begin(), common.end());
  const ProcessResult ra = runProcess(a);
  ASSERT_EQ(ra.exitCode, 0) << ra.err;
  const auto report = nlohmann::json::parse(ra.out);
  EXPECT_EQ(report["width"], 48);
  EXPECT_EQ(report["height"], 40);
  EXPECT_EQ(report["renderer"], "reference");
  EXPECT_GT(report["samples"].get<int64_t>(), 0);
  EXPECT_GE(report["timingMs"]["render"].get<double>(), 0);
  EXPECT_TRUE(report["camera"].contains("eye"));

  std::vector<std::string> b{
      render, nrrd, "-o", (dir / "b.png").string(), "--exr", (dir / "b.exr").string()};
  b.insert(b.end(), common.begin(), common.end());
  ASSERT_EQ(runProcess(b).exitCode, 0);
  const gpu::Image ia = gpu::readImage(dir / "a.exr");
  const gpu::Image ib = gpu::readImage(dir / "b.exr");
  EXPECT_EQ(ia.rgba, ib.rgba);
  float alphaSum = 0;
  for (std::size_t i = 3; i < ia.rgba.size(); i += 4) alphaSum += ia.rgba[i];
  EXPECT_GT(alphaSum, 48 * 40 * 0.1f) << "the phantom's skull should cover part of the image";

  const ProcessResult cmp =
      runProcess({toolPath("octoray-compare").string(), (dir / "a.png").string(),
                  (dir / "b.exr").string(), "--json"});
  ASSERT_EQ(cmp.exitCode, 0) << cmp.err;
  const auto metrics = nlohmann::json::parse(cmp.out);
  EXPECT_GT(metrics["psnrDb"].get<double>(), 40.0);
  EXPECT_EQ(metrics["nonFiniteA"], 0);
  // Images of different sizes: both named in the order given, sizes in the same order.
  gpu::Image small(8, 4);
  gpu::writePng(small, dir / "small.png");
  const ProcessResult sizes = runProcess({toolPath("octoray-compare").string(),
                                          (dir / "small.png").string(), (dir / "a.png").string()});
  EXPECT_EQ(sizes.exitCode, 1);
  EXPECT_EQ(sizes.err, fmt::format("octoray-compare: {} and {}: images differ in size: 8x4 and "
                                   "48x40\n",
                                   (dir / "small.png").string(), (dir / "a.png").string()));
}

TEST_F(RenderTools, ModesAndErrors) {
  const std::string render = toolPath("octoray-render").string();
  const std::string out = (dir / "x.png").string();
  for (const char* mode : {"iso", "mip"}) {
    const ProcessResult r = runProcess({render, nrrd, "-o", out, "--preset", "bone", "--mode", mode,
                                        "--iso", "300", "--size", "16x16", "--reference"});
    EXPECT_EQ(r.exitCode, 0) << mode << ": " << r.err;
  }
  // The reference path; the GPU path's errors are tested in unit_gl_render_tool.cpp.
  const ProcessResult missing = runProcess(
      {render, (dir / "none.nrrd").string(), "-o", out, "--preset", "bone", "--reference"});
  EXPECT_EQ(missing.exitCode, 1);
  EXPECT_NE(missing.err.find("none.nrrd"), std::string::npos) << missing.err;
  std::ofstream(dir / "bad.octoray") << "OCTORAY\x1a" << std::string(40, 'x');
  const ProcessResult bad = runProcess(
      {render, (dir / "bad.octoray").string(), "-o", out, "--preset", "bone", "--reference"});
  EXPECT_EQ(bad.exitCode, 1);
  EXPECT_NE(bad.err.find("bad.octoray"), std::string::npos) << bad.err;
  // A store damaged at its start, with no --preset: one line, the store's problem (it said
  // "not a DICOM file", after a note on the default preset).
  std::ofstream(dir / "short.octoray") << std::string(26, 'X');
  const ProcessResult shortStore =
      runProcess({render, (dir / "short.octoray").string(), "-o", out, "--reference"});
  EXPECT_EQ(shortStore.exitCode, 1);
  EXPECT_EQ(shortStore.err, "octoray-render: " + (dir / "short.octoray").string() +
                                ": header: file too short (26 bytes) to be an octoray store\n");
  // An output that cannot be written: exit 1 naming it, before rendering, and nothing left
  // behind (not the PNG, not a temporary).
  const std::string lonePng = (dir / "lone.png").string();
  const ProcessResult missingFolder = runProcess({render, nrrd, "-o", lonePng, "--exr",
                                                  "/nonexistent-octoray/x.exr", "--preset", "bone", "--reference"});
  EXPECT_EQ(missingFolder.exitCode, 1);
  EXPECT_NE(missingFolder.err.find("/nonexistent-octoray/x.exr: its folder does not exist"), std::string::npos)
      << missingFolder.err;
  EXPECT_FALSE(std::filesystem::exists(lonePng));
  for (const auto& e : std::filesystem::directory_iterator(dir)) {
    EXPECT_EQ(e.path().filename().string().find(".partial"), std::string::npos) << e.path();
  }
  // An output that is the input, the transfer function or the camera file: refused before
  // anything is written, the file intact (it was overwritten by the PNG).
  const std::string nrrdBytes = slurp(nrrd);
  const ProcessResult self = runProcess({render, nrrd, "-o", nrrd, "--preset", "bone", "--reference"});
  EXPECT_EQ(self.exitCode, 1);
  EXPECT_NE(self.err.find(nrrd + ": the output is the same file as the input " + nrrd), std::string::npos)
      << self.err;
  EXPECT_EQ(slurp(nrrd), nrrdBytes);
  const std::string tf = (dir / "tf.json").string();
  std::ofstream(tf) << R"({"format": "octoray-transfer-function", "version": 1, "transferFunctions": [
                           {"name": "ramp", "color": [[0, 1, 1, 1], [1000, 1, 1, 1]],
                            "opacity": [[0, 0], [1000, 1]]}]})";
  const std::string tfBytes = slurp(tf);
  const ProcessResult overTf = runProcess({render, nrrd, "-o", out, "--exr", tf, "--tf", tf, "--reference"});
  EXPECT_EQ(overTf.exitCode, 1);
  EXPECT_NE(overTf.err.find("the output is the same file as the input"), std::string::npos) << overTf.err;
  EXPECT_EQ(slurp(tf), tfBytes);
  // Sizes that do not fit an int are refused, not wrapped (4294967328 read as 32).
  for (const char* size : {"4294967328x4294967328", "4294967297x1", "16x16x", "x16", "16x-16", "0x16"}) {
    const ProcessResult r = runProcess({render, nrrd, "-o", out, "--preset", "bone", "--reference", "--size", size});
    EXPECT_EQ(r.exitCode, 1) << size;
    EXPECT_NE(r.err.find(std::string("--size \"") + size + "\": expected WxH, from 1x1 to 16384x16384"),
              std::string::npos)
        << r.err;
  }
  // A negative count is a usage error in words (CLI11's own check printed DBL_MAX in full).
  const ProcessResult threads = runProcess({render, nrrd, "-o", out, "--preset", "bone", "--reference", "--threads", "-1"});
  EXPECT_EQ(threads.exitCode, 2);
  EXPECT_NE(threads.err.find("--threads: must be 0 or a number above it, not -1"), std::string::npos) << threads.err;
  EXPECT_EQ(threads.err.find("1797693"), std::string::npos) << threads.err;
  // A field of view of 0: named as such (it said "camera: non-finite vector").
  const ProcessResult fov = runProcess({render, nrrd, "-o", out, "--preset", "bone", "--reference", "--fov", "0"});
  EXPECT_EQ(fov.exitCode, 1);
  EXPECT_NE(fov.err.find("field of view 0 degrees (--fov) must be in (0, 180)"), std::string::npos) << fov.err;
  // A zoom that no view can frame is named as the zoom (it said "field of view 180"): a
  // perspective field of view that would reach 180 degrees, an orthographic height that would
  // overflow.
  for (const auto& [zoom, projection] :
       {std::pair{"1e-300", "perspective"}, std::pair{"1e-310", "orthographic"}}) {
    const ProcessResult r = runProcess({render, nrrd, "-o", out, "--preset", "bone", "--reference",
                                        "--zoom", zoom, "--projection", projection});
    EXPECT_EQ(r.exitCode, 1) << zoom << " " << projection;
    EXPECT_NE(r.err.find(fmt::format("zoom {} is too small to frame the volume", zoom)),
              std::string::npos)
        << r.err;
  }
  // GPU-only options with --reference, and --gpu with --reference, are usage errors.
  EXPECT_EQ(runProcess({render, nrrd, "-o", out, "--preset", "bone", "--reference", "--lod-pixels", "2"})
                .exitCode,
            2);
  EXPECT_EQ(runProcess({render, nrrd, "-o", out, "--preset", "bone", "--reference", "--gpu"}).exitCode, 2);
  EXPECT_EQ(runProcess({render, nrrd, "-o", out, "--preset", "bone", "--mode", "x"}).exitCode, 2);
}

// Without --preset and --tf: CT gets the bone preset (DVR), a bone-coloured surface at 300 HU
// (iso) and a grey ramp (MIP), each said on stderr; other values a grey ramp over their range,
// and an isosurface at Otsu's threshold of them, as the viewer opens it.
TEST_F(RenderTools, DefaultsWithoutPresetOrTransferFunction) {
  const std::string render = toolPath("octoray-render").string();
  const std::vector<std::string> common{"--size", "48x40", "--azimuth", "30", "--reference"};
  auto run = [&](std::vector<std::string> args) {
    args.insert(args.begin(), render);
    args.insert(args.end(), common.begin(), common.end());
    return runProcess(args);
  };
  auto image = [&](const std::string& name) { return gpu::readImage(dir / name).rgba; };

  // The store says HU in its provenance and the phantom's NRRD in its 'sample units'; the same
  // NRRD without that line does not, but its values reach air.
  const std::string unlabelled = (dir / "unlabelled.nhdr").string();
  {
    std::ifstream in(nrrd);
    std::ofstream out(unlabelled);
    int dropped = 0;
    for (std::string line; std::getline(in, line);) {
      if (line == "sample units: HU") {
        ++dropped;
      } else {
        out << line << '\n';
      }
    }
    ASSERT_EQ(dropped, 1);
  }
  // A float32 store of that NRRD: its samples are floats, but its provenance says the source's
  // values were integers, so the same guess holds.
  const std::string floatStore = (dir / "unlabelled-float.octoray").string();
  {
    volume::BuildOptions options;
    options.format = volume::BuildOptions::Format::Float32;
    volume::buildStore(*openVolume(unlabelled), floatStore, options);
    ASSERT_EQ(volume::StoreReader(floatStore).sampleFormat(), volume::SampleFormat::Float32);
  }
  for (const auto& [input, says] : {std::pair{store, std::string("(CT, dvr)")},
                                    std::pair{nrrd, std::string("(CT, dvr)")},
                                    std::pair{unlabelled, std::string("look like CT")},
                                    std::pair{floatStore, std::string("look like CT")}}) {
    SCOPED_TRACE(input);
    const ProcessResult byDefault = run({input, "-o", (dir / "d.png").string(), "--exr", (dir / "d.exr").string()});
    ASSERT_EQ(byDefault.exitCode, 0) << byDefault.err;
    EXPECT_NE(byDefault.err.find("no --preset or --tf: using the bone preset"), std::string::npos) << byDefault.err;
    EXPECT_NE(byDefault.err.find(says), std::string::npos) << byDefault.err;
    ASSERT_EQ(run({input, "-o", (dir / "b.png").string(), "--exr", (dir / "b.exr").string(), "--preset", "bone"}).exitCode, 0);
    EXPECT_EQ(image("d.exr"), image("b.exr"));
  }

  const ProcessResult iso = run({store, "--mode", "iso", "-o", (dir / "i.png").string(), "--exr", (dir / "i.exr").string()});
  ASSERT_EQ(iso.exitCode, 0) << iso.err;
  EXPECT_NE(iso.err.find("no --iso: using 300 HU"), std::string::npos) << iso.err;
  EXPECT_NE(iso.err.find("bone-coloured surface"), std::string::npos) << iso.err;
  ASSERT_EQ(run({store, "--mode", "iso", "--iso", "300", "-o", (dir / "j.png").string(), "--exr", (dir / "j.exr").string()}).exitCode, 0);
  const auto surface = image("i.exr");
  EXPECT_EQ(surface, image("j.exr"));
  // Opaque where it hits, and bone-coloured: red > green > blue.
  double r = 0, g = 0, b = 0, covered = 0;
  for (std::size_t i = 0; i < surface.size(); i += 4) {
    if (surface[i + 3] < 0.99f) continue;
    r += surface[i], g += surface[i + 1], b += surface[i + 2], covered += 1;
  }
  ASSERT_GT(covered, 48 * 40 * 0.1);
  EXPECT_GT(r, g);
  EXPECT_GT(g, b);

  const ProcessResult mip = run({store, "--mode", "mip", "-o", (dir / "m.png").string(), "--exr", (dir / "m.exr").string()});
  ASSERT_EQ(mip.exitCode, 0) << mip.err;
  EXPECT_NE(mip.err.find("grey ramp from -200 HU"), std::string::npos) << mip.err;
  const auto grey = image("m.exr");
  double brightest = 0;
  for (std::size_t i = 0; i < grey.size(); i += 4) {
    EXPECT_EQ(grey[i], grey[i + 1]);
    EXPECT_EQ(grey[i], grey[i + 2]);
    brightest = std::max<double>(brightest, grey[i]);
  }
  // The brightest ray reaches about the volume's maximum, mapped by the ramp.
  const double maximum = volume::StoreReader(store).node(0).maxValue;
  const double expected = std::clamp((maximum + 200.0) / 1200.0, 0.0, 1.0);
  EXPECT_LE(brightest, expected + 1e-3);
  EXPECT_GE(brightest, expected - 0.1) << "maximum " << maximum << " HU";

  // Values that are not CT (0..200, uint8): a grey ramp over them.
  {
    std::ofstream raw(dir / "u8.raw", std::ios::binary);
    for (int i = 0; i < 32 * 32 * 32; ++i) raw.put(static_cast<char>((i * 7) % 201));
  }
  std::ofstream(dir / "u8.nhdr") << "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 32 32 32\n"
                                    "spacings: 1 1 1\nencoding: raw\ndata file: u8.raw\n";
  const ProcessResult other = run({(dir / "u8.nhdr").string(), "-o", (dir / "u.png").string()});
  ASSERT_EQ(other.exitCode, 0) << other.err;
  EXPECT_NE(other.err.find("grey ramp over the values 0..200"), std::string::npos) << other.err;

  // Their isosurface without --iso: Otsu's threshold, the viewer's default. A ball of 180 in a
  // background of 20 splits at the middle of the empty bins between them, 100, from the file
  // and from a store of it alike; the picture is the one --iso 100 gives.
  {
    std::ofstream raw(dir / "ball.raw", std::ios::binary);
    for (int k = 0; k < 32; ++k)
      for (int j = 0; j < 32; ++j)
        for (int i = 0; i < 32; ++i) {
          const int r2 = (i - 16) * (i - 16) + (j - 16) * (j - 16) + (k - 16) * (k - 16);
          raw.put(static_cast<char>(r2 <= 196 ? 180 : 20));
        }
  }
  std::ofstream(dir / "ball.nhdr") << "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 32 32 32\n"
                                      "spacings: 1 1 1\nencoding: raw\ndata file: ball.raw\n";
  const std::string ballStore = (dir / "ball.octoray").string();
  volume::buildStore(*openVolume((dir / "ball.nhdr").string()), ballStore, volume::BuildOptions{});
  ASSERT_EQ(run({(dir / "ball.nhdr").string(), "--mode", "iso", "--iso", "100", "-o", (dir / "k.png").string(),
                 "--exr", (dir / "k.exr").string()}).exitCode, 0);
  const auto ball = image("k.exr");
  double hit = 0;
  for (std::size_t i = 3; i < ball.size(); i += 4) hit += ball[i] > 0.99f ? 1 : 0;
  EXPECT_GT(hit, 48 * 40 * 0.1);
  for (const std::string& input : {(dir / "ball.nhdr").string(), ballStore}) {
    SCOPED_TRACE(input);
    const ProcessResult otsu = run({input, "--mode", "iso", "-o", (dir / "o.png").string(), "--exr", (dir / "o.exr").string()});
    ASSERT_EQ(otsu.exitCode, 0) << otsu.err;
    EXPECT_NE(otsu.err.find("no --iso: using 100, Otsu's threshold of the values 20..180"), std::string::npos) << otsu.err;
    EXPECT_EQ(image("o.exr"), ball);
  }
  // No finite value to split: refused by name, not an isosurface at an infinite value.
  {
    std::ofstream raw(dir / "nan.raw", std::ios::binary);
    const float nan = std::numeric_limits<float>::quiet_NaN();
    for (int i = 0; i < 8 * 8 * 8; ++i) raw.write(reinterpret_cast<const char*>(&nan), sizeof nan);
  }
  std::ofstream(dir / "nan.nhdr") << "NRRD0004\ntype: float\ndimension: 3\nsizes: 8 8 8\n"
                                     "spacings: 1 1 1\nendian: little\nencoding: raw\ndata file: nan.raw\n";
  const ProcessResult nanIso = run({(dir / "nan.nhdr").string(), "--mode", "iso", "-o", (dir / "n.png").string()});
  EXPECT_EQ(nanIso.exitCode, 1) << nanIso.err;
  EXPECT_NE(nanIso.err.find("no finite values to choose an isovalue from"), std::string::npos) << nanIso.err;
  EXPECT_NE(nanIso.err.find("nan.nhdr"), std::string::npos) << nanIso.err;
}

}  // namespace
}  // namespace octoray::test
