// Helpers shared by the NRRD and MetaImage header readers (header_text.h).

#include "header_text.h"

#include <charconv>
#include <filesystem>
#include <sstream>

#include <fmt/format.h>

#include "octoray/core/error.h"

namespace octoray::detail {

void requireRegularFile(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) throw Error(path, "not a readable file");
}

std::string fileNameOf(const std::string& path) {
  return std::filesystem::path(path).filename().string();
}

std::string trimmed(const std::string& s) {
  const auto first = s.find_first_not_of(" \t\r\n");
  if (first == std::string::npos) return {};
  return s.substr(first, s.find_last_not_of(" \t\r\n") - first + 1);
}

// An affine from per-axis unit directions, spacings and the centre of voxel (0,0,0).
Mat4 affineFromAxes(const std::array<Vec3, 3>& directions, const std::array<double, 3>& spacingMm,
                    Vec3 originMm) {
  return Mat4::fromColumns(spacingMm[0] * directions[0], spacingMm[1] * directions[1],
                           spacingMm[2] * directions[2], originMm);
}

// Whether `file` lies strictly below `folder` (both absolute and lexically normal; `folder`
// may end in a separator, which is an empty last component).
namespace {

bool isBelow(const std::filesystem::path& file, const std::filesystem::path& folder) {
  auto f = file.begin();
  for (const auto& part : folder) {
    if (part.empty()) continue;
    if (f == file.end() || *f != part) return false;
    ++f;
  }
  return f != file.end() && !f->empty();
}

}  // namespace

// The data file a header names (`field` = its value), resolved against the header's folder.
// Only files in that folder or below are read, so a header cannot make us read
// "../../etc/passwd" or "/home/someone/else". The check is on the path as written (after
// removing "." and ".."): a symbolic link inside the folder is the folder owner's choice.
std::string dataFileBesideHeader(const std::string& headerPath, const std::string& name,
                                 const char* field) {
  namespace fs = std::filesystem;
  const fs::path headerFolder = fs::path(headerPath).parent_path();
  const fs::path named(name);
  std::error_code ec;
  const fs::path folder =
      fs::absolute(headerFolder.empty() ? fs::path(".") : headerFolder, ec).lexically_normal();
  const fs::path file =
      named.is_absolute() ? named.lexically_normal() : (folder / named).lexically_normal();
  if (ec || name.empty() || !isBelow(file, folder)) {
    throw Error(headerPath, fmt::format("{} '{}' is outside the header's folder: only data files "
                                        "in that folder or below it are read",
                                        field, name));
  }
  return named.is_absolute() ? file.string() : (headerFolder / named).lexically_normal().string();
}

std::vector<std::string> words(const std::string& text) {
  std::vector<std::string> out;
  std::istringstream in(text);
  for (std::string word; in >> word;) out.push_back(word);
  return out;
}

std::optional<int64_t> parseInteger(const std::string& token) {
  int64_t value = 0;
  const char* last = token.data() + token.size();
  const auto [end, ec] = std::from_chars(token.data(), last, value);
  if (ec != std::errc() || end != last) return std::nullopt;
  return value;
}

// A decimal number in the C locale whatever the process locale; "nan" is accepted.
std::optional<double> parseNumber(std::string token) {
  token = trimmed(token);
  if (token.starts_with('+')) token.erase(0, 1);
  double value = 0;
  const char* last = token.data() + token.size();
  const auto [end, ec] = std::from_chars(token.data(), last, value);
  if (ec != std::errc() || end != last || token.empty()) return std::nullopt;
  return value;
}

}  // namespace octoray::detail
