// libFuzzer target: arbitrary bytes as a volume file with a header: NRRD (attached and
// detached: .nrrd, .nhdr), MetaImage (.mha, .mhd) and NIfTI (.nii). The first byte picks the
// format; the rest is the file. A detached header may name a data file: `data.raw` beside it
// holds 4 KiB. Every octoray::Error is an accepted answer; a crash, a hang, a sanitizer report,
// an out-of-memory or any other exception escaping is a bug. Small volumes are also read, so
// the data paths (raw, gzip, byte order, scaling) run too.

#include <cstddef>
#include <cstdint>
#include <vector>

#include "fuzz_scratch.h"
#include "octoray/core/error.h"
#include "octoray/dicom/formats.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  using namespace octoray;
  if (size < 1) return 0;
  static const char* const kNames[] = {"v.nrrd", "v.nhdr", "v.mha", "v.mhd", "v.nii"};
  const std::string name = kNames[data[0] % 5];
  static bool dataFile = [] {
    std::vector<uint8_t> raw(4096);
    for (std::size_t i = 0; i < raw.size(); ++i) raw[i] = static_cast<uint8_t>(i * 7);
    fuzz::writeScratch("data.raw", raw.data(), raw.size());
    return true;
  }();
  (void)dataFile;
  const auto path = fuzz::writeScratch(name, data + 1, size - 1);
  try {
    auto source = openVolume(path.string());
    const VolumeInfo& info = source->info();
    if (info.sampleCount() > 0 && info.sampleCount() <= (1 << 16)) {
      std::vector<float> all(static_cast<std::size_t>(info.sampleCount()));
      source->readSlab(0, info.dims[2], all);
    }
  } catch (const Error&) {
  }
  return 0;
}
