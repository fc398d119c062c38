#include "octoray/gpu/camera_path.h"

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <optional>
#include <sstream>

#include "octoray/core/error.h"

namespace octoray::gpu {
namespace {

double number(const std::string& spec, const std::string& key, const std::string& text) {
  char* end = nullptr;
  const double v = std::strtod(text.c_str(), &end);
  if (text.empty() || end != text.c_str() + text.size() || !std::isfinite(v)) {
    throw Error("", fmt::format("--path \"{}\": {} \"{}\" is not a number", spec, key, text));
  }
  return v;
}

std::vector<Camera> orbitPath(const std::string& spec, const VolumeDomain& domain,
                              const OrbitParameters& start) {
  std::istringstream parts(spec);
  std::string part;
  int frames = 0, still = 0;
  double degrees = 360, zoomFrom = start.zoom, zoomTo = start.zoom;
  bool first = true;
  while (std::getline(parts, part, ',')) {
    const auto colon = part.find(':');
    if (colon == std::string::npos) {
      throw Error("", fmt::format("--path \"{}\": \"{}\" is not KEY:VALUE", spec, part));
    }
    const std::string key = part.substr(0, colon), value = part.substr(colon + 1);
    const double v = number(spec, key, value);
    if (first != (key == "orbit")) {
      throw Error("", fmt::format("--path \"{}\": orbit:N comes first, once", spec));
    }
    first = false;
    if (key == "orbit") {
      if (v < 1 || v > 1e6 || v != std::floor(v)) {
        throw Error("", fmt::format("--path \"{}\": orbit:N needs a whole N in [1, 1e6]", spec));
      }
      frames = static_cast<int>(v);
    } else if (key == "degrees") {
      degrees = v;
    } else if (key == "zoom-from") {
      zoomFrom = v;
    } else if (key == "zoom-to") {
      zoomTo = v;
    } else if (key == "still") {
      if (v < 0 || v > 1e6 || v != std::floor(v)) {
        throw Error("", fmt::format("--path \"{}\": still:S needs a whole S >= 0", spec));
      }
      still = static_cast<int>(v);
    } else {
      throw Error("", fmt::format("--path \"{}\": unknown key \"{}\" (orbit, degrees, "
                                  "zoom-from, zoom-to, still)", spec, key));
    }
  }
  if (frames == 0) throw Error("", fmt::format("--path \"{}\": expected orbit:N", spec));
  if (!(zoomFrom > 0) || !(zoomTo > 0)) {
    throw Error("", fmt::format("--path \"{}\": zooms must be positive", spec));
  }
  std::vector<Camera> cameras;
  cameras.reserve(static_cast<std::size_t>(frames + still));
  for (int f = 0; f < frames; ++f) {
    const double s = frames > 1 ? static_cast<double>(f) / (frames - 1) : 0.0;
    OrbitParameters o = start;
    o.azimuthDegrees = start.azimuthDegrees + degrees * f / frames;
    o.zoom = zoomFrom * std::pow(zoomTo / zoomFrom, s);
    cameras.push_back(orbitCamera(domain, o));
  }
  for (int f = 0; f < still; ++f) cameras.push_back(cameras.back());
  return cameras;
}

}  // namespace

std::vector<Camera> cameraPath(const std::string& spec, const VolumeDomain& domain,
                               const OrbitParameters& start) {
  if (spec.rfind("orbit:", 0) == 0) return orbitPath(spec, domain, start);
  std::ifstream in(spec);
  if (!in) throw Error(spec, "cannot open the camera path (expected orbit:N,... or a JSON file)");
  nlohmann::json json;
  try {
    in >> json;
  } catch (const nlohmann::json::exception& e) {
    throw Error(spec, fmt::format("not JSON: {}", e.what()));
  }
  const nlohmann::json* list = &json;
  if (json.is_object()) {
    if (!json.contains("cameras")) throw Error(spec, "expected {\"cameras\": [...]} or a list");
    list = &json["cameras"];
  }
  if (!list->is_array() || list->empty()) throw Error(spec, "the camera list is empty or not a list");
  std::vector<Camera> cameras;
  for (std::size_t i = 0; i < list->size(); ++i) {
    try {
      cameras.push_back(cameraFromJson((*list)[i], spec));
      cameras.back().validate();
    } catch (const Error& e) {
      throw Error(spec, fmt::format("camera {}: {}", i, e.reason()));
    }
  }
  return cameras;
}

}  // namespace octoray::gpu
