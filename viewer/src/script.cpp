#include "octoray/viewer/script.h"

#include <fmt/format.h>

#include <cmath>
#include <fstream>
#include <map>
#include <set>

#include "octoray/core/error.h"

namespace octoray::viewer {
namespace {

using json = nlohmann::json;

struct StepReader {
  const std::string& path;
  std::size_t index;

  [[noreturn]] void fail(const std::string& what) const {
    throw Error(path, fmt::format("script step {}: {}", index, what));
  }
  std::array<double, 2> pair(const json& v, const char* field) const {
    if (!v.is_array() || v.size() != 2 || !v[0].is_number() || !v[1].is_number() ||
        !std::isfinite(v[0].get<double>()) || !std::isfinite(v[1].get<double>())) {
      fail(fmt::format("\"{}\": expected [x, y]", field));
    }
    return {v[0].get<double>(), v[1].get<double>()};
  }
  ScriptPosition position(const json& v, const char* field) const {
    ScriptPosition p;
    if (v.is_array()) {
      p.window = pair(v, field);
      return p;
    }
    if (!v.is_object() || !v.contains("view") || !v["view"].is_string()) {
      fail(fmt::format("\"{}\": expected [x, y] or {{\"view\": ..., \"pixel\"|\"fraction\"|\"patient\": ...}}", field));
    }
    try {
      p.view = parseViewName(v["view"].get<std::string>());
    } catch (const Error& e) {
      fail(fmt::format("\"{}\": {}", field, e.reason()));
    }
    int given = 0;
    if (v.contains("pixel")) p.pixel = pair(v["pixel"], field), ++given;
    if (v.contains("fraction")) p.fraction = pair(v["fraction"], field), ++given;
    if (v.contains("patient")) {
      const json& q = v["patient"];
      if (!q.is_array() || q.size() != 3) fail(fmt::format("\"{}\".patient: expected [x, y, z]", field));
      for (const auto& c : q) {
        if (!c.is_number() || !std::isfinite(c.get<double>())) fail(fmt::format("\"{}\".patient: expected numbers", field));
      }
      p.patient = Vec3{q[0].get<double>(), q[1].get<double>(), q[2].get<double>()};
      if (*p.view == ViewId::Volume) fail(fmt::format("\"{}\": a patient position needs an MPR view", field));
      ++given;
    }
    if (given != 1) fail(fmt::format("\"{}\": give exactly one of pixel, fraction, patient", field));
    return p;
  }
};

MouseButton parseButton(const std::string& name, const StepReader& r) {
  if (name == "left") return MouseButton::Left;
  if (name == "right") return MouseButton::Right;
  if (name == "middle") return MouseButton::Middle;
  r.fail(fmt::format("unknown button \"{}\" (left, right, middle)", name));
}

int parseMods(const json& v, const StepReader& r) {
  if (!v.is_array()) r.fail("\"mods\": expected a list of \"shift\", \"ctrl\", \"alt\"");
  int mods = 0;
  for (const auto& m : v) {
    const std::string s = m.is_string() ? m.get<std::string>() : "";
    if (s == "shift") mods |= kShift;
    else if (s == "ctrl") mods |= kCtrl;
    else if (s == "alt") mods |= kAlt;
    else r.fail(fmt::format("unknown modifier {}", m.dump()));
  }
  return mods;
}

}  // namespace

std::vector<ScriptStep> parseScript(const json& root, const std::string& path) {
  const json* events = &root;
  if (root.is_object()) {
    if (!root.contains("format") || root["format"] != "octoray-view-script" || !root.contains("events")) {
      throw Error(path, "expected {\"format\": \"octoray-view-script\", \"events\": [...]}");
    }
    events = &root["events"];
  }
  if (!events->is_array()) throw Error(path, "script: \"events\" must be a list");
  static const std::map<std::string, ScriptStep::Type> kTypes{
      {"move", ScriptStep::Type::Move},          {"press", ScriptStep::Type::Press},
      {"release", ScriptStep::Type::Release},    {"click", ScriptStep::Type::Click},
      {"drag", ScriptStep::Type::Drag},          {"wheel", ScriptStep::Type::Wheel},
      {"key", ScriptStep::Type::Key},            {"action", ScriptStep::Type::Action},
      {"wait-converged", ScriptStep::Type::WaitConverged},
      {"wait-preview", ScriptStep::Type::WaitPreview},
      {"screenshot", ScriptStep::Type::Screenshot},
      {"save-session", ScriptStep::Type::SaveSession},
      {"load-session", ScriptStep::Type::LoadSession},
      {"dump-state", ScriptStep::Type::DumpState},   {"quit", ScriptStep::Type::Quit}};
  static const std::set<std::string> kKnown{"type", "wait", "at", "from", "to", "button", "mods",
                                            "steps", "double", "dy", "key", "name", "value",
                                            "path", "view", "patientInfo", "timeout",
                                            "fraction"};
  std::vector<ScriptStep> out;
  for (std::size_t i = 0; i < events->size(); ++i) {
    const json& e = (*events)[i];
    const StepReader r{path, i};
    if (!e.is_object() || !e.contains("type") || !e["type"].is_string()) r.fail("expected an object with \"type\"");
    for (const auto& [key, value] : e.items()) {
      if (!kKnown.contains(key)) r.fail(fmt::format("unknown field \"{}\"", key));
    }
    const auto type = kTypes.find(e["type"].get<std::string>());
    if (type == kTypes.end()) r.fail(fmt::format("unknown type \"{}\"", e["type"].get<std::string>()));
    ScriptStep s;
    s.type = type->second;
    if (e.contains("wait")) {
      if (!e["wait"].is_number_integer() || e["wait"].get<int>() < 0) r.fail("\"wait\": expected frames >= 0");
      s.wait = e["wait"].get<int>();
    }
    if (e.contains("button")) s.button = parseButton(e["button"].is_string() ? e["button"].get<std::string>() : "", r);
    if (e.contains("mods")) s.mods = parseMods(e["mods"], r);
    if (e.contains("double")) s.doubleClick = e["double"].is_boolean() && e["double"].get<bool>();
    auto need = [&](const char* field) {
      if (!e.contains(field)) r.fail(fmt::format("\"{}\" is required for {}", field, e["type"].get<std::string>()));
      return e[field];
    };
    switch (s.type) {
      case ScriptStep::Type::Move:
      case ScriptStep::Type::Press:
      case ScriptStep::Type::Release:
      case ScriptStep::Type::Click:
        s.at = r.position(need("at"), "at");
        break;
      case ScriptStep::Type::Drag:
        s.at = r.position(need("from"), "from");
        s.to = r.position(need("to"), "to");
        if (e.contains("steps")) {
          if (!e["steps"].is_number_integer() || e["steps"].get<int>() < 1) r.fail("\"steps\": expected >= 1");
          s.steps = e["steps"].get<int>();
        }
        break;
      case ScriptStep::Type::Wheel: {
        s.at = r.position(need("at"), "at");
        const json& dy = need("dy");
        if (!dy.is_number() || !std::isfinite(dy.get<double>())) r.fail("\"dy\": expected notches");
        s.wheel = dy.get<double>();
        break;
      }
      case ScriptStep::Type::Key: {
        const json& k = need("key");
        if (!k.is_string() || k.get<std::string>().empty()) r.fail("\"key\": expected a key name");
        s.key = k.get<std::string>();
        break;
      }
      case ScriptStep::Type::Action: {
        const json& n = need("name");
        if (!n.is_string()) r.fail("\"name\": expected an action name");
        s.name = n.get<std::string>();
        if (e.contains("value")) s.value = e["value"];
        break;
      }
      case ScriptStep::Type::WaitPreview: {
        const json& f = need("fraction");
        if (!f.is_number() || !(f.get<double>() > 0 && f.get<double>() <= 1)) {
          r.fail("\"fraction\": expected a share of the slices in (0, 1]");
        }
        s.fraction = f.get<double>();
        [[fallthrough]];
      }
      case ScriptStep::Type::WaitConverged:
        if (e.contains("timeout")) {
          if (!e["timeout"].is_number() || !(e["timeout"].get<double>() > 0)) r.fail("\"timeout\": expected seconds");
          s.timeoutSeconds = e["timeout"].get<double>();
        }
        break;
      case ScriptStep::Type::Screenshot:
        if (e.contains("view")) {
          if (!e["view"].is_string()) r.fail("\"view\": expected a view name");
          try {
            s.view = parseViewName(e["view"].get<std::string>());
          } catch (const Error& err) {
            r.fail(err.reason());
          }
        }
        if (e.contains("patientInfo") && !e["patientInfo"].is_boolean()) {
          r.fail("\"patientInfo\": expected true or false");
        }
        s.patientInfo = e.value("patientInfo", false);
        [[fallthrough]];
      case ScriptStep::Type::SaveSession:
      case ScriptStep::Type::LoadSession:
      case ScriptStep::Type::DumpState: {
        const json& p = need("path");
        if (!p.is_string() || p.get<std::string>().empty()) r.fail("\"path\": expected a file name");
        s.path = p.get<std::string>();
        break;
      }
      case ScriptStep::Type::Quit:
        break;
    }
    out.push_back(std::move(s));
  }
  return out;
}

std::vector<ScriptStep> loadScript(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error(path.string(), "cannot open the script");
  json j;
  try {
    j = json::parse(in);
  } catch (const json::exception& e) {
    throw Error(path.string(), std::string("not JSON: ") + e.what());
  }
  return parseScript(j, path.string());
}

}  // namespace octoray::viewer
