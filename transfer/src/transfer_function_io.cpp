#include "octoray/transfer/transfer_function_io.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cctype>
#include <cstdlib>
#include <fstream>
#include <set>
#include <sstream>

#include "formats.h"
#include "octoray/core/error.h"
#include "octoray/core/text.h"

#ifndef OCTORAY_TRANSFER_PRESETS_DIR
#error "OCTORAY_TRANSFER_PRESETS_DIR must name the shipped presets folder (transfer/CMakeLists.txt)"
#endif

namespace octoray::transfer {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// Preset files are small; a bound keeps a wrong path (a CT volume) from filling memory.
constexpr std::uintmax_t kMaxFileBytes = 64u << 20;

std::string readText(const fs::path& path) {
  std::error_code error;
  if (!fs::is_regular_file(path, error)) throw Error(path.string(), "not a readable file");
  const std::uintmax_t size = fs::file_size(path, error);
  if (error) throw Error(path.string(), "cannot read the file size: " + error.message());
  if (size > kMaxFileBytes) {
    throw Error(path.string(), fmt::format("{} bytes is too large for a transfer-function file "
                                           "(limit {} MiB)",
                                           size, kMaxFileBytes >> 20));
  }
  std::ifstream file(path, std::ios::binary);
  std::ostringstream text;
  text << file.rdbuf();
  if (!file && !file.eof()) throw Error(path.string(), "read failed");
  return text.str();
}

json parseJson(const std::string& text, const std::string& path) {
  try {
    return json::parse(text);
  } catch (const json::exception& e) {  // parse errors, and number overflow (out_of_range)
    throw Error(path, fmt::format("not valid JSON: {}", e.what()));
  }
}

// "a.vp.json" -> "a", "b.vp" -> "b": the name a single-preset file gives its function.
std::string presetStem(const fs::path& path) {
  std::string stem = path.filename().string();
  for (const char* suffix : {".vp.json", ".json", ".vp", ".xml"}) {
    const std::string s = suffix;
    if (stem.size() > s.size() && asciiLower(stem.substr(stem.size() - s.size())) == s) {
      return stem.substr(0, stem.size() - s.size());
    }
  }
  return path.stem().string();
}

std::vector<TransferFunction> parseByContent(const std::string& text, const fs::path& file) {
  const std::string path = file.string();
  const std::size_t first = text.find_first_not_of(" \t\r\n\xEF\xBB\xBF");  // BOM tolerated
  if (first == std::string::npos) throw Error(path, "the file is empty");
  const std::string extension = asciiLower(file.extension().string());
  switch (text[first]) {
    case '<':
      return detail::parseSlicerXml(text, path);
    case '[':
      return detail::parseParaViewJson(parseJson(text, path), path);
    case '{': {
      const json root = parseJson(text, path);
      if (root.contains("volumeProperties")) {
        return detail::parseSlicerVpJson(root, path, presetStem(file));
      }
      if (root.contains("format") || root.contains("transferFunctions") || extension == ".json") {
        return detail::parseOctorayJson(root, path);
      }
      break;
    }
    default:
      if (std::isdigit(static_cast<unsigned char>(text[first])) || text[first] == '-' ||
          extension == ".vp") {
        return {detail::parseSlicerVp(text, path, presetStem(file))};
      }
      break;
  }
  throw Error(path, "not a transfer-function file this build reads (octoray JSON, Slicer "
                    "presets.xml / .vp / .vp.json, ParaView colour-map JSON)");
}

std::vector<std::string> namesOf(const std::vector<TransferFunction>& tfs) {
  std::vector<std::string> names;
  for (const TransferFunction& tf : tfs) names.push_back(tf.name);
  return names;
}

std::vector<fs::path> presetFiles() {
  const fs::path dir = presetsDir();
  std::error_code error;
  if (!fs::is_directory(dir, error)) {
    throw Error(dir.string(), "the presets folder does not exist (set OCTORAY_PRESETS)");
  }
  std::vector<fs::path> files;
  for (const fs::directory_entry& entry : fs::directory_iterator(dir)) {
    if (entry.is_regular_file() && entry.path().extension() == ".json") files.push_back(entry.path());
  }
  std::sort(files.begin(), files.end());
  return files;
}

}  // namespace

std::vector<TransferFunction> loadTransferFunctions(const fs::path& path) {
  std::vector<TransferFunction> tfs = parseByContent(readText(path), path);
  for (const TransferFunction& tf : tfs) validate(tf, path.string());
  return tfs;
}

void saveTransferFunction(const TransferFunction& tf, const fs::path& path) {
  saveTransferFunctions({tf}, path);
}

std::string transferFunctionToJsonText(const TransferFunction& tf) {
  validate(tf);
  return detail::toOctorayJsonText({tf});
}

TransferFunction transferFunctionFromJsonText(const std::string& text, const std::string& path) {
  nlohmann::json root;
  try {
    root = nlohmann::json::parse(text);
  } catch (const nlohmann::json::exception& e) {
    throw Error(path, std::string("transfer function: ") + e.what());
  }
  std::vector<TransferFunction> tfs = detail::parseOctorayJson(root, path);
  if (tfs.size() != 1) throw Error(path, "transfer function: expected exactly one");
  validate(tfs.front(), path);
  return tfs.front();
}

void saveTransferFunctions(const std::vector<TransferFunction>& tfs, const fs::path& path) {
  if (tfs.empty()) throw Error(path.string(), "nothing to save (no transfer functions)");
  std::set<std::string> names;
  for (const TransferFunction& tf : tfs) {
    validate(tf, path.string());
    if (tf.name.empty()) throw Error(path.string(), "a transfer function to save has no name");
    if (!names.insert(tf.name).second) {
      throw Error(path.string(), fmt::format("name '{}' appears twice", tf.name));
    }
  }
  // Written beside the target and renamed: readers never see a half-written file.
  const fs::path temporary = path.string() + ".partial";
  {
    std::ofstream file(temporary, std::ios::binary | std::ios::trunc);
    if (!file) throw Error(path.string(), "cannot open for writing");
    file << detail::toOctorayJsonText(tfs);
    file.flush();
    if (!file) {
      std::error_code ignored;
      fs::remove(temporary, ignored);
      throw Error(path.string(), "write failed");
    }
  }
  std::error_code error;
  fs::rename(temporary, path, error);
  if (error) {
    fs::remove(temporary, error);
    throw Error(path.string(), "cannot move the written file into place");
  }
}

TransferFunction selectTransferFunction(const std::vector<TransferFunction>& tfs,
                                        const std::string& name, const std::string& path) {
  if (tfs.empty()) throw Error(path, "holds no transfer functions");
  if (name.empty()) {
    if (tfs.size() == 1) return tfs.front();
    throw Error(path, fmt::format("holds {} transfer functions; choose one with --tf-name ({})",
                                  tfs.size(), fmt::join(namesOf(tfs), ", ")));
  }
  for (const TransferFunction& tf : tfs) {
    if (tf.name == name) return tf;
  }
  const TransferFunction* match = nullptr;
  for (const TransferFunction& tf : tfs) {
    if (asciiLower(tf.name) != asciiLower(name)) continue;
    if (match != nullptr) {
      throw Error(path, fmt::format("'{}' matches several names ignoring case; give it exactly",
                                    name));
    }
    match = &tf;
  }
  if (match == nullptr) {
    throw Error(path, fmt::format("no transfer function named '{}' (available: {})", name,
                                  fmt::join(namesOf(tfs), ", ")));
  }
  return *match;
}

fs::path presetsDir() {
  if (const char* overridden = std::getenv("OCTORAY_PRESETS");
      overridden != nullptr && *overridden != '\0') {
    return overridden;
  }
  return OCTORAY_TRANSFER_PRESETS_DIR;
}

TransferFunction findPreset(const std::string& name) {
  const fs::path direct = presetsDir() / (name + ".json");
  std::error_code error;
  // A plain name only: "../x" must not reach outside the presets folder.
  if (name.find_first_of("/\\") == std::string::npos && fs::is_regular_file(direct, error)) {
    return selectTransferFunction(loadTransferFunctions(direct), name, direct.string());
  }
  std::vector<TransferFunction> all;
  for (const fs::path& file : presetFiles()) {
    for (TransferFunction& tf : loadTransferFunctions(file)) all.push_back(std::move(tf));
  }
  return selectTransferFunction(all, name, presetsDir().string());
}

std::vector<std::string> presetNames() {
  std::vector<std::string> names;
  for (const fs::path& file : presetFiles()) {
    for (const TransferFunction& tf : loadTransferFunctions(file)) names.push_back(tf.name);
  }
  std::sort(names.begin(), names.end());
  return names;
}

}  // namespace octoray::transfer
