// octoray's own transfer-function JSON: strict reading (unknown keys are typos, not
// extensions) and lossless writing (floats widen to double and narrow back exactly).

#include <fmt/format.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <set>

#include "formats.h"
#include "octoray/core/error.h"

namespace octoray::transfer::detail {

void fail(const std::string& path, const std::string& field, const std::string& what) {
  throw Error(path, fmt::format("{}: {}", field, what));
}

namespace {

using nlohmann::json;
using nlohmann::ordered_json;

constexpr const char* kFormatName = "octoray-transfer-function";
constexpr int kFormatVersion = 1;

double number(const json& value, const std::string& path, const std::string& field) {
  if (!value.is_number()) fail(path, field, "expected a number");
  const double v = value.get<double>();
  if (!std::isfinite(v)) fail(path, field, "not a finite number");
  return v;
}

float fraction(const json& value, const std::string& path, const std::string& field) {
  const double v = number(value, path, field);
  if (v < 0 || v > 1) fail(path, field, fmt::format("{} is outside [0, 1]", v));
  return static_cast<float>(v);
}

const json& arrayOf(const json& value, std::size_t width, const std::string& path,
                    const std::string& field) {
  if (!value.is_array() || value.size() != width) {
    fail(path, field, fmt::format("expected an array of {} numbers", width));
  }
  return value;
}

void rejectUnknownKeys(const json& object, const std::set<std::string>& known,
                       const std::string& path, const std::string& field) {
  for (const auto& item : object.items()) {
    if (!known.contains(item.key())) fail(path, field, fmt::format("unknown key '{}'", item.key()));
  }
}

Material parseMaterial(const json& object, const std::string& path, const std::string& field) {
  if (!object.is_object()) fail(path, field, "expected an object");
  rejectUnknownKeys(object, {"shade", "ambient", "diffuse", "specular", "specularPower"}, path,
                    field);
  Material m;
  if (object.contains("shade")) {
    if (!object["shade"].is_boolean()) fail(path, field + ".shade", "expected true or false");
    m.shade = object["shade"].get<bool>();
  }
  if (object.contains("ambient")) m.ambient = fraction(object["ambient"], path, field + ".ambient");
  if (object.contains("diffuse")) m.diffuse = fraction(object["diffuse"], path, field + ".diffuse");
  if (object.contains("specular")) {
    m.specular = fraction(object["specular"], path, field + ".specular");
  }
  if (object.contains("specularPower")) {
    m.specularPower =
        static_cast<float>(number(object["specularPower"], path, field + ".specularPower"));
  }
  return m;
}

TransferFunction parseOne(const json& object, const std::string& path, const std::string& field) {
  if (!object.is_object()) fail(path, field, "expected an object");
  rejectUnknownKeys(object,
                    {"name", "description", "unitDistanceMm", "interpolation", "color", "opacity",
                     "gradientOpacity", "material"},
                    path, field);
  TransferFunction tf;
  if (!object.contains("name") || !object["name"].is_string() ||
      object["name"].get<std::string>().empty()) {
    fail(path, field + ".name", "expected a non-empty string");
  }
  tf.name = object["name"].get<std::string>();
  if (object.contains("description")) {
    if (!object["description"].is_string()) fail(path, field + ".description", "expected a string");
    tf.description = object["description"].get<std::string>();
  }
  if (object.contains("unitDistanceMm")) {
    tf.unitDistanceMm = number(object["unitDistanceMm"], path, field + ".unitDistanceMm");
  }
  if (object.contains("interpolation")) {
    const json& mode = object["interpolation"];
    if (mode == "linear") {
      tf.interpolation = Interpolation::Linear;
    } else if (mode == "nearest") {
      tf.interpolation = Interpolation::Nearest;
    } else {
      fail(path, field + ".interpolation", "expected \"linear\" or \"nearest\"");
    }
  }
  for (const char* key : {"color", "opacity"}) {
    if (!object.contains(key) || !object[key].is_array()) {
      fail(path, fmt::format("{}.{}", field, key), "expected an array of control points");
    }
  }
  const json& colors = object["color"];
  for (std::size_t i = 0; i < colors.size(); ++i) {
    const std::string at = fmt::format("{}.color[{}]", field, i);
    const json& p = arrayOf(colors[i], 4, path, at);
    tf.color.push_back({number(p[0], path, at), fraction(p[1], path, at),
                        fraction(p[2], path, at), fraction(p[3], path, at)});
  }
  const json& opacities = object["opacity"];
  for (std::size_t i = 0; i < opacities.size(); ++i) {
    const std::string at = fmt::format("{}.opacity[{}]", field, i);
    const json& p = arrayOf(opacities[i], 2, path, at);
    tf.opacity.push_back({number(p[0], path, at), fraction(p[1], path, at)});
  }
  if (object.contains("gradientOpacity")) {
    const json& gradients = object["gradientOpacity"];
    if (!gradients.is_array()) fail(path, field + ".gradientOpacity", "expected an array");
    for (std::size_t i = 0; i < gradients.size(); ++i) {
      const std::string at = fmt::format("{}.gradientOpacity[{}]", field, i);
      const json& p = arrayOf(gradients[i], 2, path, at);
      tf.gradientOpacity.push_back({number(p[0], path, at), fraction(p[1], path, at)});
    }
  }
  if (object.contains("material")) tf.material = parseMaterial(object["material"], path, field + ".material");
  return tf;
}

// The double whose shortest decimal form is the float's (0.1f is written "0.1", not
// "0.10000000149011612"); it narrows back to the same float, so the round trip stays exact.
double tidy(float value) {
  char text[32];
  const auto result = std::to_chars(text, text + sizeof(text) - 1, value);
  double widened = value;
  std::from_chars(text, result.ptr, widened);  // locale-independent, unlike strtod
  return widened;
}

// Indented JSON with each control point ([value, r, g, b]) on one line, so a preset reads
// as a table and diffs line by line.
void writeReadable(const ordered_json& value, int depth, std::string& out) {
  const std::string indent(static_cast<std::size_t>(depth + 1) * 2, ' ');
  const std::string closing(static_cast<std::size_t>(depth) * 2, ' ');
  const bool flat = value.is_array() && std::all_of(value.begin(), value.end(),
                                                    [](const ordered_json& v) { return v.is_primitive(); });
  if (value.is_primitive() || value.empty() || flat) {
    out += value.dump();
  } else if (value.is_array()) {
    out += "[\n";
    for (std::size_t i = 0; i < value.size(); ++i) {
      out += indent;
      writeReadable(value[i], depth + 1, out);
      out += i + 1 < value.size() ? ",\n" : "\n";
    }
    out += closing + "]";
  } else {
    out += "{\n";
    std::size_t i = 0;
    for (const auto& item : value.items()) {
      out += indent + ordered_json(item.key()).dump() + ": ";
      writeReadable(item.value(), depth + 1, out);
      out += ++i < value.size() ? ",\n" : "\n";
    }
    out += closing + "}";
  }
}

}  // namespace

std::vector<TransferFunction> parseOctorayJson(const json& root, const std::string& path) {
  if (!root.is_object()) fail(path, "(top level)", "expected an object");
  rejectUnknownKeys(root, {"format", "version", "transferFunctions"}, path, "(top level)");
  if (!root.contains("format") || root["format"] != kFormatName) {
    fail(path, "format", fmt::format("expected \"{}\"", kFormatName));
  }
  if (!root.contains("version") || !root["version"].is_number_integer() ||
      root["version"].get<int64_t>() != kFormatVersion) {
    fail(path, "version", fmt::format("expected {} (the only version this build reads)",
                                      kFormatVersion));
  }
  if (!root.contains("transferFunctions") || !root["transferFunctions"].is_array() ||
      root["transferFunctions"].empty()) {
    fail(path, "transferFunctions", "expected a non-empty array");
  }
  std::vector<TransferFunction> tfs;
  std::set<std::string> names;
  const json& list = root["transferFunctions"];
  for (std::size_t i = 0; i < list.size(); ++i) {
    const std::string field = fmt::format("transferFunctions[{}]", i);
    tfs.push_back(parseOne(list[i], path, field));
    if (!names.insert(tfs.back().name).second) {
      fail(path, field + ".name", fmt::format("'{}' appears twice", tfs.back().name));
    }
  }
  return tfs;
}

std::string toOctorayJsonText(const std::vector<TransferFunction>& tfs) {
  ordered_json list = ordered_json::array();
  for (const TransferFunction& tf : tfs) {
    ordered_json object;
    object["name"] = tf.name;
    if (!tf.description.empty()) object["description"] = tf.description;
    object["unitDistanceMm"] = tf.unitDistanceMm;
    object["interpolation"] = tf.interpolation == Interpolation::Linear ? "linear" : "nearest";
    ordered_json color = ordered_json::array();
    for (const ColorPoint& p : tf.color) color.push_back({p.value, tidy(p.r), tidy(p.g), tidy(p.b)});
    object["color"] = std::move(color);
    ordered_json opacity = ordered_json::array();
    for (const OpacityPoint& p : tf.opacity) opacity.push_back({p.value, tidy(p.alpha)});
    object["opacity"] = std::move(opacity);
    ordered_json gradient = ordered_json::array();
    for (const GradientOpacityPoint& p : tf.gradientOpacity) {
      gradient.push_back({p.magnitude, tidy(p.alpha)});
    }
    object["gradientOpacity"] = std::move(gradient);
    object["material"] = {{"shade", tf.material.shade},
                          {"ambient", tidy(tf.material.ambient)},
                          {"diffuse", tidy(tf.material.diffuse)},
                          {"specular", tidy(tf.material.specular)},
                          {"specularPower", tidy(tf.material.specularPower)}};
    list.push_back(std::move(object));
  }
  const ordered_json root = {
      {"format", kFormatName}, {"version", kFormatVersion}, {"transferFunctions", list}};
  std::string text;
  writeReadable(root, 0, text);
  return text + "\n";
}

}  // namespace octoray::transfer::detail
