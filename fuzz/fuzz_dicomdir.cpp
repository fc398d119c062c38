// libFuzzer target: arbitrary bytes as a DICOMDIR, scanned as a user's DICOMDIR is: its
// records resolved to files (which must stay inside its folder: a sibling folder holds a
// decoy), the files it lists read. Every octoray::Error and every warning is an accepted
// answer; a crash, a hang, a sanitizer report or another exception escaping is a bug.

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string>

#include "fuzz_scratch.h"
#include "octoray/core/error.h"
#include "octoray/dicom/dicom_series.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  using namespace octoray;
  namespace fs = std::filesystem;
  static const bool layout = [] {
    fs::create_directories(fuzz::scratchDir() / "media/IMG");
    fs::create_directories(fuzz::scratchDir() / "outside");
    const uint8_t text[] = "not an image";
    fuzz::writeScratch("media/IMG/I1", text, sizeof text);
    fuzz::writeScratch("outside/secret", text, sizeof text);
    return true;
  }();
  (void)layout;
  const auto path = fuzz::writeScratch("media/DICOMDIR", data, size);
  try {
    const dicom::DicomScan scan = dicom::scanDicom(path);
    // A record leading out of the DICOMDIR's folder must never be followed: the decoy would be
    // read (and skipped as no image) if it were.
    auto outside = [](const std::string& p) {
      return fs::weakly_canonical(p).string().find("/outside/") != std::string::npos;
    };
    for (const auto& series : scan.series) {
      for (const auto& frame : series.frames) {
        if (outside(frame.path)) __builtin_trap();
      }
    }
    for (const auto& skipped : scan.skipped) {
      if (outside(skipped.path)) __builtin_trap();
    }
  } catch (const Error&) {
  }
  return 0;
}
