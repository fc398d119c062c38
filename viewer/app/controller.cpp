// Input handlers: every mouse and key event, real (GLFW callbacks) or replayed (a script),
// ends here and becomes a change of the session model. The mouse map is the one Slicer, Horos,
// Weasis and OHIF share (../shared/research/viewer-anchors.md):
//   MPR views: left-drag = the current tool (window/level by default: horizontal = width,
//   vertical = level, up raises it; gain = width at the press / 200 per pixel), middle-drag
//   = pan, right-drag = zoom, wheel = slices (Ctrl+wheel = zoom), Shift+left = crosshair,
//   Ctrl+left-drag = rotate the other planes about this view's normal (oblique MPR).
//   3D view: left-drag = rotate (trackball), middle-drag = pan, right-drag or wheel = zoom.
//   Double-click maximises a view (and restores the layout).
//   Keys 1-9: the window/level table's presets; 0: auto window/level (Weasis' key 0).
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <numbers>

#include "app.h"
#include "octoray/core/error.h"

namespace octoray::viewer {
namespace {

constexpr double kDegrees = std::numbers::pi / 180.0;

// Keeps a rotation orthonormal after many small products.
Mat4 orthonormalise(const Mat4& r) {
  Vec3 c0 = normalize(r.column(0));
  Vec3 c1 = r.column(1);
  c1 = normalize(c1 - dot(c1, c0) * c0);
  const Vec3 c2 = cross(c0, c1);
  return Mat4::fromColumns(c0, c1, c2, {0, 0, 0});
}

}  // namespace

const char* toolName(Tool t) {
  switch (t) {
    case Tool::WindowLevel: return "window-level";
    case Tool::Crosshair: return "crosshair";
    case Tool::Distance: return "distance";
    case Tool::Angle: return "angle";
    case Tool::Ellipse: return "ellipse";
    case Tool::Rectangle: return "rectangle";
  }
  return "?";
}

Tool parseToolName(const std::string& name) {
  for (Tool t : {Tool::WindowLevel, Tool::Crosshair, Tool::Distance, Tool::Angle, Tool::Ellipse,
                 Tool::Rectangle}) {
    if (name == toolName(t)) return t;
  }
  throw Error("", fmt::format("unknown tool \"{}\" (window-level, crosshair, distance, angle, "
                              "ellipse, rectangle)", name));
}

void Controller::handle(const InputEvent& e) {
  switch (e.type) {
    case InputEvent::Type::Move: move(e); break;
    case InputEvent::Type::Press: press(e); break;
    case InputEvent::Type::Release: release(e); break;
    case InputEvent::Type::Wheel: wheel(e); break;
    case InputEvent::Type::Key: key(e); break;
  }
}

void Controller::press(const InputEvent& e) {
  lastX_ = e.x;
  lastY_ = e.y;
  const auto view = app_.viewAt(e.x, e.y);
  if (!view) return;
  activeView_ = *view;
  if (e.doubleClick && e.button == MouseButton::Left) {
    app_.toggleMaximise(*view);
    drag_.reset();
    return;
  }
  Session& s = app_.session;
  Drag d{*view, e.button, e.mods, e.x, e.y, e.x, e.y, s.wl, s.camera, {}, s.mprRotation, std::nullopt};
  if (isMpr(*view)) {
    const MprView* mv = app_.mprView(*view);
    if (!mv) return;
    d.startPlane = mv->plane();
    const Rect r = app_.viewRect(*view);
    const Vec3 p = d.startPlane.at(e.x - r.x, e.y - r.y);
    d.clipFace = e.button == MouseButton::Left && !(e.mods & (kCtrl | kShift)) ? app_.clipFaceAt(*view, e.x, e.y)
                                                                              : std::nullopt;
    if (d.clipFace) {
      drag_ = d;  // a clip-box handle takes the drag before the tool
      return;
    }
    if (e.button == MouseButton::Left && !(e.mods & kCtrl)) {
      const Tool t = (e.mods & kShift) ? Tool::Crosshair : tool;
      if (t == Tool::Crosshair) {
        s.crosshair = p;
      } else if (t == Tool::Distance || t == Tool::Ellipse || t == Tool::Rectangle) {
        Measurement m;
        m.kind = t == Tool::Distance ? MeasureKind::Distance
                 : t == Tool::Ellipse ? MeasureKind::Ellipse
                                      : MeasureKind::Rectangle;
        m.view = *view;
        m.points = {p, p};
        m.right = d.startPlane.right;
        m.down = d.startPlane.down;
        pending_ = m;
      } else if (t == Tool::Angle) {
        // Three clicks: first arm, vertex, second arm.
        if (!pending_ || pending_->kind != MeasureKind::Angle || pending_->view != *view) {
          Measurement m;
          m.kind = MeasureKind::Angle;
          m.view = *view;
          m.points = {p};
          m.right = d.startPlane.right;
          m.down = d.startPlane.down;
          pending_ = m;
        } else {
          pending_->points.push_back(p);
          if (pending_->points.size() == 3) {
            s.measurements.push_back(*pending_);
            pending_.reset();
          }
        }
      }
    }
  }
  drag_ = d;
}

void Controller::move(const InputEvent& e) {
  lastX_ = e.x;
  lastY_ = e.y;
  if (const auto view = app_.viewAt(e.x, e.y); view && !drag_) activeView_ = *view;
  if (!drag_) return;
  Drag& d = *drag_;
  Session& s = app_.session;
  const double dx = e.x - d.startX, dy = e.y - d.startY;
  const double stepX = e.x - d.lastX, stepY = e.y - d.lastY;
  d.lastX = e.x;
  d.lastY = e.y;
  app_.markInteraction();
  if (d.view == ViewId::Volume) {
    gpu::Camera c = d.startCamera;
    const Vec3 forward = normalize(c.target - c.eye);
    const Vec3 right = normalize(cross(forward, c.up));
    const Vec3 up = normalize(cross(right, forward));
    const double distance = length(c.target - c.eye);
    const Rect r = app_.viewRect(ViewId::Volume);
    if (d.button == MouseButton::Left) {
      // Trackball: horizontal turns about the view's up axis, vertical about its right axis.
      const Mat4 rot = rotationAbout(right, -dy * 0.4 * kDegrees) * rotationAbout(up, -dx * 0.4 * kDegrees);
      const Vec3 offset = rot.transformVector(c.eye - c.target);
      c.eye = c.target + offset;
      c.up = normalize(rot.transformVector(up));
    } else if (d.button == MouseButton::Middle) {
      const double mmPerPixel =
          c.projection == gpu::Projection::Orthographic
              ? c.orthoHeightMm / std::max(1, r.h)
              : 2.0 * distance * c.tanHalfFovY() / std::max(1, r.h);
      const Vec3 shift = (-dx * mmPerPixel) * right + (dy * mmPerPixel) * up;
      c.eye = c.eye + shift;
      c.target = c.target + shift;
    } else {
      const double factor = std::exp(dy * 0.01);  // drag down: farther
      c.eye = c.target + factor * (c.eye - c.target);
      c.orthoHeightMm *= factor;
    }
    s.camera.eye = c.eye;
    s.camera.target = c.target;
    s.camera.up = c.up;
    s.camera.orthoHeightMm = c.orthoHeightMm;
    return;
  }
  MprViewState& vs = s.mprViews[static_cast<std::size_t>(d.view)];
  const Rect r = app_.viewRect(d.view);
  const MprPlane& plane = d.startPlane;
  if (d.button == MouseButton::Middle) {
    vs.panRightMm -= stepX * app_.mprView(d.view)->plane().mmPerPixel;
    vs.panDownMm -= stepY * app_.mprView(d.view)->plane().mmPerPixel;
    return;
  }
  if (d.button == MouseButton::Right) {
    vs.zoom = std::clamp(vs.zoom * std::exp(-stepY * 0.01), 0.05, 200.0);
    return;
  }
  // Left button.
  const Vec3 p = plane.at(e.x - r.x, e.y - r.y);
  if (d.clipFace && app_.grid()) {
    // The grabbed face follows the cursor along its index axis, staying a voxel from the other.
    const auto [axis, side] = *d.clipFace;
    const Grid& grid = *app_.grid();
    const double q = grid.indexFromPatient.transformPoint(p)[axis];
    const double lo = -0.5, hi = static_cast<double>(grid.dims[static_cast<std::size_t>(axis)]) - 0.5;
    ClipBox& c = s.clip;
    double* bounds[2][3] = {{&c.lo.x, &c.lo.y, &c.lo.z}, {&c.hi.x, &c.hi.y, &c.hi.z}};
    if (side == 0) *bounds[0][axis] = std::clamp(q, lo, *bounds[1][axis] - 1.0);
    else *bounds[1][axis] = std::clamp(q, *bounds[0][axis] + 1.0, hi);
    return;
  }
  if (d.mods & kCtrl) {
    // Oblique: the other planes turn about this view's normal by the angle the cursor swept
    // about the crosshair.
    const auto c = plane.pixelOf(s.crosshair);
    const double a0 = std::atan2(d.startY - r.y - c[1], d.startX - r.x - c[0]);
    const double a1 = std::atan2(e.y - r.y - c[1], e.x - r.x - c[0]);
    s.mprRotation = orthonormalise(rotationAbout(plane.normal, a1 - a0) * d.startRotation);
    return;
  }
  const Tool t = (d.mods & kShift) ? Tool::Crosshair : tool;
  if (t == Tool::WindowLevel) {
    const double gain = d.startWl.window / 200.0;
    s.wl.window = std::max(app_.minimumWindow(), d.startWl.window + dx * gain);
    s.wl.level = d.startWl.level - dy * gain;
    s.wlPreset.clear();
    app_.windowLevelChosen();
  } else if (t == Tool::Crosshair) {
    s.crosshair = p;
  } else if (pending_ && pending_->kind != MeasureKind::Angle && pending_->points.size() == 2) {
    pending_->points[1] = p;
  }
}

void Controller::release(const InputEvent& e) {
  lastX_ = e.x;
  lastY_ = e.y;
  if (drag_ && pending_ && pending_->kind != MeasureKind::Angle && drag_->button == MouseButton::Left) {
    const Rect r = app_.viewRect(drag_->view);
    pending_->points[1] = drag_->startPlane.at(e.x - r.x, e.y - r.y);
    if (length(pending_->points[1] - pending_->points[0]) > 0) {
      app_.session.measurements.push_back(*pending_);
    }
    pending_.reset();
  }
  drag_.reset();
}

void Controller::scrollSlices(ViewId view, double steps) {
  const Grid* grid = app_.grid();
  if (!grid || !isMpr(view)) return;
  Vec3 right, down, normal;
  viewAxes(view, app_.session.mprRotation, right, down, normal);
  const double step = grid->sliceStepMm(normal);
  app_.session.crosshair = app_.session.crosshair + (steps * step) * normal;
}

void Controller::wheel(const InputEvent& e) {
  const auto view = app_.viewAt(e.x, e.y);
  if (!view) return;
  activeView_ = *view;
  Session& s = app_.session;
  app_.markInteraction();
  if (*view == ViewId::Volume) {
    const double factor = std::pow(0.9, e.wheel);  // away from the user: closer
    s.camera.eye = s.camera.target + factor * (s.camera.eye - s.camera.target);
    s.camera.orthoHeightMm *= factor;
    return;
  }
  if (e.mods & kCtrl) {
    MprViewState& vs = s.mprViews[static_cast<std::size_t>(*view)];
    vs.zoom = std::clamp(vs.zoom * std::pow(1.1, e.wheel), 0.05, 200.0);
    return;
  }
  scrollSlices(*view, e.wheel);
}

void Controller::key(const InputEvent& e) {
  const std::string& k = e.key;
  const auto hovered = app_.viewAt(lastX_, lastY_);
  const ViewId view = hovered ? *hovered : activeView_;
  if (k.size() == 1 && k[0] >= '0' && k[0] <= '9') {
    app_.applyWindowLevelKey(k[0] - '0');
    return;
  }
  if (k == "F1" || k == "?") {
    app_.showHelp = !app_.showHelp;
    return;
  }
  if (k == "Escape") {
    pending_.reset();
    app_.showHelp = false;
    return;
  }
  if (k == "Delete" || k == "Backspace") {
    if (!app_.session.measurements.empty()) app_.session.measurements.pop_back();
    return;
  }
  if (k == "o" && !(e.mods & kShift)) {
    app_.session.overlays = !app_.session.overlays;
    return;
  }
  if ((e.mods & kShift) && k.size() == 1 && std::string("APLRSI").find(static_cast<char>(std::toupper(k[0]))) != std::string::npos) {
    app_.standardView(static_cast<char>(std::toupper(k[0])));
    return;
  }
  if (k == "r") {
    if (view == ViewId::Volume) app_.resetCamera();
    else app_.resetMprViews();
    return;
  }
  if (k == "w") tool = Tool::WindowLevel;
  else if (k == "x") tool = Tool::Crosshair;
  else if (k == "l") tool = Tool::Distance;
  else if (k == "a") tool = Tool::Angle;
  else if (k == "e") tool = Tool::Ellipse;
  else if (k == "b") tool = Tool::Rectangle;
  else if (k == "f") app_.toggleMaximise(view);
  else if (isMpr(view)) {
    if (k == "Up" || k == "Right") scrollSlices(view, 1);
    else if (k == "Down" || k == "Left") scrollSlices(view, -1);
    else if (k == "PageUp") scrollSlices(view, 10);
    else if (k == "PageDown") scrollSlices(view, -10);
  }
}

}  // namespace octoray::viewer
