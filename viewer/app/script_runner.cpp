// Replaying a script: its steps as InputEvents for the controller, and the named actions
// panel controls perform (docs/viewer-script-json.md).
#include <epoxy/gl.h>
#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>

#include "app.h"
#include "pacs_panel.h"
#include "octoray/core/error.h"
#include "octoray/gpu/image_io.h"
#include "octoray/transfer/transfer_function_io.h"
#include "util.h"

namespace octoray::viewer {
namespace fs = std::filesystem;

// ---- script --------------------------------------------------------------------------------

std::optional<std::array<double, 2>> App::resolve(const ScriptPosition& p) const {
  if (p.window) return *p.window;
  const Rect r = viewRect(*p.view);
  if (r.w <= 0) return std::nullopt;
  if (p.pixel) return std::array<double, 2>{r.x + (*p.pixel)[0], r.y + (*p.pixel)[1]};
  if (p.fraction) return std::array<double, 2>{r.x + (*p.fraction)[0] * r.w, r.y + (*p.fraction)[1] * r.h};
  const MprView* mv = mprView(*p.view);
  if (!mv) return std::nullopt;
  const auto px = mv->plane().pixelOf(*p.patient);
  return std::array<double, 2>{r.x + px[0], r.y + px[1]};
}

void App::runScript() {
  while (scriptStep_ < script_.size()) {
    const ScriptStep& s = script_[scriptStep_];
    if (waiting_) {
      if (s.type == ScriptStep::Type::WaitPreview ? previewFraction() < s.fraction : !converged()) {
        if (secondsSince(waitStart_) > s.timeoutSeconds) {
          throw Error(options_.script,
                      s.type == ScriptStep::Type::WaitPreview
                          ? fmt::format("script step {}: the preview holds {:.0f} % of the slices after {} s, not {:.0f} %",
                                        scriptStep_, 100 * previewFraction(), s.timeoutSeconds, 100 * s.fraction)
                          : fmt::format("script step {}: not converged after {} s", scriptStep_, s.timeoutSeconds));
        }
        return;
      }
      waiting_ = false;
      ++scriptStep_;
      continue;
    }
    if (dragStep_ < 0 && scriptWait_ < s.wait) {
      ++scriptWait_;
      return;
    }
    auto at = [&](const ScriptPosition& p) {
      const auto xy = resolve(p);
      if (!xy) throw Error(options_.script, fmt::format("script step {}: the view is not on screen", scriptStep_));
      return *xy;
    };
    InputEvent e;
    e.mods = s.mods;
    e.button = s.button;
    switch (s.type) {
      case ScriptStep::Type::Move:
      case ScriptStep::Type::Press:
      case ScriptStep::Type::Release:
      case ScriptStep::Type::Wheel: {
        const auto xy = at(s.at);
        e.x = xy[0];
        e.y = xy[1];
        e.type = s.type == ScriptStep::Type::Move    ? InputEvent::Type::Move
                 : s.type == ScriptStep::Type::Press ? InputEvent::Type::Press
                 : s.type == ScriptStep::Type::Wheel ? InputEvent::Type::Wheel
                                                     : InputEvent::Type::Release;
        e.wheel = s.wheel;
        e.doubleClick = s.doubleClick;
        queue(e);
        break;
      }
      case ScriptStep::Type::Click: {
        const auto xy = at(s.at);
        e.x = xy[0];
        e.y = xy[1];
        e.type = InputEvent::Type::Move;
        queue(e);
        e.type = InputEvent::Type::Press;
        e.doubleClick = s.doubleClick;
        queue(e);
        e.type = InputEvent::Type::Release;
        e.doubleClick = false;
        queue(e);
        break;
      }
      case ScriptStep::Type::Drag: {
        // One frame per step: press, `steps` moves, release (interactive quality meanwhile).
        const auto from = at(s.at), to = at(s.to);
        if (dragStep_ < 0) {
          e.type = InputEvent::Type::Move;
          e.x = from[0];
          e.y = from[1];
          queue(e);
          e.type = InputEvent::Type::Press;
          queue(e);
          dragStep_ = 1;
          return;
        }
        const double t = static_cast<double>(dragStep_) / s.steps;
        e.type = InputEvent::Type::Move;
        e.x = from[0] + t * (to[0] - from[0]);
        e.y = from[1] + t * (to[1] - from[1]);
        queue(e);
        if (dragStep_ < s.steps) {
          ++dragStep_;
          return;
        }
        e.type = InputEvent::Type::Release;
        queue(e);
        dragStep_ = -1;
        break;
      }
      case ScriptStep::Type::Key:
        e.type = InputEvent::Type::Key;
        e.key = s.key;
        queue(e);
        break;
      case ScriptStep::Type::Action: action(s.name, s.value); break;
      case ScriptStep::Type::WaitConverged:
      case ScriptStep::Type::WaitPreview:
        waiting_ = true;
        waitStart_ = std::chrono::steady_clock::now();
        return;
      case ScriptStep::Type::Screenshot: shot_ = PendingShot{s.path, s.view, s.patientInfo}; break;
      case ScriptStep::Type::SaveSession: saveSessionTo(s.path); break;
      case ScriptStep::Type::LoadSession: loadSessionFrom(s.path); break;
      case ScriptStep::Type::DumpState: dumpState(s.path); break;
      case ScriptStep::Type::Quit: quit_ = true; break;
    }
    ++scriptStep_;
    scriptWait_ = 0;
    return;  // one step per frame
  }
  if (options_.exit && script_.size() > 0 && scriptStep_ >= script_.size() && options_.screenshot.empty()) {
    quit_ = true;
  }
}

void App::action(const std::string& name, const nlohmann::json& value) {
  auto text = [&]() {
    if (!value.is_string()) throw Error(options_.script, fmt::format("action {}: expected a string value", name));
    return value.get<std::string>();
  };
  auto number = [&]() {
    if (!value.is_number()) throw Error(options_.script, fmt::format("action {}: expected a number", name));
    return value.get<double>();
  };
  if (name == "pacs-panel") showPacs = value.get<bool>();
  else if (name.starts_with("pacs-")) pacs_->action(*this, name, value);
  else if (name == "layout") setLayout(parseLayoutName(text()));
  else if (name == "maximise") toggleMaximise(parseViewName(text()));
  else if (name == "tool") controller_.tool = parseToolName(text());
  else if (name == "preset") selectTfPreset(text());
  else if (name == "wl-preset") chooseWindowLevelPreset(text());
  else if (name == "window-level") {
    if (!value.is_array() || value.size() != 2 || !value[0].is_number() || !value[1].is_number()) {
      throw Error("", "action window-level: expected [window, level], two numbers");
    }
    const double window = value[0].get<double>(), level = value[1].get<double>();
    // A session keeps only a window above 0 (session.cpp), so none other is taken here.
    if (!(window > 0) || !std::isfinite(window) || !std::isfinite(level)) {
      throw Error("", fmt::format("action window-level: the window must be above 0 and both finite, not [{}, {}]",
                                  window, level));
    }
    session.wl = {window, level};
    session.wlPreset.clear();
    windowLevelChosen();
  } else if (name == "mode") {
    session.mode = parseModeName(text());
    modeChanged();
  }
  else if (name == "iso") {
    session.isoValue = number();
    isoValueChosen();
  }
  else if (name == "lod-pixels") session.lodPixels = number();
  else if (name == "step-factor") session.stepFactor = number();
  else if (name == "slab") session.slab = parseSlabMode(text());
  else if (name == "slab-mm") session.slabMm = number();
  else if (name == "overlays") session.overlays = value.get<bool>();
  else if (name == "clip") {
    // true / false, or {"lo": [i, j, k], "hi": [i, j, k]} in index space (enables it).
    if (value.is_boolean()) {
      session.clip.enabled = value.get<bool>();
    } else {
      const auto lo = value.at("lo"), hi = value.at("hi");
      session.clip = {true, {lo[0].get<double>(), lo[1].get<double>(), lo[2].get<double>()},
                      {hi[0].get<double>(), hi[1].get<double>(), hi[2].get<double>()}};
    }
  }
  else if (name == "patient-info") session.patientInfo = value.get<bool>();
  else if (name == "interactive-quality") session.interactiveQuality = value.get<bool>();
  else if (name == "preintegration") session.preintegration = value.get<bool>();
  else if (name == "crosshair") {
    if (!value.is_array() || value.size() != 3) throw Error("", "action crosshair: expected [x, y, z]");
    session.crosshair = {value[0].get<double>(), value[1].get<double>(), value[2].get<double>()};
  } else if (name == "rotate-planes") {
    // {"view": "axial", "degrees": 30}: what a Ctrl+drag does, by an exact angle.
    Vec3 r, d, n;
    viewAxes(parseViewName(value.at("view").get<std::string>()), session.mprRotation, r, d, n);
    const Mat4 rot = rotationAbout(n, value.at("degrees").get<double>() * 3.14159265358979323846 / 180.0);
    session.mprRotation = rot * session.mprRotation;
  } else if (name == "reset-planes") session.mprRotation = Mat4::identity();
  else if (name == "standard-view") standardView(text().empty() ? 'A' : text()[0]);
  else if (name == "reset-camera") resetCamera();
  else if (name == "open") open(text());
  else if (name == "movie") exportMovie(value.at("folder").get<std::string>(), value.value("frames", 36), value.value("degrees", 360.0));
  else if (name == "exr") export3dExr(text());
  else if (name == "save-camera") gpu::saveCamera(session.camera, text());
  else if (name == "help") showHelp = value.is_boolean() ? value.get<bool>() : !showHelp;
  else if (name == "panel") showPanel = value.get<bool>();
  else if (name == "clear-measurements") session.measurements.clear();
  else if (name == "tf-opacity") {
    // [[HU, alpha], ...]: the opacity points the TF editor's canvas edits.
    std::vector<transfer::OpacityPoint> points;
    for (const auto& p : value) points.push_back({p.at(0).get<double>(), p.at(1).get<float>()});
    transfer::TransferFunction tf = session.tf;
    tf.opacity = points;
    transfer::validate(tf, options_.script);
    session.tf = tf;
    tfChosenForDataset_ = true;
  } else if (name == "tf-color") {
    // [[HU, r, g, b], ...]: the colour points of the editor's swatches.
    std::vector<transfer::ColorPoint> points;
    for (const auto& p : value) {
      points.push_back({p.at(0).get<double>(), p.at(1).get<float>(), p.at(2).get<float>(), p.at(3).get<float>()});
    }
    transfer::TransferFunction tf = session.tf;
    tf.color = points;
    transfer::validate(tf, options_.script);
    session.tf = tf;
    tfChosenForDataset_ = true;
  } else if (name == "save-tf") {
    transfer::saveTransferFunction(session.tf, text());
  }
  else throw Error(options_.script, fmt::format("unknown action \"{}\"", name));
}

}  // namespace octoray::viewer
