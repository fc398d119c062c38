// libFuzzer target: arbitrary text as the raw-volume options a user types (--raw-dims,
// --raw-type, --raw-spacing, --raw-header-bytes, one per line), parsed as octoray-import parses
// them and opened over a 4 KiB data file; small volumes are read. Every octoray::Error is an
// accepted answer; a crash, a hang, a sanitizer report, an out-of-memory or another exception
// escaping is a bug.

#include <cstddef>
#include <cstdint>
#include <sstream>
#include <string>
#include <vector>

#include "cli_support.h"
#include "fuzz_scratch.h"
#include "octoray/core/error.h"
#include "octoray/dicom/formats.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  using namespace octoray;
  static const std::string rawPath = [] {
    std::vector<uint8_t> raw(4096);
    for (std::size_t i = 0; i < raw.size(); ++i) raw[i] = static_cast<uint8_t>(i * 13);
    return fuzz::writeScratch("volume.raw", raw.data(), raw.size()).string();
  }();
  std::istringstream text(std::string(reinterpret_cast<const char*>(data), size));
  std::string dims, type, spacing, headerBytes;
  std::getline(text, dims);
  std::getline(text, type);
  std::getline(text, spacing);
  std::getline(text, headerBytes);
  try {
    RawOptions options;
    options.dims = cli::parseDims(dims, "--raw-dims");
    if (!type.empty()) options.sampleType = parseSampleType(type);
    if (!spacing.empty()) {
      const auto s = cli::parseTriple(spacing, "--raw-spacing");
      options.spacingMm = {s[0], s[1], s[2]};
    }
    if (!headerBytes.empty()) {
      std::size_t used = 0;
      try {
        options.headerBytes = std::stoull(headerBytes, &used);
      } catch (const std::exception&) {
        return 0;  // CLI11 refuses what is not a number before octoray sees it
      }
    }
    options.bigEndian = size > 0 && (data[size - 1] & 1);
    auto source = openRawVolume(rawPath, options);
    const VolumeInfo& info = source->info();
    if (info.sampleCount() > 0 && info.sampleCount() <= (1 << 16)) {
      std::vector<float> all(static_cast<std::size_t>(info.sampleCount()));
      source->readSlab(0, info.dims[2], all);
    }
  } catch (const Error&) {
  }
  return 0;
}
