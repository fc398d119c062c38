// libFuzzer target: arbitrary bytes as the JSON documents octoray reads from users: a camera
// (octoray-render --camera, the viewer), a viewer session, a viewer script and a window/level
// preset table; the first byte picks which. Every octoray::Error is an accepted answer; a crash,
// a sanitizer report or another exception escaping (a nlohmann::json type error, say) is a bug.

#include <cstddef>
#include <cstdint>
#include <string>

#include <nlohmann/json.hpp>

#include "fuzz_scratch.h"
#include "octoray/core/error.h"
#include "octoray/gpu/camera.h"
#include "octoray/viewer/presets.h"
#include "octoray/viewer/script.h"
#include "octoray/viewer/session.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  using namespace octoray;
  if (size < 1) return 0;
  const int kind = data[0] % 4;
  try {
    if (kind == 3) {
      viewer::loadWindowLevelPresets(fuzz::writeScratch("presets.json", data + 1, size - 1));
      return 0;
    }
    const std::string text(reinterpret_cast<const char*>(data + 1), size - 1);
    const nlohmann::json j = nlohmann::json::parse(text, nullptr, false);
    if (j.is_discarded()) return 0;
    if (kind == 0) (void)gpu::cameraFromJson(j, "camera.json");
    if (kind == 1) (void)viewer::sessionToJson(viewer::sessionFromJson(j, "session.json"));
    if (kind == 2) (void)viewer::parseScript(j, "script.json");
  } catch (const Error&) {
  }
  return 0;
}
