#pragma once
// Input events and scripts. Real input (GLFW callbacks) and replayed input (a script) become
// the same InputEvent values and go through the same handlers (controller.h), so a test drives
// the viewer the way a person does.
//
// A script (docs/viewer-script-json.md) is a list of steps run in order, one frame apart by
// default ("wait": frames before the step). Positions are window pixels [x, y] (fractional
// allowed; y down), or relative to a view: {"view": "axial", "pixel": [x, y]},
// {"view": "axial", "fraction": [fx, fy]} or {"view": "axial", "patient": [x, y, z]} (the
// pixel where a patient position projects in that MPR view).

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "octoray/core/geometry.h"
#include "octoray/viewer/session.h"

namespace octoray::viewer {

enum Modifier : int { kShift = 1, kCtrl = 2, kAlt = 4 };
enum class MouseButton { Left = 0, Right = 1, Middle = 2 };

struct InputEvent {
  enum class Type { Move, Press, Release, Wheel, Key } type = Type::Move;
  double x = 0, y = 0;  // window pixels (framebuffer), y down
  MouseButton button = MouseButton::Left;
  int mods = 0;
  double wheel = 0;     // notches; positive = away from the user
  std::string key;      // "a".."z", "0".."9", "Up", "Down", "Left", "Right", "PageUp",
                        // "PageDown", "Home", "End", "Escape", "Delete", "F1", "Space"
  bool doubleClick = false;
};

struct ScriptPosition {
  std::optional<std::array<double, 2>> window;
  std::optional<ViewId> view;
  std::optional<std::array<double, 2>> pixel, fraction;
  std::optional<Vec3> patient;
};

struct ScriptStep {
  enum class Type {
    Move, Press, Release, Click, Drag, Wheel, Key, Action, WaitConverged, WaitPreview, Screenshot,
    SaveSession, LoadSession, DumpState, Quit
  } type = Type::Move;
  int wait = 1;                    // frames before the step
  ScriptPosition at, to;           // at: move/press/release/click/wheel/drag start; to: drag end
  MouseButton button = MouseButton::Left;
  int mods = 0;
  int steps = 8;                   // drag: frames (intermediate moves)
  bool doubleClick = false;
  double wheel = 0;
  std::string key;                 // key: name (see InputEvent)
  std::string name;                // action name
  nlohmann::json value;            // action value
  std::string path;                // screenshot / session / state file
  std::optional<ViewId> view;      // screenshot of one view (else the whole window)
  bool patientInfo = false;        // screenshot: keep patient corners (off unless asked)
  double timeoutSeconds = 120;     // wait-converged, wait-preview
  double fraction = 0;             // wait-preview: the share of the preview's slices to wait for
};

// Throws octoray::Error naming `path` and the step at fault.
std::vector<ScriptStep> parseScript(const nlohmann::json& json, const std::string& path = {});
std::vector<ScriptStep> loadScript(const std::filesystem::path& path);

}  // namespace octoray::viewer
