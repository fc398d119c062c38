#pragma once
// Helpers shared by the text-header readers of formats_nrrd.cpp and formats_metaimage.cpp:
// file checks, the data file a header names (kept inside the header's folder), words and
// locale-independent numbers.

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "octoray/core/geometry.h"

namespace octoray::detail {

// Throws Error(path, "not a readable file") unless `path` is a regular file.
void requireRegularFile(const std::string& path);

// The last component of `path`.
std::string fileNameOf(const std::string& path);

// `s` without leading and trailing blanks (space, tab, CR, LF).
std::string trimmed(const std::string& s);

// An affine from per-axis unit directions, spacings and the centre of voxel (0,0,0).
Mat4 affineFromAxes(const std::array<Vec3, 3>& directions, const std::array<double, 3>& spacingMm,
                    Vec3 originMm);

// The data file a header names (`name`, the value of `field`), resolved against the header's
// folder; throws Error(headerPath, ...) where it lies outside that folder or below it.
std::string dataFileBesideHeader(const std::string& headerPath, const std::string& name,
                                 const char* field);

// The blank-separated words of `text`.
std::vector<std::string> words(const std::string& text);

// A whole decimal integer token, nothing else.
std::optional<int64_t> parseInteger(const std::string& token);

// A decimal number in the C locale whatever the process locale; "nan" is accepted.
std::optional<double> parseNumber(std::string token);

}  // namespace octoray::detail
