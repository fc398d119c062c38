#include "octoray/viewer/session.h"

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <cmath>
#include <fstream>
#include <set>

#include "octoray/core/error.h"
#include "octoray/transfer/transfer_function_io.h"

namespace octoray::viewer {
namespace {

using json = nlohmann::json;
constexpr const char* kFormat = "octoray-session";
constexpr int kVersion = 1;

template <typename E, std::size_t N>
E parseName(const std::string& name, const std::array<std::pair<E, const char*>, N>& table,
            const char* what) {
  std::string known;
  for (const auto& [value, text] : table) {
    if (name == text) return value;
    known += known.empty() ? text : std::string(", ") + text;
  }
  throw Error("", fmt::format("unknown {} \"{}\" (expected one of: {})", what, name, known));
}

constexpr std::array<std::pair<ViewId, const char*>, 4> kViews{
    {{ViewId::Axial, "axial"}, {ViewId::Coronal, "coronal"}, {ViewId::Sagittal, "sagittal"},
     {ViewId::Volume, "3d"}}};
constexpr std::array<std::pair<Layout, const char*>, 3> kLayouts{
    {{Layout::FourUp, "four-up"}, {Layout::OneUp, "one-up"}, {Layout::OnePlusThree, "1+3"}}};
constexpr std::array<std::pair<SlabMode, const char*>, 4> kSlabs{
    {{SlabMode::None, "none"}, {SlabMode::Mip, "mip"}, {SlabMode::MinIp, "minip"},
     {SlabMode::Mean, "mean"}}};
constexpr std::array<std::pair<gpu::RaycastMode, const char*>, 3> kModes{
    {{gpu::RaycastMode::Dvr, "dvr"}, {gpu::RaycastMode::Iso, "iso"}, {gpu::RaycastMode::Mip, "mip"}}};
constexpr std::array<std::pair<MeasureKind, const char*>, 4> kMeasures{
    {{MeasureKind::Distance, "distance"}, {MeasureKind::Angle, "angle"},
     {MeasureKind::Ellipse, "ellipse"}, {MeasureKind::Rectangle, "rectangle"}}};

template <typename E, std::size_t N>
const char* nameOf(E value, const std::array<std::pair<E, const char*>, N>& table) {
  for (const auto& [v, text] : table) {
    if (v == value) return text;
  }
  return "?";
}

json vec(Vec3 v) { return json::array({v.x, v.y, v.z}); }

// Field access that names the path and the field on every failure.
struct Reader {
  const std::string& path;

  [[noreturn]] void fail(const std::string& field, const std::string& what) const {
    throw Error(path, fmt::format("session field \"{}\": {}", field, what));
  }
  const json& at(const json& object, const std::string& key, const std::string& field) const {
    if (!object.is_object() || !object.contains(key)) fail(field, "missing");
    return object.at(key);
  }
  double number(const json& object, const std::string& key, const std::string& field) const {
    const json& v = at(object, key, field);
    if (!v.is_number() || !std::isfinite(v.get<double>())) fail(field, "expected a finite number");
    return v.get<double>();
  }
  double positive(const json& object, const std::string& key, const std::string& field) const {
    const double v = number(object, key, field);
    if (!(v > 0)) fail(field, "expected a positive number");
    return v;
  }
  bool boolean(const json& object, const std::string& key, const std::string& field) const {
    const json& v = at(object, key, field);
    if (!v.is_boolean()) fail(field, "expected true or false");
    return v.get<bool>();
  }
  std::string string(const json& object, const std::string& key, const std::string& field) const {
    const json& v = at(object, key, field);
    if (!v.is_string()) fail(field, "expected a string");
    return v.get<std::string>();
  }
  Vec3 vec3(const json& v, const std::string& field) const {
    if (!v.is_array() || v.size() != 3) fail(field, "expected [x, y, z]");
    std::array<double, 3> c{};
    for (std::size_t i = 0; i < 3; ++i) {
      if (!v[i].is_number() || !std::isfinite(v[i].get<double>())) fail(field, "expected finite numbers");
      c[i] = v[i].get<double>();
    }
    return {c[0], c[1], c[2]};
  }
  template <typename E, std::size_t N>
  E name(const json& object, const std::string& key, const std::string& field,
         const std::array<std::pair<E, const char*>, N>& table, const char* what) const {
    const std::string text = string(object, key, field);
    try {
      return parseName(text, table, what);
    } catch (const Error& e) {
      fail(field, e.reason());
    }
  }
};

void rejectUnknown(const json& object, const std::set<std::string>& known, const Reader& r,
                   const std::string& where) {
  for (const auto& [key, value] : object.items()) {
    if (!known.contains(key)) r.fail(where.empty() ? key : where + "." + key, "unknown field");
  }
}

}  // namespace

const char* viewName(ViewId v) { return nameOf(v, kViews); }
ViewId parseViewName(const std::string& name) { return parseName(name, kViews, "view"); }
const char* layoutName(Layout l) { return nameOf(l, kLayouts); }
Layout parseLayoutName(const std::string& name) { return parseName(name, kLayouts, "layout"); }
const char* slabModeName(SlabMode m) { return nameOf(m, kSlabs); }
SlabMode parseSlabMode(const std::string& name) { return parseName(name, kSlabs, "slab mode"); }
const char* modeName(gpu::RaycastMode m) { return nameOf(m, kModes); }
gpu::RaycastMode parseModeName(const std::string& name) { return parseName(name, kModes, "mode"); }
const char* measureKindName(MeasureKind k) { return nameOf(k, kMeasures); }
MeasureKind parseMeasureKind(const std::string& name) {
  return parseName(name, kMeasures, "measurement kind");
}

json sessionToJson(const Session& s) {
  json j;
  j["format"] = kFormat;
  j["version"] = kVersion;
  j["source"] = s.source;
  j["layout"] = layoutName(s.layout);
  j["mainView"] = viewName(s.mainView);
  j["camera"] = gpu::cameraToJson(s.camera);
  j["preset"] = s.preset;
  j["transferFunction"] = json::parse(transfer::transferFunctionToJsonText(s.tf));
  j["mode"] = modeName(s.mode);
  j["isoValue"] = s.isoValue;
  j["quality"] = {{"lodPixels", s.lodPixels},
                  {"stepFactor", s.stepFactor},
                  {"earlyTermination", s.earlyTermination},
                  {"shading", s.shading},
                  {"preintegration", s.preintegration},
                  {"interactive", s.interactiveQuality}};
  j["clip"] = {{"enabled", s.clip.enabled}, {"lo", vec(s.clip.lo)}, {"hi", vec(s.clip.hi)}};
  j["windowLevel"] = {{"window", s.wl.window}, {"level", s.wl.level}, {"preset", s.wlPreset}};
  j["crosshair"] = vec(s.crosshair);
  json rotation = json::array();
  for (int r = 0; r < 3; ++r) {
    rotation.push_back({s.mprRotation.m[static_cast<std::size_t>(r)][0],
                        s.mprRotation.m[static_cast<std::size_t>(r)][1],
                        s.mprRotation.m[static_cast<std::size_t>(r)][2]});
  }
  j["mprRotation"] = rotation;
  j["slab"] = {{"mode", slabModeName(s.slab)}, {"thicknessMm", s.slabMm}};
  json views = json::object();
  for (int v = 0; v < 3; ++v) {
    const MprViewState& m = s.mprViews[static_cast<std::size_t>(v)];
    views[viewName(static_cast<ViewId>(v))] = {
        {"zoom", m.zoom}, {"panRightMm", m.panRightMm}, {"panDownMm", m.panDownMm}};
  }
  j["mprViews"] = views;
  json measurements = json::array();
  for (const Measurement& m : s.measurements) {
    json points = json::array();
    for (const Vec3& p : m.points) points.push_back(vec(p));
    measurements.push_back({{"kind", measureKindName(m.kind)},
                            {"view", viewName(m.view)},
                            {"points", points},
                            {"right", vec(m.right)},
                            {"down", vec(m.down)}});
  }
  j["measurements"] = measurements;
  j["overlays"] = {{"annotations", s.overlays}, {"patientInfo", s.patientInfo}};
  return j;
}

Session sessionFromJson(const json& j, const std::string& path) {
  const Reader r{path};
  if (!j.is_object()) r.fail("(top level)", "expected an object");
  if (!j.contains("format") || j["format"] != kFormat) r.fail("format", "expected \"octoray-session\"");
  if (!j.contains("version") || j["version"] != kVersion) r.fail("version", "expected 1");
  rejectUnknown(j,
                {"format", "version", "source", "layout", "mainView", "camera", "preset",
                 "transferFunction", "mode", "isoValue", "quality", "clip", "windowLevel", "crosshair",
                 "mprRotation", "slab", "mprViews", "measurements", "overlays"},
                r, "");
  Session s;
  s.source = r.string(j, "source", "source");
  s.layout = r.name(j, "layout", "layout", kLayouts, "layout");
  s.mainView = r.name(j, "mainView", "mainView", kViews, "view");
  try {
    s.camera = gpu::cameraFromJson(r.at(j, "camera", "camera"), path);
    s.camera.validate();
  } catch (const Error& e) {
    r.fail("camera", e.reason());
  }
  s.preset = r.string(j, "preset", "preset");
  s.tf = transfer::transferFunctionFromJsonText(r.at(j, "transferFunction", "transferFunction").dump(),
                                                path);
  s.mode = r.name(j, "mode", "mode", kModes, "mode");
  s.isoValue = r.number(j, "isoValue", "isoValue");
  const json& q = r.at(j, "quality", "quality");
  rejectUnknown(q, {"lodPixels", "stepFactor", "earlyTermination", "shading", "preintegration", "interactive"}, r,
                "quality");
  s.lodPixels = r.number(q, "lodPixels", "quality.lodPixels");
  if (s.lodPixels < 0) r.fail("quality.lodPixels", "expected >= 0");
  s.stepFactor = r.positive(q, "stepFactor", "quality.stepFactor");
  s.earlyTermination = r.positive(q, "earlyTermination", "quality.earlyTermination");
  if (s.earlyTermination > 1) r.fail("quality.earlyTermination", "expected (0, 1]");
  s.shading = r.boolean(q, "shading", "quality.shading");
  // Sessions saved before it existed have none: post-classified, as they were drawn.
  s.preintegration = q.contains("preintegration") && r.boolean(q, "preintegration", "quality.preintegration");
  s.interactiveQuality = r.boolean(q, "interactive", "quality.interactive");
  const json& clip = r.at(j, "clip", "clip");
  rejectUnknown(clip, {"enabled", "lo", "hi"}, r, "clip");
  s.clip.enabled = r.boolean(clip, "enabled", "clip.enabled");
  s.clip.lo = r.vec3(r.at(clip, "lo", "clip.lo"), "clip.lo");
  s.clip.hi = r.vec3(r.at(clip, "hi", "clip.hi"), "clip.hi");
  if (!(s.clip.lo.x < s.clip.hi.x && s.clip.lo.y < s.clip.hi.y && s.clip.lo.z < s.clip.hi.z)) {
    r.fail("clip", "lo must be below hi on every axis");
  }
  const json& wl = r.at(j, "windowLevel", "windowLevel");
  rejectUnknown(wl, {"window", "level", "preset"}, r, "windowLevel");
  s.wl.window = r.positive(wl, "window", "windowLevel.window");
  s.wl.level = r.number(wl, "level", "windowLevel.level");
  s.wlPreset = r.string(wl, "preset", "windowLevel.preset");
  s.crosshair = r.vec3(r.at(j, "crosshair", "crosshair"), "crosshair");
  const json& rot = r.at(j, "mprRotation", "mprRotation");
  if (!rot.is_array() || rot.size() != 3) r.fail("mprRotation", "expected three rows of three numbers");
  for (std::size_t row = 0; row < 3; ++row) {
    const Vec3 v = r.vec3(rot[row], "mprRotation");
    s.mprRotation.m[row][0] = v.x;
    s.mprRotation.m[row][1] = v.y;
    s.mprRotation.m[row][2] = v.z;
  }
  // A rotation: orthonormal with determinant +1 (to rounding).
  {
    const Vec3 c0 = s.mprRotation.column(0), c1 = s.mprRotation.column(1), c2 = s.mprRotation.column(2);
    const double err = std::abs(dot(c0, c0) - 1) + std::abs(dot(c1, c1) - 1) + std::abs(dot(c2, c2) - 1) +
                       std::abs(dot(c0, c1)) + std::abs(dot(c0, c2)) + std::abs(dot(c1, c2)) +
                       std::abs(dot(cross(c0, c1), c2) - 1);
    if (err > 1e-6) r.fail("mprRotation", "not a rotation matrix");
  }
  const json& slab = r.at(j, "slab", "slab");
  rejectUnknown(slab, {"mode", "thicknessMm"}, r, "slab");
  s.slab = r.name(slab, "mode", "slab.mode", kSlabs, "slab mode");
  s.slabMm = r.positive(slab, "thicknessMm", "slab.thicknessMm");
  const json& views = r.at(j, "mprViews", "mprViews");
  rejectUnknown(views, {"axial", "coronal", "sagittal"}, r, "mprViews");
  for (int v = 0; v < 3; ++v) {
    const std::string name = viewName(static_cast<ViewId>(v));
    const json& m = r.at(views, name, "mprViews." + name);
    rejectUnknown(m, {"zoom", "panRightMm", "panDownMm"}, r, "mprViews." + name);
    MprViewState& state = s.mprViews[static_cast<std::size_t>(v)];
    state.zoom = r.positive(m, "zoom", "mprViews." + name + ".zoom");
    state.panRightMm = r.number(m, "panRightMm", "mprViews." + name + ".panRightMm");
    state.panDownMm = r.number(m, "panDownMm", "mprViews." + name + ".panDownMm");
  }
  const json& measurements = r.at(j, "measurements", "measurements");
  if (!measurements.is_array()) r.fail("measurements", "expected an array");
  for (std::size_t i = 0; i < measurements.size(); ++i) {
    const std::string field = fmt::format("measurements[{}]", i);
    const json& m = measurements[i];
    rejectUnknown(m, {"kind", "view", "points", "right", "down"}, r, field);
    Measurement out;
    out.kind = r.name(m, "kind", field + ".kind", kMeasures, "measurement kind");
    out.view = r.name(m, "view", field + ".view", kViews, "view");
    if (!isMpr(out.view)) r.fail(field + ".view", "measurements belong to MPR views");
    const json& points = r.at(m, "points", field + ".points");
    const std::size_t want = out.kind == MeasureKind::Angle ? 3 : 2;
    if (!points.is_array() || points.size() != want) {
      r.fail(field + ".points", fmt::format("expected {} points", want));
    }
    for (const json& p : points) out.points.push_back(r.vec3(p, field + ".points"));
    out.right = r.vec3(r.at(m, "right", field + ".right"), field + ".right");
    out.down = r.vec3(r.at(m, "down", field + ".down"), field + ".down");
    if (std::abs(length(out.right) - 1) > 1e-6 || std::abs(length(out.down) - 1) > 1e-6 ||
        std::abs(dot(out.right, out.down)) > 1e-6) {
      r.fail(field, "right and down must be orthogonal unit vectors");
    }
    s.measurements.push_back(std::move(out));
  }
  const json& overlays = r.at(j, "overlays", "overlays");
  rejectUnknown(overlays, {"annotations", "patientInfo"}, r, "overlays");
  s.overlays = r.boolean(overlays, "annotations", "overlays.annotations");
  s.patientInfo = r.boolean(overlays, "patientInfo", "overlays.patientInfo");
  return s;
}

void saveSession(const Session& session, const std::filesystem::path& path) {
  const std::string text = sessionToJson(session).dump(2) + "\n";
  const std::filesystem::path temporary = path.string() + ".partial";
  {
    std::ofstream out(temporary, std::ios::binary | std::ios::trunc);
    out << text;
    out.flush();
    if (!out) {
      std::error_code ignored;
      std::filesystem::remove(temporary, ignored);
      throw Error(path.string(), "cannot write the session file");
    }
  }
  std::error_code ec;
  std::filesystem::rename(temporary, path, ec);
  if (ec) {
    std::filesystem::remove(temporary, ec);
    throw Error(path.string(), "cannot write the session file (rename failed)");
  }
}

Session loadSession(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error(path.string(), "cannot open the session file");
  json j;
  try {
    j = json::parse(in);
  } catch (const json::exception& e) {
    throw Error(path.string(), std::string("not JSON: ") + e.what());
  }
  return sessionFromJson(j, path.string());
}

}  // namespace octoray::viewer
