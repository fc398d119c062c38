// ParaView colour maps (the JSON its "Export Presets" writes): an array of
// {"Name", "RGBPoints": [x r g b ...], "Points": [x alpha midpoint sharpness ...]?}.
// ParaView interpolates in the map's ColorSpace; we interpolate in RGB, which matches exactly
// for "RGB" maps and closely for the others at the point density presets use.

#include <fmt/format.h>

#include <cmath>

#include "formats.h"
#include "octoray/core/error.h"

namespace octoray::transfer::detail {
namespace {

using nlohmann::json;

std::vector<double> numbers(const json& array, std::size_t tuple, const std::string& path,
                            const std::string& field) {
  if (!array.is_array() || array.empty() || array.size() % tuple != 0) {
    fail(path, field, fmt::format("expected a non-empty array of numbers in groups of {}", tuple));
  }
  std::vector<double> values;
  for (std::size_t i = 0; i < array.size(); ++i) {
    if (!array[i].is_number()) fail(path, fmt::format("{}[{}]", field, i), "expected a number");
    values.push_back(array[i].get<double>());
  }
  return values;
}

}  // namespace

std::vector<TransferFunction> parseParaViewJson(const json& root, const std::string& path) {
  if (!root.is_array() || root.empty()) fail(path, "(top level)", "expected a non-empty array");
  std::vector<TransferFunction> tfs;
  for (std::size_t i = 0; i < root.size(); ++i) {
    const std::string field = fmt::format("[{}]", i);
    const json& map = root[i];
    if (!map.is_object()) fail(path, field, "expected an object");
    // Categorical maps (IndexedColors, no RGBPoints) colour labels, not a value axis.
    if (!map.contains("RGBPoints") && map.contains("IndexedColors")) continue;
    if (!map.contains("Name") || !map["Name"].is_string() ||
        map["Name"].get<std::string>().empty()) {
      fail(path, field + ".Name", "expected a non-empty string");
    }
    TransferFunction tf;
    tf.name = map["Name"].get<std::string>();
    const std::string at = fmt::format("{} ('{}')", field, tf.name);
    if (!map.contains("RGBPoints")) fail(path, at + ".RGBPoints", "is missing");
    const std::vector<double> rgb = numbers(map["RGBPoints"], 4, path, at + ".RGBPoints");
    for (std::size_t k = 0; k < rgb.size(); k += 4) {
      tf.color.push_back({rgb[k], static_cast<float>(rgb[k + 1]), static_cast<float>(rgb[k + 2]),
                          static_cast<float>(rgb[k + 3])});
    }
    if (map.contains("Points")) {
      const std::vector<double> points = numbers(map["Points"], 4, path, at + ".Points");
      for (std::size_t k = 0; k < points.size(); k += 4) {
        if (points[k + 2] != 0.5 || points[k + 3] != 0.0) {
          fail(path, at + ".Points",
               "midpoint/sharpness other than 0.5/0 (non-linear segments) is not supported");
        }
        tf.opacity.push_back({points[k], static_cast<float>(points[k + 1])});
      }
    } else {
      // ParaView's default opacity for a new map: a linear ramp across the colour range.
      tf.opacity = {{tf.color.front().value, 0.0f}, {tf.color.back().value, 1.0f}};
    }
    tf.material.shade = false;  // ParaView volume rendering shades only when asked
    if (map.contains("Description") && map["Description"].is_string()) {
      tf.description = map["Description"].get<std::string>();
    }
    tfs.push_back(std::move(tf));
  }
  if (tfs.empty()) throw Error(path, "no colour map with RGBPoints in this ParaView file");
  return tfs;
}

}  // namespace octoray::transfer::detail
