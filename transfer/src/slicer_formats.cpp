// 3D Slicer's volume-property formats: presets.xml (MRML VolumeProperty elements, parsed with
// expat), the line-based .vp and the JSON .vp.json. All three carry VTK's piecewise functions;
// the XML and .vp flatten them as "count x1 y1 x2 y2 ..." strings.

#include <expat.h>
#include <fmt/format.h>
#include <fmt/ranges.h>

#include <charconv>
#include <cmath>
#include <limits>
#include <map>
#include <memory>
#include <sstream>
#include <string_view>

#include "formats.h"
#include "octoray/core/error.h"

namespace octoray::transfer::detail {
namespace {

using nlohmann::json;

std::vector<std::string> tokens(const std::string& text) {
  std::vector<std::string> words;
  std::istringstream stream(text);
  for (std::string word; stream >> word;) words.push_back(word);
  return words;
}

// "count v1 ... v_count": the numbers after the count, checked against it and `tuple`.
std::vector<double> vtkNumbers(const std::string& text, std::size_t tuple, const std::string& path,
                               const std::string& field) {
  const std::vector<std::string> words = tokens(text);
  if (words.empty()) fail(path, field, "is empty (expected \"count v1 v2 ...\")");
  const double count = parseNumber(words[0], path, field + " count");
  if (count < 0 || count != std::floor(count)) {
    fail(path, field, fmt::format("count '{}' is not a non-negative integer", words[0]));
  }
  if (static_cast<double>(words.size() - 1) != count) {
    fail(path, field, fmt::format("count says {} numbers but {} follow", words[0], words.size() - 1));
  }
  if ((words.size() - 1) % tuple != 0) {
    fail(path, field, fmt::format("{} numbers do not form groups of {}", words.size() - 1, tuple));
  }
  std::vector<double> numbers;
  for (std::size_t i = 1; i < words.size(); ++i) {
    numbers.push_back(parseNumber(words[i], path, fmt::format("{} number {}", field, i)));
  }
  return numbers;
}

float toFloat(double v) { return static_cast<float>(v); }

Interpolation interpolationFromVtk(double code, const std::string& path, const std::string& field) {
  if (code == 0) return Interpolation::Nearest;
  if (code == 1) return Interpolation::Linear;
  fail(path, field, fmt::format("{} is not 0 (nearest) or 1 (linear)", code));
}

bool flagFromText(const std::string& text, const std::string& path, const std::string& field) {
  const double v = parseNumber(text, path, field);
  if (v != 0 && v != 1) fail(path, field, fmt::format("{} is not 0 or 1", text));
  return v == 1;
}

// Collects the attributes of every <VolumeProperty> element; expat reports malformed XML.
struct XmlState {
  std::vector<std::map<std::string, std::string>> elements;
};

void XMLCALL startElement(void* user, const XML_Char* name, const XML_Char** attributes) {
  if (std::string_view(name) != "VolumeProperty") return;
  auto* state = static_cast<XmlState*>(user);
  std::map<std::string, std::string>& element = state->elements.emplace_back();
  for (std::size_t i = 0; attributes[i] != nullptr; i += 2) element[attributes[i]] = attributes[i + 1];
}

TransferFunction fromXmlElement(const std::map<std::string, std::string>& element,
                                const std::string& path, std::size_t index) {
  auto field = [&](const std::string& key) {
    const auto it = element.find("name");
    return fmt::format("VolumeProperty {} ('{}') {}", index,
                       it == element.end() ? std::string("?") : it->second, key);
  };
  auto get = [&](const std::string& key) -> const std::string& {
    const auto it = element.find(key);
    if (it == element.end()) fail(path, field(key), "attribute is missing");
    return it->second;
  };
  TransferFunction tf;
  tf.name = get("name");
  if (tf.name.empty()) fail(path, field("name"), "is empty");
  tf.opacity = parseVtkOpacity(get("scalarOpacity"), path, field("scalarOpacity"));
  tf.color = parseVtkColor(get("colorTransfer"), path, field("colorTransfer"));
  if (element.contains("gradientOpacity")) {
    tf.gradientOpacity =
        parseVtkGradientOpacity(get("gradientOpacity"), path, field("gradientOpacity"));
  }
  // Material attributes are optional in MRML; absent ones keep VTK's defaults.
  if (element.contains("shade")) tf.material.shade = flagFromText(get("shade"), path, field("shade"));
  const std::pair<const char*, float Material::*> materialKeys[] = {
      {"ambient", &Material::ambient},
      {"diffuse", &Material::diffuse},
      {"specular", &Material::specular},
      {"specularPower", &Material::specularPower}};
  for (const auto& [key, member] : materialKeys) {
    if (element.contains(key)) tf.material.*member = toFloat(parseNumber(get(key), path, field(key)));
  }
  if (element.contains("interpolation")) {
    tf.interpolation = interpolationFromVtk(
        parseNumber(get("interpolation"), path, field("interpolation")), path, field("interpolation"));
  }
  return tf;
}

// A .vp.json piecewise function: {"points": [{"x", "y", "midpoint"?, "sharpness"?}, ...]}.
std::vector<std::pair<double, json>> jsonPoints(const json& function, const std::string& path,
                                                const std::string& field, const char* yKey) {
  if (!function.is_object() || !function.contains("points") || !function["points"].is_array()) {
    fail(path, field, "expected an object with a \"points\" array");
  }
  std::vector<std::pair<double, json>> points;
  const json& list = function["points"];
  for (std::size_t i = 0; i < list.size(); ++i) {
    const std::string at = fmt::format("{}.points[{}]", field, i);
    const json& p = list[i];
    if (!p.is_object() || !p.contains("x") || !p["x"].is_number() || !p.contains(yKey)) {
      fail(path, at, fmt::format("expected an object with numbers \"x\" and \"{}\"", yKey));
    }
    // Only VTK's default shape (linear between points) is representable.
    if ((p.contains("midpoint") && p["midpoint"] != 0.5) ||
        (p.contains("sharpness") && p["sharpness"] != 0.0)) {
      fail(path, at, "midpoint/sharpness other than 0.5/0 (non-linear segments) is not supported");
    }
    points.emplace_back(p["x"].get<double>(), p[yKey]);
  }
  return points;
}

float jsonFraction(const json& value, const std::string& path, const std::string& field) {
  if (!value.is_number()) fail(path, field, "expected a number");
  return toFloat(value.get<double>());  // range checked by validate()
}

TransferFunction fromVpJsonComponent(const json& component, const std::string& path,
                                     const std::string& field) {
  if (!component.is_object()) fail(path, field, "expected an object");
  TransferFunction tf;
  if (component.contains("shade")) {
    if (!component["shade"].is_boolean()) fail(path, field + ".shade", "expected true or false");
    tf.material.shade = component["shade"].get<bool>();
  } else {
    tf.material.shade = false;  // the schema's default
  }
  if (component.contains("lighting")) {
    const json& lighting = component["lighting"];
    const std::pair<const char*, float Material::*> keys[] = {{"ambient", &Material::ambient},
                                                               {"diffuse", &Material::diffuse},
                                                               {"specular", &Material::specular},
                                                               {"specularPower", &Material::specularPower}};
    for (const auto& [key, member] : keys) {
      if (!lighting.is_object() || !lighting.contains(key) || !lighting[key].is_number()) {
        fail(path, fmt::format("{}.lighting.{}", field, key), "expected a number");
      }
      tf.material.*member = toFloat(lighting[key].get<double>());
    }
  }
  if (component.contains("scalarOpacityUnitDistance")) {
    if (!component["scalarOpacityUnitDistance"].is_number()) {
      fail(path, field + ".scalarOpacityUnitDistance", "expected a number");
    }
    tf.unitDistanceMm = component["scalarOpacityUnitDistance"].get<double>();
  }
  if (!component.contains("scalarOpacity")) fail(path, field + ".scalarOpacity", "is missing");
  for (const auto& [x, y] : jsonPoints(component["scalarOpacity"], path, field + ".scalarOpacity", "y")) {
    tf.opacity.push_back({x, jsonFraction(y, path, field + ".scalarOpacity")});
  }
  const bool gradientDisabled = component.contains("disableGradientOpacity") &&
                                component["disableGradientOpacity"] == true;
  if (component.contains("gradientOpacity") && !gradientDisabled) {
    for (const auto& [x, y] :
         jsonPoints(component["gradientOpacity"], path, field + ".gradientOpacity", "y")) {
      tf.gradientOpacity.push_back({x, jsonFraction(y, path, field + ".gradientOpacity")});
    }
  }
  if (component.contains("rgbTransferFunction")) {
    const std::string at = field + ".rgbTransferFunction";
    for (const auto& [x, c] : jsonPoints(component["rgbTransferFunction"], path, at, "color")) {
      if (!c.is_array() || c.size() != 3) fail(path, at, "color must be an array of 3 numbers");
      tf.color.push_back({x, jsonFraction(c[0], path, at), jsonFraction(c[1], path, at),
                          jsonFraction(c[2], path, at)});
    }
  } else if (component.contains("grayTransferFunction")) {
    const std::string at = field + ".grayTransferFunction";
    for (const auto& [x, y] : jsonPoints(component["grayTransferFunction"], path, at, "y")) {
      const float grey = jsonFraction(y, path, at);
      tf.color.push_back({x, grey, grey, grey});
    }
  } else {
    fail(path, field, "has neither rgbTransferFunction nor grayTransferFunction");
  }
  return tf;
}

}  // namespace

double parseNumber(const std::string& text, const std::string& path, const std::string& field) {
  const std::size_t begin = text.find_first_not_of(" \t\r\n");
  const std::size_t end = text.find_last_not_of(" \t\r\n");
  if (begin == std::string::npos) fail(path, field, "expected a number, found nothing");
  const char* first = text.data() + begin;
  const char* last = text.data() + end + 1;
  if (*first == '+') ++first;  // from_chars rejects a leading '+', which VTK may write
  double value = 0;
  const auto [ptr, ec] = std::from_chars(first, last, value);
  if (ec != std::errc() || ptr != last || !std::isfinite(value)) {
    fail(path, field, fmt::format("'{}' is not a finite number", text.substr(begin, end - begin + 1)));
  }
  return value;
}

std::vector<OpacityPoint> parseVtkOpacity(const std::string& text, const std::string& path,
                                          const std::string& field) {
  const std::vector<double> n = vtkNumbers(text, 2, path, field);
  std::vector<OpacityPoint> points;
  for (std::size_t i = 0; i < n.size(); i += 2) points.push_back({n[i], toFloat(n[i + 1])});
  return points;
}

std::vector<GradientOpacityPoint> parseVtkGradientOpacity(const std::string& text,
                                                          const std::string& path,
                                                          const std::string& field) {
  const std::vector<double> n = vtkNumbers(text, 2, path, field);
  std::vector<GradientOpacityPoint> points;
  for (std::size_t i = 0; i < n.size(); i += 2) points.push_back({n[i], toFloat(n[i + 1])});
  return points;
}

std::vector<ColorPoint> parseVtkColor(const std::string& text, const std::string& path,
                                      const std::string& field) {
  const std::vector<double> n = vtkNumbers(text, 4, path, field);
  std::vector<ColorPoint> points;
  for (std::size_t i = 0; i < n.size(); i += 4) {
    points.push_back({n[i], toFloat(n[i + 1]), toFloat(n[i + 2]), toFloat(n[i + 3])});
  }
  return points;
}

std::vector<TransferFunction> parseSlicerXml(const std::string& text, const std::string& path) {
  XmlState state;
  std::unique_ptr<XML_ParserStruct, decltype(&XML_ParserFree)> parser(XML_ParserCreate(nullptr),
                                                                      &XML_ParserFree);
  if (!parser) throw Error(path, "cannot create an XML parser (out of memory)");
  XML_SetUserData(parser.get(), &state);
  XML_SetStartElementHandler(parser.get(), &startElement);
  if (text.size() > static_cast<std::size_t>(std::numeric_limits<int>::max()) ||
      XML_Parse(parser.get(), text.data(), static_cast<int>(text.size()), XML_TRUE) ==
          XML_STATUS_ERROR) {
    throw Error(path, fmt::format("not well-formed XML at line {}, column {}: {}",
                                  XML_GetCurrentLineNumber(parser.get()),
                                  XML_GetCurrentColumnNumber(parser.get()),
                                  XML_ErrorString(XML_GetErrorCode(parser.get()))));
  }
  if (state.elements.empty()) throw Error(path, "no <VolumeProperty> element in this XML file");
  std::vector<TransferFunction> tfs;
  for (std::size_t i = 0; i < state.elements.size(); ++i) {
    tfs.push_back(fromXmlElement(state.elements[i], path, i));
  }
  return tfs;
}

TransferFunction parseSlicerVp(const std::string& text, const std::string& path,
                               const std::string& name) {
  // Slicer's vtkMRMLVolumePropertyStorageNode writes these nine lines in this order.
  static const char* const kLines[] = {"interpolation", "shade",          "ambient",
                                       "diffuse",       "specular",       "specularPower",
                                       "scalarOpacity", "gradientOpacity", "colorTransfer"};
  std::vector<std::string> lines;
  std::istringstream stream(text);
  for (std::string line; std::getline(stream, line);) {
    if (line.find_first_not_of(" \t\r") != std::string::npos) lines.push_back(line);
  }
  if (lines.size() != std::size(kLines)) {
    throw Error(path, fmt::format("a .vp file has {} non-empty lines ({}), this one has {}",
                                  std::size(kLines), fmt::join(kLines, ", "), lines.size()));
  }
  auto field = [&](std::size_t i) { return fmt::format("line {} ({})", i + 1, kLines[i]); };
  TransferFunction tf;
  tf.name = name;
  tf.interpolation = interpolationFromVtk(parseNumber(lines[0], path, field(0)), path, field(0));
  tf.material.shade = flagFromText(lines[1], path, field(1));
  tf.material.ambient = toFloat(parseNumber(lines[2], path, field(2)));
  tf.material.diffuse = toFloat(parseNumber(lines[3], path, field(3)));
  tf.material.specular = toFloat(parseNumber(lines[4], path, field(4)));
  tf.material.specularPower = toFloat(parseNumber(lines[5], path, field(5)));
  tf.opacity = parseVtkOpacity(lines[6], path, field(6));
  tf.gradientOpacity = parseVtkGradientOpacity(lines[7], path, field(7));
  tf.color = parseVtkColor(lines[8], path, field(8));
  return tf;
}

std::vector<TransferFunction> parseSlicerVpJson(const json& root, const std::string& path,
                                                const std::string& stem) {
  if (!root.is_object() || !root.contains("volumeProperties") ||
      !root["volumeProperties"].is_array() || root["volumeProperties"].empty()) {
    fail(path, "volumeProperties", "expected a non-empty array");
  }
  const json& list = root["volumeProperties"];
  std::vector<TransferFunction> tfs;
  for (std::size_t i = 0; i < list.size(); ++i) {
    const std::string field = fmt::format("volumeProperties[{}]", i);
    const json& property = list[i];
    if (!property.is_object()) fail(path, field, "expected an object");
    // CT volumes have one scalar component; several independent ones are not renderable here.
    if (!property.contains("components") || !property["components"].is_array() ||
        property["components"].size() != 1) {
      fail(path, field + ".components", "expected exactly one component (scalar volumes only)");
    }
    TransferFunction tf = fromVpJsonComponent(property["components"][0], path,
                                              field + ".components[0]");
    if (property.contains("name") && property["name"].is_string()) {
      tf.name = property["name"].get<std::string>();
    } else {
      tf.name = list.size() == 1 ? stem : fmt::format("{}-{}", stem, i);
    }
    if (property.contains("interpolationType")) {
      const json& type = property["interpolationType"];
      if (type == "nearest") {
        tf.interpolation = Interpolation::Nearest;
      } else if (type == "linear" || type == "cubic") {  // cubic: linear is the nearest we have
        tf.interpolation = Interpolation::Linear;
      } else {
        fail(path, field + ".interpolationType", "expected \"nearest\", \"linear\" or \"cubic\"");
      }
    }
    tfs.push_back(std::move(tf));
  }
  return tfs;
}

}  // namespace octoray::transfer::detail
