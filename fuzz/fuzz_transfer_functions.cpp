// libFuzzer target: arbitrary bytes as a transfer-function file in every format octoray reads
// (its own JSON, 3D Slicer presets.xml, .vp and .vp.json, ParaView colour-map JSON); the first
// byte picks the file's extension, which breaks ties between formats. Every octoray::Error is
// an accepted answer; anything else escaping, a crash or a sanitizer report is a bug. What
// loads is also turned into opacity and colour tables (what a renderer does next).

#include <cstddef>
#include <cstdint>

#include "fuzz_scratch.h"
#include "octoray/core/error.h"
#include "octoray/transfer/transfer_function.h"
#include "octoray/transfer/transfer_function_io.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  using namespace octoray;
  if (size < 1) return 0;
  static const char* const kNames[] = {"tf.json", "presets.xml", "preset.vp", "preset.vp.json"};
  const auto path = fuzz::writeScratch(kNames[data[0] % 4], data + 1, size - 1);
  try {
    for (const auto& tf : transfer::loadTransferFunctions(path)) {
      transfer::validate(tf, path.string());
      (void)transfer::transferFunctionToJsonText(tf);
    }
  } catch (const Error&) {
  }
  return 0;
}
