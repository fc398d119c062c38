// octoray-compare: how far apart two images are (PNG or OpenEXR, any mix): RMSE, PSNR, SSIM,
// maximum absolute error and the count of NaN/infinite pixels over premultiplied RGB (the
// images over black), and the largest alpha difference when both files carry alpha.
//   octoray-compare A B [--json]

#include <fmt/format.h>
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

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
      throw octoray::Error(pathB, e.reason() + " (against " + pathA + ")");
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
                                                        : nlohmann::json()}}
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
