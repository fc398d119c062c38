// reference-render: time per frame of the CPU reference renderer on the synthetic head phantom
// (volume/phantom.h, 0.5 mm isotropic) at several volume and image sizes, for DVR, isosurface
// and MIP with shading on and off. Prints the median of N frames per case and the sample
// rate; docs/benchmarks/reference-renderer.md records a run. Rendering uses the defaults the
// tools use (step 0.25 x spacing, early termination at 0.99) and every core unless --threads.

#include <tbb/global_control.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <CLI/CLI.hpp>

#include "octoray/gpu/camera.h"
#include "octoray/gpu/reference/reference_renderer.h"
#include "octoray/transfer/transfer_function_io.h"
#include "octoray/volume/phantom.h"

using Clock = std::chrono::steady_clock;
using namespace octoray;
using gpu::reference::RenderMode;
using gpu::reference::RenderOptions;

namespace {

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

struct Case {
  const char* name;
  RenderMode mode;
  bool shade;
};

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Times the CPU reference renderer on the phantom: medians of N frames per case."};
  std::vector<int64_t> volumes{256, 512};
  std::vector<int> images{256, 512};
  int repeats = 3, largeRepeats = 1, threads = 0;
  int64_t largeFrom = 512;
  std::string preset = "bone";
  double iso = 300;
  app.add_option("--volumes", volumes, "cubic phantom edges")->capture_default_str();
  app.add_option("--images", images, "square image edges")->capture_default_str();
  app.add_option("--repeats", repeats, "frames per case")->capture_default_str();
  app.add_option("--large-repeats", largeRepeats, "frames per case for volumes >= --large-from")
      ->capture_default_str();
  app.add_option("--large-from", largeFrom, "edge from which a volume counts as large")
      ->capture_default_str();
  app.add_option("--preset", preset, "transfer function preset")->capture_default_str();
  app.add_option("--iso", iso, "isovalue in HU")->capture_default_str();
  app.add_option("--threads", threads, "worker threads (0: all cores)");
  CLI11_PARSE(app, argc, argv);

  std::optional<tbb::global_control> limit;
  if (threads > 0) {
    limit.emplace(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(threads));
  }
  const transfer::TransferFunction tf = transfer::findPreset(preset);
  const std::vector<Case> cases{{"dvr", RenderMode::Dvr, true},
                                {"dvr", RenderMode::Dvr, false},
                                {"iso", RenderMode::Iso, true},
                                {"iso", RenderMode::Iso, false},
                                {"mip", RenderMode::Mip, false}};
  fmt::print("{:>7} {:>7} {:>4} {:>7} {:>7} {:>11} {:>9} {:>10}\n", "volume", "image", "mode",
             "shading", "frames", "median ms", "Msamples", "Msamples/s");
  for (int64_t edge : volumes) {
    volume::PhantomOptions phantom;
    phantom.dims = {edge, edge, edge};
    const auto loadStart = Clock::now();
    auto source = volume::makePhantom(phantom);
    const auto volume = gpu::reference::ReferenceVolume::fromSource(*source);
    source.reset();
    fmt::print("# {}^3 phantom generated and loaded in {:.1f} s\n", edge,
               std::chrono::duration<double>(Clock::now() - loadStart).count());
    const int frames = edge >= largeFrom ? largeRepeats : repeats;
    for (int image : images) {
      gpu::OrbitParameters orbit;
      orbit.azimuthDegrees = 30;
      orbit.elevationDegrees = 15;
      orbit.width = orbit.height = image;
      const auto camera = gpu::orbitCamera({volume.dims(), volume.patientFromIndex()}, orbit);
      const gpu::reference::ReferenceRenderer renderer(volume);
      for (const Case& c : cases) {
        RenderOptions options;
        options.mode = c.mode;
        options.isoValue = iso;
        options.shading = c.shade ? RenderOptions::Shading::On : RenderOptions::Shading::Off;
        std::vector<double> ms;
        int64_t samples = 0;
        for (int r = 0; r < frames; ++r) {
          const auto start = Clock::now();
          const auto result = renderer.render(camera, tf, options);
          ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - start).count());
          samples = result.stats.samples;
        }
        const double m = median(ms);
        fmt::print("{:>6}³ {:>5}² {:>4} {:>7} {:>7} {:>11.0f} {:>9.1f} {:>10.1f}\n", edge, image,
                   c.name, c.mode == RenderMode::Mip ? "-" : (c.shade ? "on" : "off"), frames, m,
                   static_cast<double>(samples) / 1e6, static_cast<double>(samples) / 1e3 / m);
        std::fflush(stdout);
      }
    }
  }
  return 0;
}
