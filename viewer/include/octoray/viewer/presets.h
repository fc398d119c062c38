#pragma once
// The window/level preset table (viewer/presets/window-level.json): name, keyboard key 1-9,
// window and level in HU, and where the values come from. Users edit the file (or the table
// in the viewer's panel); a bad file is an Error naming the file and the entry.

#include <filesystem>
#include <string>
#include <vector>

#include "octoray/dicom/volume_source.h"

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

// Automatic window/level, named "auto" (Weasis' key 0; Slicer's auto W/L takes the same
// percentiles): the window spans the 0.1st to the 99.9th percentile of the volume's values and
// the level is its centre. `histogram` counts the values in equal bins over [lo, hi]; a
// percentile is interpolated linearly inside its bin. Where they lie less than a bin apart
// (nearly every value the same, as a mask's zeros), and for an empty histogram, the window is
// the whole range. Values and window are in the volume's unit, whatever
// it is: this is what a volume without Hounsfield units (MR, or a file without units) opens with.
WindowLevelPreset autoWindowLevel(const std::vector<int>& histogram, double lo, double hi);

// Decimals enough to tell values apart on a label or control spanning `range` of the volume's
// unit, about a thousandth of it: none from 100 up (HU), one from 10, two from 1, three from
// 0.1 and so on (an ADC map's 0.003: five); none for a range that is not a positive number.
int valueDecimals(double range);
// The step of a window/level or value control spanning `range`: the power of ten about a
// hundredth of it (10 for CT's 4095 HU, 0.001 for values in [0, 0.44]).
double valueStep(double range);

// The windows a volume's file names (DICOM's WindowCenter / WindowWidth, VolumeInfo::windows),
// as presets named "file", "file 2", ... in the file's order, their source its explanation
// ("BRAIN") or where they come from. A volume that names one opens with the first, as Horos,
// Weasis, OHIF and Slicer open a DICOM series; its values are in the volume's unit.
std::vector<WindowLevelPreset> fileWindowLevelPresets(const std::vector<SourceWindow>& windows);

}  // namespace octoray::viewer
