#pragma once
// One parser per input format (internal to octoray_transfer); loadTransferFunctions picks one.
// Each returns unvalidated functions and throws octoray::Error(path, ...) on malformed input.

#include <nlohmann/json.hpp>

#include <string>
#include <vector>

#include "octoray/transfer/transfer_function.h"

namespace octoray::transfer::detail {

// Throws octoray::Error(path, "FIELD: WHAT"): how every parser here reports malformed input.
[[noreturn]] void fail(const std::string& path, const std::string& field, const std::string& what);

// octoray JSON (docs/transfer-function-json.md).
std::vector<TransferFunction> parseOctorayJson(const nlohmann::json& root, const std::string& path);
std::string toOctorayJsonText(const std::vector<TransferFunction>& tfs);

// 3D Slicer presets.xml: one function per <VolumeProperty> element.
std::vector<TransferFunction> parseSlicerXml(const std::string& text, const std::string& path);
// 3D Slicer .vp: nine lines (interpolation, shade, ambient, diffuse, specular, specular
// power, scalar opacity, gradient opacity, colour).
TransferFunction parseSlicerVp(const std::string& text, const std::string& path,
                               const std::string& name);
// 3D Slicer .vp.json (volume-property-schema-v1.0.0.json).
std::vector<TransferFunction> parseSlicerVpJson(const nlohmann::json& root,
                                                const std::string& path,
                                                const std::string& stem);
// ParaView colour maps: an array of {Name, RGBPoints, Points?}.
std::vector<TransferFunction> parseParaViewJson(const nlohmann::json& root,
                                                const std::string& path);

// VTK's "count v1 a1 v2 a2 ..." / "count v r g b ..." encodings, shared by .xml and .vp.
std::vector<OpacityPoint> parseVtkOpacity(const std::string& text, const std::string& path,
                                          const std::string& field);
std::vector<GradientOpacityPoint> parseVtkGradientOpacity(const std::string& text,
                                                          const std::string& path,
                                                          const std::string& field);
std::vector<ColorPoint> parseVtkColor(const std::string& text, const std::string& path,
                                      const std::string& field);
// One finite number, the whole of `text` (surrounding white space allowed).
double parseNumber(const std::string& text, const std::string& path, const std::string& field);

}  // namespace octoray::transfer::detail
