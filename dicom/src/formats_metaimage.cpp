// MetaImage (.mhd, .mha), parsed as ITK's MetaIO writes it. MetaIO itself (vtkmetaio) is not
// used on untrusted files: fuzzing found it reading for ever on "NDims = -4" and overrunning
// fixed buffers on long field names. The samples are then streamed slab by slab by the shared
// raw slab reader.
//
// Limits on untrusted headers: a header may be at most kMaxMetaHeaderBytes (1 MiB); a data
// file it names must lie in the header's folder or below it.

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
#include <fmt/ranges.h>

#include "header_text.h"
#include "octoray/core/error.h"
#include "octoray/core/text.h"
#include "octoray/dicom/formats.h"
#include "raw_slab_reader.h"

namespace octoray {

namespace {

constexpr std::size_t kMaxMetaHeaderBytes = std::size_t{1} << 20;

// MetaIO's fields (MetaObject's and MetaImage's); others are kept as warnings.
constexpr const char* kMetaFields[] = {
    "Comment", "ObjectType", "ObjectSubType", "TransformType", "NDims", "Name", "ID", "ParentID",
    "ParentName", "AcquisitionDate", "CompressedData", "CompressedDataSize", "BinaryData",
    "BinaryDataByteOrderMSB", "ElementByteOrderMSB", "Color", "Position", "Offset", "Origin",
    "Orientation", "Rotation", "TransformMatrix", "CenterOfRotation", "AnatomicalOrientation",
    "DistanceUnits", "ElementSpacing", "ElementSize", "DimSize", "HeaderSize",
    "HeaderSizePerSlice", "Modality", "SequenceID", "ElementMin", "ElementMax",
    "ElementNumberOfChannels", "ElementType", "ElementToIntensityFunctionSlope",
    "ElementToIntensityFunctionOffset", "ElementDataFile"};

// A MetaImage header: "Name = value" lines up to ElementDataFile, the last field; a LOCAL
// (.mha) file's samples follow that line. Field names are matched without regard to case.
struct MetaHeader {
  std::map<std::string, std::string> fields;  // canonical name -> trimmed value
  std::vector<std::string> unknown;
  uint64_t headerBytes = 0;

  const std::string* field(const char* name) const {
    const auto it = fields.find(name);
    return it == fields.end() ? nullptr : &it->second;
  }
};

MetaHeader readMetaHeader(const std::string& path) {
  std::ifstream stream(path, std::ios::binary);
  if (!stream) throw Error(path, "cannot open the file for reading");
  std::string text(kMaxMetaHeaderBytes, '\0');
  stream.read(text.data(), static_cast<std::streamsize>(text.size()));
  text.resize(static_cast<std::size_t>(stream.gcount()));
  MetaHeader header;
  std::size_t at = 0;
  for (int lineNumber = 1; at < text.size(); ++lineNumber) {
    const std::size_t newline = text.find('\n', at);
    const std::size_t end = newline == std::string::npos ? text.size() : newline;
    std::string line = text.substr(at, end - at);
    at = end + 1;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (detail::trimmed(line).empty()) continue;
    const bool printable = std::none_of(line.begin(), line.end(), [](char c) {
      const auto u = static_cast<unsigned char>(c);
      return (u < 0x20 && u != '\t') || u == 0x7f;
    });
    const std::size_t equals = line.find('=');
    const std::string name =
        equals == std::string::npos ? "" : detail::trimmed(line.substr(0, equals));
    const bool identifier =
        !name.empty() && name.size() <= 64 && std::all_of(name.begin(), name.end(), [](char c) {
          return std::isalnum(static_cast<unsigned char>(c)) || c == '_';
        });
    if (!printable || !identifier) {
      throw Error(path, fmt::format("not a MetaImage header: line {} is not a field "
                                    "('Name = value')",
                                    lineNumber));
    }
    std::string canonical = name;
    bool known = false;
    for (const char* field : kMetaFields) {
      if (asciiLower(field) == asciiLower(name)) {
        canonical = field;
        known = true;
      }
    }
    if (!known) header.unknown.push_back(name);
    if (!header.fields.emplace(canonical, detail::trimmed(line.substr(equals + 1))).second) {
      throw Error(path, fmt::format("field '{}' appears twice in the header", canonical));
    }
    if (canonical == "ElementDataFile") {
      header.headerBytes = std::min<uint64_t>(at, text.size());
      return header;
    }
  }
  if (text.size() == kMaxMetaHeaderBytes) {
    throw Error(path, fmt::format("no ElementDataFile field in the first {} bytes: not a "
                                  "MetaImage header",
                                  kMaxMetaHeaderBytes));
  }
  throw Error(path, "the MetaImage header has no ElementDataFile field");
}

// `count` finite numbers (integers from 1 to 2^40 with `dimensions`), or a message naming the
// field.
std::vector<double> metaNumbers(const MetaHeader& header, const char* name, std::size_t count,
                                bool dimensions, const std::string& path) {
  const std::string& text = *header.field(name);
  const std::vector<std::string> tokens = detail::words(text);
  std::vector<double> out;
  for (const auto& token : tokens) {
    if (dimensions) {
      // Exact as doubles; any larger size is refused by the volume's byte count anyway.
      const auto value = detail::parseInteger(token);
      if (!value || *value < 1 || *value > (int64_t{1} << 40)) break;
      out.push_back(static_cast<double>(*value));
    } else {
      const auto value = detail::parseNumber(token);
      if (!value || !std::isfinite(*value)) break;
      out.push_back(*value);
    }
  }
  if (out.size() != count || tokens.size() != count) {
    throw Error(path, fmt::format("{} = '{}': {} {} expected", name, text.substr(0, 80), count,
                                  dimensions ? "positive integers" : "finite numbers"));
  }
  return out;
}

bool metaBool(const MetaHeader& header, const char* name, bool otherwise,
              const std::string& path) {
  const std::string* text = header.field(name);
  if (!text) return otherwise;
  const std::string value = asciiLower(*text);
  if (value == "true" || value == "t" || value == "1") return true;
  if (value == "false" || value == "f" || value == "0") return false;
  throw Error(path, fmt::format("{} = '{}': True or False expected", name, text->substr(0, 80)));
}

// The first of `names` the header has, or nullptr.
const char* firstMetaField(const MetaHeader& header, std::initializer_list<const char*> names) {
  for (const char* name : names) {
    if (header.field(name)) return name;
  }
  return nullptr;
}

}  // namespace

std::unique_ptr<VolumeSource> openMetaImage(const std::string& path) {
  detail::requireRegularFile(path);
  const MetaHeader header = readMetaHeader(path);
  std::vector<std::string> missing;
  for (const char* required : {"NDims", "DimSize", "ElementType"}) {
    if (!header.field(required)) missing.emplace_back(required);
  }
  if (!missing.empty()) {
    throw Error(path, fmt::format("MetaImage header lacks the required field(s) {}",
                                  fmt::join(missing, ", ")));
  }
  if (const auto* type = header.field("ObjectType"); type && asciiLower(*type) != "image") {
    throw Error(path, fmt::format("ObjectType = '{}': only images are read", type->substr(0, 80)));
  }
  const std::string& nDimsText = *header.field("NDims");
  const auto nDimsValue = detail::parseInteger(nDimsText);
  if (!nDimsValue || *nDimsValue < 2 || *nDimsValue > 4) {
    throw Error(path, fmt::format("NDims = '{}': only 2D and 3D images are supported",
                                  nDimsText.substr(0, 40)));
  }
  const auto nDims = static_cast<std::size_t>(*nDimsValue);
  const std::vector<double> dimSize = metaNumbers(header, "DimSize", nDims, true, path);
  if (nDims == 4 && dimSize[3] != 1) throw Error(path, "4D images are not supported");
  if (const auto* channels = header.field("ElementNumberOfChannels");
      channels && detail::parseInteger(*channels) != 1) {
    throw Error(path, fmt::format("ElementNumberOfChannels = {}: only scalar images are supported",
                                  channels->substr(0, 40)));
  }
  if (!metaBool(header, "BinaryData", true, path)) {
    throw Error(path, "ASCII (BinaryData = False) data is not supported");
  }

  VolumeInfo info;
  info.format = "metaimage";
  info.sourcePath = path;
  info.description = detail::fileNameOf(path);
  for (const auto& name : header.unknown) {
    info.warnings.push_back(fmt::format("unknown field '{}'", name));
  }
  info.dims = {static_cast<int64_t>(dimSize[0]), static_cast<int64_t>(dimSize[1]),
               nDims > 2 ? static_cast<int64_t>(dimSize[2]) : 1};

  // ITK's convention: space is LPS, TransformMatrix row a is the direction of index axis a.
  // Without ElementSpacing, MetaIO takes ElementSize as the spacing.
  const std::size_t spatial = std::min<std::size_t>(nDims, 3);
  std::vector<double> spacing(nDims, 1.0), offset(nDims, 0.0), matrix(nDims * nDims, 0.0);
  for (std::size_t a = 0; a < nDims; ++a) matrix[a * nDims + a] = 1.0;
  if (const char* name = firstMetaField(header, {"ElementSpacing", "ElementSize"})) {
    spacing = metaNumbers(header, name, nDims, false, path);
    // The geometry stays as written (index a steps |s| mm against its direction); ITK does not
    // support negative spacing, so a file that has one was likely not written by it.
    if (std::any_of(spacing.begin(), spacing.end(), [](double s) { return s < 0; })) {
      info.warnings.push_back(
          fmt::format("{} {} has a negative value: each such index axis "
                      "runs against its TransformMatrix direction",
                      name, fmt::join(spacing, " ")));
    }
  }
  if (const char* name = firstMetaField(header, {"Offset", "Position", "Origin"})) {
    offset = metaNumbers(header, name, nDims, false, path);
  }
  if (const char* name = firstMetaField(header, {"TransformMatrix", "Rotation", "Orientation"})) {
    matrix = metaNumbers(header, name, nDims * nDims, false, path);
  }
  std::array<Vec3, 3> axes;
  std::array<double, 3> spacingMm{1, 1, 1};
  double origin[3] = {0, 0, 0};
  for (std::size_t a = 0; a < spatial; ++a) {
    spacingMm[a] = spacing[a];
    double v[3] = {0, 0, 0};
    for (std::size_t r = 0; r < spatial; ++r) v[r] = matrix[a * nDims + r];
    axes[a] = normalize({v[0], v[1], v[2]});
    origin[a] = offset[a];
  }
  if (spatial == 2) axes[2] = normalize(cross(axes[0], axes[1]));
  info.patientFromIndex =
      detail::affineFromAxes(axes, spacingMm, {origin[0], origin[1], origin[2]});
  detail::checkAffine(info.patientFromIndex, path);

  detail::RawLayout layout;
  layout.dims = info.dims;
  const std::string& elementType = *header.field("ElementType");
  static constexpr std::pair<const char*, SampleType> kMetaTypes[] = {
      {"MET_CHAR", SampleType::Int8},     {"MET_UCHAR", SampleType::UInt8},
      {"MET_SHORT", SampleType::Int16},   {"MET_USHORT", SampleType::UInt16},
      {"MET_INT", SampleType::Int32},     {"MET_LONG", SampleType::Int32},  // 32 bits in MetaIO
      {"MET_UINT", SampleType::UInt32},   {"MET_ULONG", SampleType::UInt32},
      {"MET_FLOAT", SampleType::Float32}, {"MET_DOUBLE", SampleType::Float64}};
  const auto type = std::find_if(std::begin(kMetaTypes), std::end(kMetaTypes),
                                 [&](const auto& t) { return elementType == t.first; });
  if (type == std::end(kMetaTypes)) {
    throw Error(path, fmt::format("unsupported ElementType '{}'; supported: 8/16/32-bit integers "
                                  "(MET_CHAR ... MET_ULONG), MET_FLOAT, MET_DOUBLE",
                                  elementType.substr(0, 40)));
  }
  layout.sampleType = type->second;
  const char* byteOrder = firstMetaField(header, {"BinaryDataByteOrderMSB", "ElementByteOrderMSB"});
  layout.bigEndian = byteOrder && metaBool(header, byteOrder, false, path);
  const bool compressed = metaBool(header, "CompressedData", false, path);
  layout.compression = compressed ? detail::Compression::Deflate : detail::Compression::None;
  if (header.field("ElementToIntensityFunctionSlope")) {
    layout.valueScale = metaNumbers(header, "ElementToIntensityFunctionSlope", 1, false, path)[0];
  }
  if (header.field("ElementToIntensityFunctionOffset")) {
    layout.valueOffset = metaNumbers(header, "ElementToIntensityFunctionOffset", 1, false, path)[0];
  }

  const std::string& dataFile = *header.field("ElementDataFile");
  const bool local = asciiLower(dataFile) == "local";
  if (dataFile.empty() || dataFile.starts_with("LIST") || dataFile.find('%') != std::string::npos) {
    throw Error(path, fmt::format("ElementDataFile = '{}': only LOCAL or a single data file is "
                                  "supported",
                                  dataFile.substr(0, 80)));
  }
  layout.dataPath = local ? path : detail::dataFileBesideHeader(path, dataFile, "ElementDataFile");
  detail::volumeBytes(layout.dims, layout.sampleType, path);  // sizes too large for any file
  int64_t headerSize = 0;
  if (const auto* text = header.field("HeaderSize")) {
    const auto value = detail::parseInteger(*text);
    if (!value || *value < -1) {
      throw Error(path, fmt::format("HeaderSize = '{}': -1 or more expected", text->substr(0, 40)));
    }
    headerSize = *value;
  }
  if (headerSize > 0) {
    layout.fileOffsetBytes = static_cast<uint64_t>(headerSize);
  } else if (headerSize == -1) {
    // "HeaderSize = -1": the samples are the last bytes of the data file.
    if (compressed) throw Error(path, "HeaderSize = -1 is not supported with compressed data");
    std::error_code ec;
    const uint64_t fileBytes = std::filesystem::file_size(layout.dataPath, ec);
    if (ec) throw Error(layout.dataPath, "cannot read the file: " + ec.message());
    const uint64_t dataBytes = detail::volumeBytes(info.dims, layout.sampleType, path);
    layout.fileOffsetBytes = fileBytes >= dataBytes ? fileBytes - dataBytes : 0;
  } else if (local) {
    layout.fileOffsetBytes = header.headerBytes;
  }
  return detail::openRawLayout(std::move(info), std::move(layout));
}


}  // namespace octoray
