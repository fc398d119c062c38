#pragma once
// Reading and writing transfer functions: octoray's own JSON (docs/transfer-function-json.md)
// and the preset formats CT users bring along — 3D Slicer's presets.xml, its older line-based
// .vp and newer .vp.json files, and ParaView colour-map JSON. Every file is untrusted: a bad
// one throws octoray::Error naming the file and the field at fault.

#include <filesystem>
#include <string>
#include <vector>

#include "octoray/transfer/transfer_function.h"

namespace octoray::transfer {

// Every transfer function in `path`, in file order, validated. The format is recognised from
// the content (first character and top-level keys), the extension breaking ties:
//   '<' ... <VolumeProperty ...>         Slicer presets.xml (one per element)
//   { "volumeProperties": [...] }        Slicer .vp.json (named by "name" or the file stem)
//   { "format": "octoray-transfer-function", ... }  octoray JSON
//   [ { "Name", "RGBPoints", ... } ]     ParaView colour maps
//   numbers on 9 lines                   Slicer .vp (named by the file stem)
std::vector<TransferFunction> loadTransferFunctions(const std::filesystem::path& path);

// Writes octoray JSON: to a temporary name, renamed when complete, so a failure never leaves
// a partial file. Validates first; names must be unique within one file.
void saveTransferFunction(const TransferFunction& tf, const std::filesystem::path& path);
void saveTransferFunctions(const std::vector<TransferFunction>& tfs,
                           const std::filesystem::path& path);

// One transfer function as the text of an octoray JSON file, and back (validated; `path`
// names where the JSON came from in messages): for documents that embed a function, such as
// the viewer's session file.
std::string transferFunctionToJsonText(const TransferFunction& tf);
TransferFunction transferFunctionFromJsonText(const std::string& text, const std::string& path);

// The --tf-name rule: with an empty `name`, the only function in the list (an error when
// there are several, listing them); otherwise the function with exactly that name, or failing
// that the only one whose name matches ignoring case. `path` names the file in messages.
TransferFunction selectTransferFunction(const std::vector<TransferFunction>& tfs,
                                        const std::string& name, const std::string& path = {});

// The folder of shipped presets: $OCTORAY_PRESETS when set, else transfer/presets of the
// source tree this library was built from.
std::filesystem::path presetsDir();
// A shipped preset by name ("bone", "lung", ...): `<presetsDir>/<name>.json` when it exists,
// else any function of that name in the folder's .json files. Throws octoray::Error listing
// the names available when there is none.
TransferFunction findPreset(const std::string& name);
// Names of all presets in presetsDir(), sorted.
std::vector<std::string> presetNames();

}  // namespace octoray::transfer
