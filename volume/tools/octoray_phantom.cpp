// octoray-phantom: writes the synthetic head phantom at any size as NRRD (detached header +
// raw int16), generated slab by slab, so scale tests need neither a download nor the memory to
// hold the volume.

#include <fmt/format.h>
#include <tbb/global_control.h>
#include <CLI/CLI.hpp>

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "cli_checks.h"
#include "cli_support.h"
#include "octoray/core/error.h"
#include "octoray/volume/phantom.h"

namespace {

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "Writes the octoray synthetic head CT phantom (HU, int16) at any size as NRRD: a "
      "detached header and a .raw data file beside it."};
  app.footer(
      "Examples:\n"
      "  octoray-phantom -o head.nhdr                          # 256^3, 1 mm, band-limited\n"
      "  octoray-phantom -o big.nhdr --size 2048x2048x1024 --spacing 0.25,0.25,0.5\n"
      "  octoray-import head.nhdr -o head.octoray\n");
  std::string output;
  std::string size = "256x256x256";
  std::string spacing = "0.5,0.5,0.5";
  uint64_t seed = 1;
  int threads = 0;
  double psfSigma = 1.0;
  bool hardEdges = false;
  app.add_option("-o,--output", output, "header to write (.nhdr or .nrrd); data goes to .raw")
      ->required();
  app.add_option("--size", size, "columns x rows x slices")->capture_default_str();
  app.add_option("--spacing", spacing, "column, row and slice spacing in mm")
      ->capture_default_str();
  app.add_option("--seed", seed, "seed of the noise")->capture_default_str();
  auto* psf = app.add_option("--psf-sigma", psfSigma,
                             "Gaussian point-spread function, sigma in voxels (partial-volume "
                             "boundaries and correlated noise, as a scanner's); 0 = hard edges")
                  ->check(CLI::Range(0.0, 4.0))
                  ->capture_default_str();
  app.add_flag("--hard-edges", hardEdges, "the old hard-edged phantom (same as --psf-sigma 0)")
      ->excludes(psf);
  app.add_option("--threads", threads, "worker threads (0: all cores)")
      ->check(octoray::cli::kNonNegative);
  try {
    app.parse(argc, argv);
  } catch (const CLI::Success& e) {
    return app.exit(e);  // --help
  } catch (const CLI::ParseError& e) {
    fmt::print(stderr, "octoray-phantom: {}\nRun with --help for more information.\n", e.what());
    return 2;
  }

  return octoray::cli::runTool("octoray-phantom", [&] {
    octoray::volume::PhantomOptions options;
    options.seed = seed;
    options.psfSigmaVoxels = hardEdges ? 0.0 : psfSigma;
    options.dims = octoray::cli::parseDims(size, "--size");
    for (int64_t d : options.dims) {
      if (d > 1048576) throw octoray::Error("", fmt::format("--size \"{}\": at most 1048576", size));
    }
    const auto spacingMm = octoray::cli::parseTriple(spacing, "--spacing");
    options.spacingMm = {spacingMm[0], spacingMm[1], spacingMm[2]};

    std::optional<tbb::global_control> threadLimit;
    if (threads > 0) {
      threadLimit.emplace(tbb::global_control::max_allowed_parallelism,
                          static_cast<std::size_t>(threads));
    }

    const auto start = std::chrono::steady_clock::now();
    {
      octoray::cli::ProgressBar progress("phantom");
      octoray::volume::writePhantomNrrd(options, output, [&](int64_t done, int64_t total) {
        progress.update(static_cast<std::size_t>(done), static_cast<std::size_t>(total));
      });
    }
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

    const double samples = static_cast<double>(options.dims[0]) *
                           static_cast<double>(options.dims[1]) *
                           static_cast<double>(options.dims[2]);
    std::filesystem::path raw(output);
    raw.replace_extension(".raw");
    fmt::print("wrote {} x {} x {} phantom (seed {}, spacing {} x {} x {} mm) to {} + {}\n",
               options.dims[0], options.dims[1], options.dims[2], seed, options.spacingMm.x,
               options.spacingMm.y, options.spacingMm.z, output, raw.filename().string());
    fmt::print("  {} bytes of int16 data in {:.2f} s ({:.1f} Mvoxels/s)\n",
               static_cast<uint64_t>(samples) * 2, seconds,
               seconds > 0 ? samples / seconds / 1e6 : 0.0);
    return 0;
  });
}
