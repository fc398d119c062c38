#include "octoray/viewer/presets.h"

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <fstream>
#include <optional>
#include <set>

#include "octoray/core/error.h"

namespace octoray::viewer {

std::vector<WindowLevelPreset> loadWindowLevelPresets(const std::filesystem::path& path) {
  const std::string file = path.string();
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error(file, "cannot open the window/level preset table");
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(in);
  } catch (const nlohmann::json::exception& e) {
    throw Error(file, std::string("not JSON: ") + e.what());
  }
  if (!j.is_object() || !j.contains("format") || j["format"] != "octoray-window-level-presets" ||
      !j.contains("presets") || !j["presets"].is_array()) {
    throw Error(file, "expected {\"format\": \"octoray-window-level-presets\", \"presets\": [...]}");
  }
  std::vector<WindowLevelPreset> out;
  std::set<int> keys;
  std::set<std::string> names;
  for (std::size_t i = 0; i < j["presets"].size(); ++i) {
    const auto& p = j["presets"][i];
    auto bad = [&](const std::string& what) {
      return Error(file, fmt::format("presets[{}]: {}", i, what));
    };
    if (!p.is_object() || !p.contains("name") || !p["name"].is_string() || !p.contains("window") ||
        !p["window"].is_number() || !p.contains("level") || !p["level"].is_number()) {
      throw bad("expected name, window and level");
    }
    // Optional fields: absent, or of their type (never converted: a key of 1.5 is no key).
    const char* const keyRule = "key must be an integer 1-9 (or 0 for none)";
    if (p.contains("key") && !p["key"].is_number_integer()) throw bad(keyRule);
    if (p.contains("source") && !p["source"].is_string()) throw bad("source must be a string");
    WindowLevelPreset w;
    w.name = p["name"].get<std::string>();
    w.window = p["window"].get<double>();
    w.level = p["level"].get<double>();
    const int64_t key = p.contains("key") ? p["key"].get<int64_t>() : 0;
    if (key < 0 || key > 9) throw bad(keyRule);
    w.key = static_cast<int>(key);
    w.source = p.contains("source") ? p["source"].get<std::string>() : std::string();
    if (!std::isfinite(w.window) || w.window < 1 || !std::isfinite(w.level)) {
      throw bad("window must be >= 1 HU and level finite");
    }
    if (w.key != 0 && !keys.insert(w.key).second) throw bad(fmt::format("key {} used twice", w.key));
    if (!names.insert(w.name).second) throw bad(fmt::format("name \"{}\" used twice", w.name));
    out.push_back(std::move(w));
  }
  if (out.empty()) throw Error(file, "no presets");
  return out;
}

void saveWindowLevelPresets(const std::vector<WindowLevelPreset>& presets,
                            const std::filesystem::path& path) {
  nlohmann::ordered_json j;
  j["format"] = "octoray-window-level-presets";
  j["version"] = 1;
  j["presets"] = nlohmann::ordered_json::array();
  for (const auto& p : presets) {
    j["presets"].push_back({{"key", p.key}, {"name", p.name}, {"window", p.window},
                            {"level", p.level}, {"source", p.source}});
  }
  const std::filesystem::path temporary = path.string() + ".partial";
  {
    std::ofstream out(temporary, std::ios::binary | std::ios::trunc);
    out << j.dump(2) << "\n";
    if (!out) throw Error(path.string(), "cannot write the preset table");
  }
  std::filesystem::rename(temporary, path);
}

std::filesystem::path defaultWindowLevelPresetsPath() {
  if (const char* env = std::getenv("OCTORAY_WL_PRESETS"); env && *env) return env;
  return std::filesystem::path(OCTORAY_VIEWER_SOURCE_DIR) / "presets" / "window-level.json";
}

WindowLevelPreset autoWindowLevel(const std::vector<int>& histogram, double lo, double hi) {
  WindowLevelPreset p;
  p.name = "auto";
  p.source = "0.1st to 99.9th percentile of the volume's values";
  const double binWidth = histogram.empty() ? hi - lo : (hi - lo) / static_cast<double>(histogram.size());
  int64_t total = 0;
  for (const int c : histogram) total += c;
  if (total == 0 || !(hi > lo)) {
    p.window = std::max(hi - lo, 1.0);
    p.level = 0.5 * (lo + hi);
    return p;
  }
  // The value below which `fraction` of the samples lie.
  auto percentile = [&](double fraction) {
    const double target = fraction * static_cast<double>(total);
    double below = 0;
    for (std::size_t b = 0; b < histogram.size(); ++b) {
      const double count = histogram[b];
      if (count > 0 && below + count >= target) {
        return lo + (static_cast<double>(b) + (target - below) / count) * binWidth;
      }
      below += count;
    }
    return hi;
  };
  const double low = percentile(0.001), high = percentile(0.999);
  if (high - low < binWidth) {
    // At least 99.8 % of the values in one bin (a mask's zeros): the percentiles say nothing,
    // so the whole range, which shows the rest (a 0/1 mask: W 1 / L 0.5, zeros black).
    p.window = hi - lo;
    p.level = 0.5 * (lo + hi);
    return p;
  }
  p.window = high - low;
  p.level = 0.5 * (low + high);
  return p;
}

int valueDecimals(double range) {
  if (!(range > 0) || !std::isfinite(range)) return 0;
  return std::clamp(2 - static_cast<int>(std::floor(std::log10(range))), 0, 12);
}

double valueStep(double range) {
  if (!(range > 0) || !std::isfinite(range)) return 1;
  return std::pow(10.0, std::floor(std::log10(range)) - 2);
}

std::vector<WindowLevelPreset> fileWindowLevelPresets(const std::vector<SourceWindow>& windows) {
  std::vector<WindowLevelPreset> presets;
  for (const SourceWindow& w : windows) {
    WindowLevelPreset p;
    p.name = presets.empty() ? "file" : fmt::format("file {}", presets.size() + 1);
    p.window = w.width;
    p.level = w.center;
    p.source = w.explanation.empty() ? "the file's WindowCenter / WindowWidth"
                                     : fmt::format("the file's WindowCenter / WindowWidth: {}", w.explanation);
    presets.push_back(std::move(p));
  }
  return presets;
}

}  // namespace octoray::viewer
