// NRRD (.nrrd, .nhdr), parsed as teem's format (NRRD0001-0005). The samples are then
// streamed slab by slab by the shared raw slab reader, never through VTK's whole-volume reader.
//
// Limits on untrusted headers: a header (and so any one of its lines) may be at most
// kMaxNrrdHeaderBytes (1 MiB); a data file it names must lie in the header's folder or below.

#include <algorithm>
#include <bit>
#include <cctype>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <initializer_list>
#include <iostream>
#include <map>
#include <mutex>
#include <optional>
#include <sstream>

#include <fmt/format.h>

#include "header_text.h"
#include "octoray/core/error.h"
#include "octoray/core/text.h"
#include "octoray/dicom/formats.h"
#include "raw_slab_reader.h"

namespace octoray {

namespace {

constexpr bool kHostBigEndian = std::endian::native == std::endian::big;

// The header is parsed here rather than by VTK 9.1's vtkNrrdReader, which loops forever on a
// header whose last line has no newline (std::getline at the end leaves the previous line in
// place), reads sizes with 32-bit atoi (so "-5" or "1e10" pass as something else), drops
// "spacings" given before "dimension", expands "data file" patterns without bound and resolves
// data files anywhere on disk.

// Real headers are a few hundred bytes; this bounds the header and so every line in it.
constexpr std::size_t kMaxNrrdHeaderBytes = std::size_t{1} << 20;
// NRRD_DIM_MAX in teem.
constexpr int kMaxNrrdDimension = 16;

// The fields of one header (names in their canonical spelling) and where its data start.
struct NrrdHeader {
  std::map<std::string, std::string> fields;  // field -> description, trimmed
  bool endsWithBlankLine = false;             // a blank line ends the header (attached data)
  uint64_t headerBytes = 0;                   // bytes up to and including that blank line

  std::optional<std::string> field(const std::string& name) const {
    const auto it = fields.find(name);
    if (it == fields.end()) return std::nullopt;
    return it->second;
  }
};

// Alternative spellings teem accepts, mapped to the canonical field name.
std::string canonicalNrrdField(const std::string& name) {
  static const std::map<std::string, std::string> kAliases = {
      {"datafile", "data file"},       {"lineskip", "line skip"}, {"byteskip", "byte skip"},
      {"centerings", "centers"},       {"axismins", "axis mins"}, {"axismaxs", "axis maxs"},
      {"oldmin", "old min"},           {"oldmax", "old max"},     {"blocksize", "block size"},
      {"sampleunits", "sample units"},
  };
  const auto alias = kAliases.find(name);
  return alias == kAliases.end() ? name : alias->second;
}

bool knownNrrdField(const std::string& field) {
  static const char* kFields[] = {"type",         "dimension",       "sizes",
                                  "encoding",     "endian",          "data file",
                                  "line skip",    "byte skip",       "spacings",
                                  "space",        "space dimension", "space directions",
                                  "space origin", "space units",     "measurement frame",
                                  "kinds",        "content",         "thicknesses",
                                  "axis mins",    "axis maxs",       "centers",
                                  "labels",       "units",           "min",
                                  "max",          "old min",         "old max",
                                  "block size",   "number",          "sample units"};
  return std::any_of(std::begin(kFields), std::end(kFields),
                     [&](const char* known) { return field == known; });
}

// Reads the header: the magic line, then fields, key/value pairs and comments up to a blank
// line or the end of the file (a detached header). Every step consumes a line, and no more
// than kMaxNrrdHeaderBytes are read.
NrrdHeader readNrrdHeader(const std::string& path) {
  std::ifstream file(path, std::ios::binary);
  if (!file) throw Error(path, "cannot open the file for reading");
  std::string text(kMaxNrrdHeaderBytes + 1, '\0');
  file.read(text.data(), static_cast<std::streamsize>(text.size()));
  text.resize(static_cast<std::size_t>(file.gcount()));
  const bool truncatedByLimit = text.size() > kMaxNrrdHeaderBytes;

  const auto tooLong = [&] {
    return Error(path, fmt::format("the header does not end within {} bytes (NRRD headers, and "
                                   "every line in them, are limited to 1 MiB)",
                                   kMaxNrrdHeaderBytes));
  };

  NrrdHeader header;
  std::size_t at = 0;
  for (int lineNumber = 1; at < text.size(); ++lineNumber) {
    const std::size_t newline = text.find('\n', at);
    if (newline == std::string::npos && truncatedByLimit) throw tooLong();
    const std::size_t end = newline == std::string::npos ? text.size() : newline;
    std::string line = text.substr(at, end - at);
    at = end + 1;  // past the newline (or past the end)
    if (!line.empty() && line.back() == '\r') line.pop_back();

    if (lineNumber == 1) {
      if (line.size() != 8 || !line.starts_with("NRRD000") ||
          !std::isdigit(static_cast<unsigned char>(line[7]))) {
        throw Error(path, "not a NRRD file (the first line is not a NRRD000X magic)");
      }
      continue;
    }
    if (line.empty()) {
      header.endsWithBlankLine = newline != std::string::npos;
      header.headerBytes = std::min<uint64_t>(at, text.size());
      return header;
    }
    if (line.front() == '#') continue;
    // Text (UTF-8 allowed), no control characters: binary bytes are not a header line.
    const bool printable = std::none_of(line.begin(), line.end(), [](char c) {
      const auto u = static_cast<unsigned char>(c);
      return (u < 0x20 && u != '\t') || u == 0x7f;
    });
    const std::size_t field = line.find(": ");
    const std::size_t keyValue = line.find(":=");
    if (!printable || (field == std::string::npos && keyValue == std::string::npos)) {
      throw Error(path, fmt::format("header line {} is not a field ('name: value'), a key/value "
                                    "pair ('key:=value') or a comment",
                                    lineNumber));
    }
    if (keyValue != std::string::npos && (field == std::string::npos || keyValue < field)) {
      continue;  // key/value pairs carry nothing octoray reads
    }
    const std::string name = canonicalNrrdField(line.substr(0, field));
    if (!header.fields.emplace(name, detail::trimmed(line.substr(field + 2))).second) {
      throw Error(path, fmt::format("field '{}' appears twice in the header", name));
    }
  }
  if (truncatedByLimit) throw tooLong();
  header.headerBytes = text.size();  // a detached header: the whole file
  return header;
}


// "(x,y,z)": a vector of numbers.
std::optional<std::vector<double>> parseNrrdVector(const std::string& text) {
  if (text.size() < 2 || text.front() != '(' || text.back() != ')') return std::nullopt;
  std::vector<double> vector;
  std::stringstream items(text.substr(1, text.size() - 2));
  for (std::string item; std::getline(items, item, ',');) {
    const auto value = detail::parseNumber(item);
    if (!value) return std::nullopt;
    vector.push_back(*value);
  }
  if (vector.empty()) return std::nullopt;
  return vector;
}

// "space directions": one "(x,y,z)" vector or "none" per axis.
std::vector<std::optional<std::vector<double>>> parseSpaceDirections(const std::string& text,
                                                                     const std::string& path) {
  std::vector<std::optional<std::vector<double>>> axes;
  for (const std::string& word : detail::words(text)) {
    if (word == "none") {
      axes.emplace_back(std::nullopt);
      continue;
    }
    auto vector = parseNrrdVector(word);
    if (!vector || vector->size() > 3 ||
        !std::all_of(vector->begin(), vector->end(), [](double v) { return std::isfinite(v); })) {
      throw Error(path, fmt::format("malformed 'space directions': {}", text));
    }
    axes.emplace_back(std::move(vector));
  }
  return axes;
}

// The sign flips taking a NRRD space to LPS. Unknown or absent spaces are kept as they are.
Vec3 nrrdSpaceToLps(const std::optional<std::string>& space, std::vector<std::string>& warnings) {
  if (!space) {
    warnings.push_back("no 'space' field: axes are taken as patient LPS");
    return {1, 1, 1};
  }
  const std::string s = asciiLower(*space);
  if (s == "left-posterior-superior" || s == "lps") return {1, 1, 1};
  if (s == "right-anterior-superior" || s == "ras") return {-1, -1, 1};
  if (s == "left-anterior-superior" || s == "las") return {1, -1, 1};
  warnings.push_back(
      fmt::format("space '{}' is not anatomical: axes are taken as patient LPS", *space));
  return {1, 1, 1};
}

// Kinds of axes that are positions along the grid; any other kind (vector, RGB-color, ...)
// makes the axis a set of components of one sample.
bool spatialKind(const std::string& kind) {
  const std::string k = asciiLower(kind);
  return k == "domain" || k == "space" || k == "time" || k == "???" || k == "none";
}

// One spatial axis of the grid: its size, and its step (direction * spacing) when known.
struct NrrdAxis {
  int64_t size = 1;
  std::optional<std::vector<double>> direction;  // from "space directions"
  double spacing = std::nan("");                 // from "spacings"
};

// The grid's axes from the per-axis fields. Scalar volumes only: an axis of components (a
// "none" space direction, or a kind such as vector or RGB-color) must hold a single sample,
// and is then dropped; at most three axes remain.
std::vector<NrrdAxis> nrrdSpatialAxes(const NrrdHeader& header, const std::string& path,
                                      std::vector<std::string>& warnings) {
  const std::string dimensionText = *header.field("dimension");
  const auto dimension = detail::parseInteger(dimensionText);
  if (!dimension || *dimension < 1 || *dimension > kMaxNrrdDimension) {
    throw Error(path, fmt::format("invalid 'dimension: {}' (1 to {} expected)", dimensionText,
                                  kMaxNrrdDimension));
  }
  const auto axisCount = static_cast<std::size_t>(*dimension);
  // The words of a per-axis field, which must give one value per axis.
  const auto perAxis = [&](const char* name) {
    auto values = detail::words(*header.field(name));
    if (values.size() != axisCount) {
      throw Error(path, fmt::format("'{}' gives {} value(s) for 'dimension: {}'", name,
                                    values.size(), axisCount));
    }
    return values;
  };

  std::vector<NrrdAxis> axes(axisCount);
  const auto sizes = perAxis("sizes");
  for (std::size_t a = 0; a < axisCount; ++a) {
    const auto size = detail::parseInteger(sizes[a]);
    if (!size || *size < 1) {
      throw Error(path, fmt::format("invalid 'sizes: {}': '{}' is not a positive integer",
                                    *header.field("sizes"), sizes[a]));
    }
    axes[a].size = *size;
  }
  if (header.field("spacings")) {
    const auto spacings = perAxis("spacings");
    for (std::size_t a = 0; a < axisCount; ++a) {
      const auto spacing = detail::parseNumber(spacings[a]);
      if (!spacing) {
        throw Error(path, fmt::format("invalid 'spacings: {}': '{}' is not a number",
                                      *header.field("spacings"), spacings[a]));
      }
      axes[a].spacing = *spacing;
    }
  }
  std::vector<bool> componentAxis(axisCount, false);
  if (const auto text = header.field("space directions")) {
    auto directions = parseSpaceDirections(*text, path);
    if (directions.size() != axisCount) {
      throw Error(path, fmt::format("'space directions' gives {} value(s) for 'dimension: {}'",
                                    directions.size(), axisCount));
    }
    for (std::size_t a = 0; a < axisCount; ++a) {
      componentAxis[a] = !directions[a];
      axes[a].direction = std::move(directions[a]);
    }
    if (header.field("spacings")) {
      warnings.push_back("'spacings' ignored: 'space directions' give the geometry");
    }
  }
  if (header.field("kinds")) {
    const auto kinds = perAxis("kinds");
    for (std::size_t a = 0; a < axisCount; ++a) {
      if (!spatialKind(kinds[a])) componentAxis[a] = true;
    }
  }

  std::vector<NrrdAxis> spatial;
  for (std::size_t a = 0; a < axisCount; ++a) {
    if (!componentAxis[a]) {
      spatial.push_back(axes[a]);
    } else if (axes[a].size > 1) {
      throw Error(path, fmt::format("samples with {} components are not supported (scalar "
                                    "volumes only)",
                                    axes[a].size));
    }
  }
  if (spatial.empty()) throw Error(path, "no spatial axis (every axis holds components)");
  if (spatial.size() > 3) {
    throw Error(path, fmt::format("{} spatial axes: only volumes of up to 3 axes are supported",
                                  spatial.size()));
  }
  return spatial;
}

// Index -> patient: space directions (full orientation) when present, else per-axis spacings.
Mat4 nrrdPatientFromIndex(const NrrdHeader& header, const std::vector<NrrdAxis>& spatial,
                          const std::string& path, std::vector<std::string>& warnings) {
  std::array<Vec3, 3> unitAxes{Vec3{1, 0, 0}, Vec3{0, 1, 0}, Vec3{0, 0, 1}};
  std::array<double, 3> spacingMm{1, 1, 1};
  const bool directions = header.field("space directions").has_value();
  if (directions) {
    for (std::size_t a = 0; a < spatial.size(); ++a) {
      const auto& v = *spatial[a].direction;
      const Vec3 column{v[0], v.size() > 1 ? v[1] : 0, v.size() > 2 ? v[2] : 0};
      spacingMm[a] = length(column);
      unitAxes[a] = normalize(column);
    }
    // A single image: its slice axis is the normal, with a nominal 1 mm.
    if (spatial.size() == 2) unitAxes[2] = normalize(cross(unitAxes[0], unitAxes[1]));
  } else {
    for (std::size_t a = 0; a < spatial.size(); ++a) {
      const double s = spatial[a].spacing;
      if (std::isfinite(s) && s != 0) {
        spacingMm[a] = s;
      } else if (header.field("spacings")) {
        warnings.push_back(fmt::format("axis {} has no usable spacing ({}): 1 mm assumed", a, s));
      }
    }
  }
  Vec3 originMm{0, 0, 0};
  if (const auto text = header.field("space origin")) {
    const auto origin = parseNrrdVector(*text);
    if (!origin || origin->size() > 3) {
      throw Error(path, fmt::format("malformed 'space origin': {}", *text));
    }
    const auto& o = *origin;
    originMm = {o[0], o.size() > 1 ? o[1] : 0, o.size() > 2 ? o[2] : 0};
  }
  Mat4 patientFromIndex = detail::affineFromAxes(unitAxes, spacingMm, originMm);
  if (directions) {
    const Vec3 flip = nrrdSpaceToLps(header.field("space"), warnings);
    for (int row = 0; row < 3; ++row) {
      for (int col = 0; col < 4; ++col) patientFromIndex.m[row][col] *= flip[row];
    }
  } else {
    warnings.push_back("no 'space directions': axis-aligned volume assumed");
  }
  detail::checkAffine(patientFromIndex, path);
  return patientFromIndex;
}

// Where the samples are and how they are stored: type, encoding, byte order, data file and
// skips. `layout.dims` must be set.
void nrrdSampleLayout(const NrrdHeader& header, const std::string& path, detail::RawLayout& layout,
                      std::vector<std::string>& warnings) {
  try {
    layout.sampleType = parseSampleType(*header.field("type"));
  } catch (const Error& e) {
    throw Error(path, e.reason());
  }
  const std::string encoding = *header.field("encoding");
  if (asciiLower(encoding) == "gzip" || asciiLower(encoding) == "gz") {
    layout.compression = detail::Compression::Deflate;
  } else if (asciiLower(encoding) != "raw") {
    throw Error(path, fmt::format("encoding '{}': only raw and gzip NRRD encodings are supported",
                                  encoding));
  }
  layout.bigEndian = kHostBigEndian;
  if (const auto endian = header.field("endian")) {
    const std::string e = asciiLower(*endian);
    if (e != "little" && e != "big") {
      throw Error(path, fmt::format("invalid 'endian: {}' (little or big expected)", *endian));
    }
    layout.bigEndian = e == "big";
  } else if (sampleBytes(layout.sampleType) > 1) {
    warnings.push_back(fmt::format("no 'endian' field: {}-endian samples assumed",
                                   kHostBigEndian ? "big" : "little"));
  }

  if (const auto dataFile = header.field("data file")) {
    const auto parts = detail::words(*dataFile);
    const bool severalFiles = parts.empty() || parts.front() == "LIST" ||
                              (parts.size() >= 4 && parts.front().find('%') != std::string::npos);
    if (severalFiles) throw Error(path, "data split over several files is not supported");
    layout.dataPath = detail::dataFileBesideHeader(path, *dataFile, "data file");
  } else if (header.endsWithBlankLine) {
    layout.dataPath = path;
    layout.fileOffsetBytes = header.headerBytes;
  } else {
    throw Error(path,
                "the header has no 'data file' and no blank line after which attached "
                "data would start");
  }
  if (const auto lineSkip = header.field("line skip");
      lineSkip && detail::parseInteger(*lineSkip) != 0) {
    throw Error(path, fmt::format("'line skip: {}' is not supported", *lineSkip));
  }
  if (const auto byteSkip = header.field("byte skip")) {
    const auto skip = detail::parseInteger(*byteSkip);
    if (!skip || *skip < -1) {
      throw Error(path, fmt::format("invalid 'byte skip: {}' (-1 or more expected)", *byteSkip));
    }
    if (*skip != 0 && layout.compression != detail::Compression::None) {
      throw Error(path, fmt::format("'byte skip: {}' is only supported with raw encoding", *skip));
    }
    if (*skip == -1) {
      // The samples are the last bytes of the data file.
      std::error_code ec;
      const uint64_t fileBytes = std::filesystem::file_size(layout.dataPath, ec);
      if (ec) throw Error(layout.dataPath, "cannot read the file: " + ec.message());
      const uint64_t dataBytes = detail::volumeBytes(layout.dims, layout.sampleType, path);
      layout.fileOffsetBytes = fileBytes >= dataBytes ? fileBytes - dataBytes : 0;
    } else {
      layout.fileOffsetBytes += static_cast<uint64_t>(*skip);
    }
  }
}

}  // namespace

std::unique_ptr<VolumeSource> openNrrd(const std::string& path) {
  detail::requireRegularFile(path);
  const NrrdHeader header = readNrrdHeader(path);
  std::vector<std::string> missing;
  for (const char* required : {"type", "dimension", "sizes", "encoding"}) {
    if (!header.field(required)) missing.emplace_back(required);
  }
  if (!missing.empty()) {
    throw Error(
        path, fmt::format("NRRD header lacks the required field(s) {}", fmt::join(missing, ", ")));
  }

  VolumeInfo info;
  info.format = "nrrd";
  info.sourcePath = path;
  info.description = detail::fileNameOf(path);
  for (const auto& [name, value] : header.fields) {
    if (!knownNrrdField(name)) info.warnings.push_back(fmt::format("unknown field '{}'", name));
  }
  const std::vector<NrrdAxis> spatial = nrrdSpatialAxes(header, path, info.warnings);
  for (std::size_t a = 0; a < 3; ++a) info.dims[a] = a < spatial.size() ? spatial[a].size : 1;
  info.patientFromIndex = nrrdPatientFromIndex(header, spatial, path, info.warnings);

  // The values' unit (NRRD's 'sample units'): Hounsfield units make the volume CT, as DICOM's
  // modality does; any other unit is kept as a note (our unit field knows only HU).
  if (const auto units = header.field("sample units")) {
    std::string unit = *units;
    if (unit.size() >= 2 && unit.front() == '"' && unit.back() == '"') {
      unit = unit.substr(1, unit.size() - 2);
    }
    if (asciiLower(unit) == "hu" || asciiLower(unit) == "hounsfield units") {
      info.unit = "HU";
    } else if (!unit.empty()) {
      info.warnings.push_back(
          fmt::format("sample units '{}' are not Hounsfield units: the values are "
                      "shown as they are, not as CT",
                      unit));
    }
  }

  detail::RawLayout layout;
  layout.dims = info.dims;
  nrrdSampleLayout(header, path, layout, info.warnings);
  detail::volumeBytes(layout.dims, layout.sampleType, path);  // sizes too large for any file
  return detail::openRawLayout(std::move(info), std::move(layout));
}

}  // namespace octoray
