// octoray-view: the clinician's viewer for CT volumes larger than GPU memory.
//   octoray-view [DATA] [--layout four-up|one-up|1+3] [--preset NAME] [--wl NAME]
//     [--mode dvr|iso|mip] [--camera JSON] [--session JSON] [--script ACTIONS.json]
//     [--screenshot OUT.png] [--frames N] [--exit] [--size WxH] [--pool-mib N]
//     [--cache-mib N] [--cache-dir DIR] [--stats OUT.csv]
// DATA is an octree store, a DICOM folder / DICOMDIR / file, or any volume octoray-import
// reads (imported in the background into a store in the cache folder).
#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include <array>
#include <iostream>
#include <memory>

#include "app.h"
#include "cli_support.h"
#include "octoray/core/error.h"

int main(int argc, char** argv) {
  using namespace octoray;
  CLI::App cli{"octoray-view: view CT volumes larger than GPU memory (four-up MPR + 3D)"};
  cli.footer(
      "Examples:\n"
      "  octoray-view                                  # empty window: File > Open, or drop files\n"
      "  octoray-view /media/cd/DICOMDIR               # imports in the background, MPR at once\n"
      "  octoray-view head.octoray --layout 1+3 --preset bone --wl brain\n");
  viewer::AppOptions o;
  std::string size = "1280x800", cacheDir;
  cli.add_option("data", o.data, "an octree store, a DICOM folder/DICOMDIR/file, NRRD, MHD, NIfTI or TIFF");
  cli.add_option("--layout", o.layout, "four-up (default), one-up or 1+3");
  cli.add_option("--preset", o.preset, "3D transfer-function preset (ours or Slicer's)");
  cli.add_option("--wl", o.wlPreset, "window/level preset (brain, subdural, stroke, bone, lung, ...; auto: from the volume's values; file, file 2, ...: the windows the volume's file names, the first being the default where it names one)");
  cli.add_option("--mode", o.mode, "3D mode: dvr, iso or mip");
  cli.add_option("--camera", o.camera, "3D camera JSON (octoray-render --save-camera)");
  cli.add_option("--session", o.session, "a saved viewing session (JSON)");
  cli.add_option("--script", o.script, "replay timed input events (JSON)");
  cli.add_option("--screenshot", o.screenshot, "write the window to this PNG when converged");
  cli.add_option("--frames", o.frames, "run at least this many frames");
  cli.add_flag("--exit", o.exit, "exit when the script, frames and screenshot are done");
  cli.add_option("--size", size, "window size WxH (default 1280x800)");
  cli.add_option("--pool-mib", o.poolMib, "GPU brick pool (MiB, default 512)");
  cli.add_option("--cache-mib", o.cacheMib, "CPU brick cache (MiB, default 1024)");
  cli.add_option("--cache-dir", cacheDir, "where imported stores are kept (default ~/.cache/octoray)");
  cli.add_option("--stats", o.statsPath, "per-frame figures as CSV (frame time, working set, RSS)");
  cli.add_option("--visibility", o.visibility, "3D working-set feedback: rays (default), occlusion, both, none");
  cli.add_flag("--hidden", o.hidden, "an invisible window (still needs a display)");
  CLI11_PARSE(cli, argc, argv);
  const octoray::cli::WorkerThreadsJoinedAtExit joinedAtExit;
  try {
    const std::array<int, 2> window = octoray::cli::parseImageSize(size, "--size", 320, 240, 16384);
    o.width = window[0];
    o.height = window[1];
    o.cacheDir = cacheDir;
    std::unique_ptr<viewer::App> made;
    try {
      made = std::make_unique<viewer::App>(o);
    } catch (const viewer::GlUnavailable& e) {
      return viewer::showStartupError(e.what(), o.screenshot, o.exit);
    }
    viewer::App& app = *made;
    const int code = app.run();
    // Messages the window showed also go to stderr, so scripts and tests see them.
    for (const auto& m : app.messages) std::cerr << "octoray-view: " << m << "\n";
    return code;
  } catch (const std::exception& e) {
    std::cerr << "octoray-view: " << e.what() << "\n";
    return 1;
  }
}
