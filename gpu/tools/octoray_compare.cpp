// octoray-compare: how far apart two images are (PNG or OpenEXR, any mix): RMSE, PSNR, SSIM,
// maximum absolute error and the count of NaN/infinite pixels over premultiplied RGB (the
// images over black), and the largest alpha difference when both files carry alpha. With two
// EXRs carrying depth (Z, mm: isosurface hits), also the depth difference where both hit and
// the pixels where only one does.
//   octoray-compare A B [--json]

#include <fmt/format.h>
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <iostream>
#include <string>

#include "cli_support.h"
#include "octoray/core/error.h"
#include "octoray/gpu/image_io.h"
#include "octoray/gpu/image_metrics.h"

int main(int argc, char** argv) {
  CLI::App app{
      "Compares two images (PNG or OpenEXR) as seen over black: RMSE, PSNR, SSIM, max error, "
      "NaN/inf pixels; alpha separately when both have it."};
  app.footer(
      "Examples:\n"
      "  octoray-compare gpu.png reference.png            # RMSE, PSNR, SSIM, max error\n"
      "  octoray-compare gpu.exr reference.exr --json     # with depth error, as JSON\n");
  std::string pathA, pathB;
  bool json = false;
  app.add_option("a", pathA, "first image")->required();
  app.add_option("b", pathB, "second image")->required();
  app.add_flag("--json", json, "print the metrics as JSON");
  try {
    app.parse(argc, argv);
  } catch (const CLI::Success& e) {
    return app.exit(e);
  } catch (const CLI::Error& e) {
    fmt::print(stderr, "octoray-compare: {}\nRun with --help for more information.\n", e.what());
    return 2;
  }
  return octoray::cli::runTool("octoray-compare", [&] {
    using namespace octoray::gpu;
    const Image a = readImage(pathA);
    const Image b = readImage(pathB);
    ImageMetrics m;
    try {
      m = compare(a, b);
    } catch (const octoray::Error& e) {
      // Both named, in the order given: either may be the wrong one.
      throw octoray::Error("", fmt::format("{} and {}: {}", pathA, pathB, e.reason()));
    }
    // Depth (EXR Z): finite where a ray hit (isosurfaces) or met material (DVR).
    double depthMean = 0, depthMax = 0;
    int64_t depthBoth = 0, depthOne = 0;
    if (a.depth.size() == b.depth.size()) {
      for (std::size_t i = 0; i < a.depth.size(); ++i) {
        const bool ha = std::isfinite(a.depth[i]), hb = std::isfinite(b.depth[i]);
        if (ha && hb) {
          const double d = std::abs(static_cast<double>(a.depth[i]) - b.depth[i]);
          depthMean += d;
          depthMax = std::max(depthMax, d);
          ++depthBoth;
        } else if (ha != hb) {
          ++depthOne;
        }
      }
      if (depthBoth > 0) depthMean /= static_cast<double>(depthBoth);
    }
    // JSON has no infinity: identical images report "psnrDb": null.
    const nlohmann::json psnr =
        std::isfinite(m.psnrDb) ? nlohmann::json(m.psnrDb) : nlohmann::json();
    if (json) {
      std::cout << nlohmann::json{{"a", pathA},
                                  {"b", pathB},
                                  {"width", a.width},
                                  {"height", a.height},
                                  {"rmse", m.rmse},
                                  {"psnrDb", psnr},
                                  {"ssim", m.ssim},
                                  {"maxAbsError", m.maxAbsError},
                                  {"nonFiniteA", m.nonFiniteA},
                                  {"nonFiniteB", m.nonFiniteB},
                                  {"maxAlphaError", m.alphaCompared
                                                        ? nlohmann::json(m.maxAlphaError)
                                                        : nlohmann::json()},
                                  {"depth", {{"pixelsBoth", depthBoth},
                                             {"pixelsOne", depthOne},
                                             {"meanAbsMm", depthMean},
                                             {"maxAbsMm", depthMax}}}}
                       .dump(2)
                << '\n';
    } else {
      fmt::print(
          "{}x{}  RMSE {:.6g}  PSNR {:.2f} dB  SSIM {:.6f}  max error {:.6g}  "
          "NaN/inf pixels {} / {}{}\n",
          a.width, a.height, m.rmse, m.psnrDb, m.ssim, m.maxAbsError, m.nonFiniteA, m.nonFiniteB,
          m.alphaCompared ? fmt::format("  max alpha error {:.6g}", m.maxAlphaError) : "");
    }
    return 0;
  });
}
