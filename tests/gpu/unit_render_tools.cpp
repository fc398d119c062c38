// octoray-render and octoray-compare as a user runs them: a store and a NRRD of the same
// phantom render the same image, --json reports what was done, bad input exits 1 naming the
// file, usage errors exit 2.

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <filesystem>
#include <fstream>

#include "octoray/gpu/image_io.h"
#include "octoray/gpu/image_metrics.h"
#include "octoray/volume/phantom.h"
#include "octoray/volume/store_builder.h"
#include "run_process.h"
#include "test_paths.h"

namespace octoray::test {
namespace {

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
  EXPECT_EQ(
      runProcess({render, nrrd, "-o", out, "--preset", "bone", "--mode", "iso", "--reference"}).exitCode,
      1);
  // GPU-only options with --reference, and --gpu with --reference, are usage errors.
  EXPECT_EQ(runProcess({render, nrrd, "-o", out, "--preset", "bone", "--reference", "--lod-pixels", "2"})
                .exitCode,
            2);
  EXPECT_EQ(runProcess({render, nrrd, "-o", out, "--preset", "bone", "--reference", "--gpu"}).exitCode, 2);
  EXPECT_EQ(runProcess({render, nrrd, "-o", out}).exitCode, 2);  // no transfer function
  EXPECT_EQ(runProcess({render, nrrd, "-o", out, "--preset", "bone", "--mode", "x"}).exitCode, 2);
}

}  // namespace
}  // namespace octoray::test
