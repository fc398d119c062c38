#pragma once
// The window/level preset table (viewer/presets/window-level.json): name, keyboard key 1-9,
// window and level in HU, and where the values come from. Users edit the file (or the table
// in the viewer's panel); a bad file is an Error naming the file and the entry.

#include <filesystem>
#include <string>
#include <vector>

namespace octoray::viewer {

struct WindowLevelPreset {
  int key = 0;  // 1-9, or 0 for none
  std::string name;
  double window = 400, level = 40;
  std::string source;
};

std::vector<WindowLevelPreset> loadWindowLevelPresets(const std::filesystem::path& path);
void saveWindowLevelPresets(const std::vector<WindowLevelPreset>& presets,
                            const std::filesystem::path& path);
// $OCTORAY_WL_PRESETS when set, else viewer/presets/window-level.json of the source tree.
std::filesystem::path defaultWindowLevelPresetsPath();

}  // namespace octoray::viewer
