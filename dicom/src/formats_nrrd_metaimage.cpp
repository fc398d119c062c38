// NRRD (.nrrd, .nhdr) and MetaImage (.mhd, .mha): headers are read by VTK's vtkNrrdReader and
// by MetaIO (bundled with VTK as vtkmetaio); the samples are then streamed slab by slab by the
// shared raw slab reader, never through the libraries' whole-volume readers.

#include <vtkNrrdReader.h>
#include <vtkObjectFactory.h>
#include <vtkStringArray.h>
#include <vtkType.h>
#include <vtkmetaio/metaImage.h>

#include <algorithm>
#include <bit>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <optional>
#include <sstream>

#include <fmt/format.h>

#include "octoray/core/error.h"
#include "octoray/dicom/formats.h"
#include "raw_slab_reader.h"
#include "vtk_messages.h"

namespace octoray {

namespace {

constexpr bool kHostBigEndian = std::endian::native == std::endian::big;

void requireRegularFile(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) throw Error(path, "not a readable file");
}

std::string fileNameOf(const std::string& path) {
  return std::filesystem::path(path).filename().string();
}

std::string lowerCase(std::string s) {
  for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
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

// ---------------------------------------------------------------------------------------------
// NRRD

// vtkNrrdReader keeps the encoding, the data file list and the header length protected; this
// subclass exposes them and lets us run the header parse alone (no pipeline, no data read).
class NrrdHeaderReader : public vtkNrrdReader {
 public:
  static NrrdHeaderReader* New();
  vtkTypeMacro(NrrdHeaderReader, vtkNrrdReader)

      bool parseHeader() {
    return ReadHeader() != 0;
  }
  bool rawEncoding() const { return Encoding == ENCODING_RAW; }
  bool gzipEncoding() const { return Encoding == ENCODING_GZIP; }
  vtkStringArray* dataFiles() const { return DataFiles; }
  unsigned long attachedHeaderBytes() const { return HeaderSize; }

 protected:
  NrrdHeaderReader() = default;
  ~NrrdHeaderReader() override = default;
};
vtkStandardNewMacro(NrrdHeaderReader);

// vtkNrrdReader (VTK 9.1) parses "space directions" only for their lengths and "space" only
// for a LAS flip of its own output: it keeps neither the direction vectors nor the space. No
// other library in the dependency set reads NRRD, so these two fields (and "spacings", needed
// only to undo the reader's vector guess below) are looked up here by key. The rest of the
// header is vtkNrrdReader's. The header ends at the first blank line (or the end of a .nhdr).
std::optional<std::string> nrrdField(const std::string& path, const std::string& key) {
  std::ifstream file(path, std::ios::binary);
  std::string line;
  std::getline(file, line);  // the "NRRD000X" magic
  for (int lines = 0; lines < 10000 && std::getline(file, line); ++lines) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty()) break;
    if (line[0] == '#') continue;
    const auto colon = line.find(": ");
    if (colon != std::string::npos && line.substr(0, colon) == key) {
      return trimmed(line.substr(colon + 2));
    }
  }
  return std::nullopt;
}

// "space directions": one "(x,y,z)" vector or "none" per axis.
std::vector<std::optional<std::vector<double>>> parseSpaceDirections(const std::string& text,
                                                                     const std::string& path) {
  std::vector<std::optional<std::vector<double>>> axes;
  std::size_t at = 0;
  while ((at = text.find_first_not_of(" \t", at)) != std::string::npos) {
    if (text.compare(at, 4, "none") == 0) {
      axes.emplace_back(std::nullopt);
      at += 4;
      continue;
    }
    const auto close = text.find(')', at);
    if (text[at] != '(' || close == std::string::npos) {
      throw Error(path, fmt::format("malformed 'space directions': {}", text));
    }
    std::vector<double> vector;
    std::stringstream items(text.substr(at + 1, close - at - 1));
    for (std::string item; std::getline(items, item, ',');) {
      std::size_t used = 0;
      double value = 0;
      try {
        value = std::stod(item, &used);
      } catch (const std::exception&) {
        used = 0;
      }
      if (used == 0 || !trimmed(item.substr(used)).empty()) {
        throw Error(path, fmt::format("malformed 'space directions': {}", text));
      }
      vector.push_back(value);
    }
    axes.emplace_back(std::move(vector));
    at = close + 1;
  }
  return axes;
}

// The sign flips taking a NRRD space to LPS. Unknown or absent spaces are kept as they are.
Vec3 nrrdSpaceToLps(const std::optional<std::string>& space, std::vector<std::string>& warnings) {
  if (!space) {
    warnings.push_back("no 'space' field: axes are taken as patient LPS");
    return {1, 1, 1};
  }
  const std::string s = lowerCase(*space);
  if (s == "left-posterior-superior" || s == "lps") return {1, 1, 1};
  if (s == "right-anterior-superior" || s == "ras") return {-1, -1, 1};
  if (s == "left-anterior-superior" || s == "las") return {1, -1, 1};
  warnings.push_back(
      fmt::format("space '{}' is not anatomical: axes are taken as patient LPS", *space));
  return {1, 1, 1};
}

SampleType sampleTypeFromVtk(int vtkType, const std::string& path) {
  switch (vtkType) {
    case VTK_CHAR:
    case VTK_SIGNED_CHAR:
      return SampleType::Int8;
    case VTK_UNSIGNED_CHAR:
      return SampleType::UInt8;
    case VTK_SHORT:
      return SampleType::Int16;
    case VTK_UNSIGNED_SHORT:
      return SampleType::UInt16;
    case VTK_INT:
      return SampleType::Int32;
    case VTK_UNSIGNED_INT:
      return SampleType::UInt32;
    case VTK_FLOAT:
      return SampleType::Float32;
    case VTK_DOUBLE:
      return SampleType::Float64;
    default:
      throw Error(path, fmt::format("unsupported sample type (VTK type {}); supported: 8/16/32-bit "
                                    "integers, float, double",
                                    vtkType));
  }
}

}  // namespace

std::unique_ptr<VolumeSource> openNrrd(const std::string& path) {
  requireRegularFile(path);
  vtkNew<NrrdHeaderReader> reader;
  detail::VtkMessages messages(reader);
  reader->SetFileName(path.c_str());
  if (!reader->parseHeader() || !messages.errors().empty()) {
    throw Error(path, messages.errors().empty()
                          ? std::string("not a readable NRRD header")
                          : "not a readable NRRD header: " + messages.errors().front());
  }
  VolumeInfo info;
  info.format = "nrrd";
  info.sourcePath = path;
  info.description = fileNameOf(path);
  for (const auto& warning : messages.warnings()) info.warnings.push_back(warning);

  if (reader->dataFiles()->GetNumberOfValues() > 1) {
    throw Error(path, "data split over several files is not supported");
  }
  if (!reader->rawEncoding() && !reader->gzipEncoding()) {
    throw Error(path, "only raw and gzip NRRD encodings are supported");
  }

  const auto directionsText = nrrdField(path, "space directions");
  std::vector<std::optional<std::vector<double>>> directions;
  if (directionsText) directions = parseSpaceDirections(*directionsText, path);

  // vtkNrrdReader takes a first axis of 9 samples or fewer as vector components. For a scalar
  // volume of at most 3 axes, put that axis back; real vector data (a "none" first direction,
  // or more than 3 axes) is refused.
  int extent[6];
  reader->GetDataExtent(extent);
  std::array<int64_t, 3> dims{extent[1] + 1, extent[3] + 1, extent[5] + 1};
  double spacing[3];
  reader->GetDataSpacing(spacing);
  std::array<double, 3> spacingMm{spacing[0], spacing[1], spacing[2]};
  const int components = reader->GetNumberOfScalarComponents();
  if (components > 1) {
    const bool vectorAxis = !directions.empty() && !directions.front();
    if (vectorAxis || reader->GetFileDimensionality() + 1 > 3) {
      throw Error(path, fmt::format("samples with {} components are not supported (scalar "
                                    "volumes only)",
                                    components));
    }
    dims = {components, dims[0], dims[1]};
    double firstSpacing = 1;
    if (const auto spacings = nrrdField(path, "spacings")) {
      std::stringstream values(*spacings);
      if (!(values >> firstSpacing)) firstSpacing = 1;
    }
    spacingMm = {firstSpacing, spacingMm[0], spacingMm[1]};
  }
  info.dims = dims;

  // Geometry: space directions (full orientation) when present, else per-axis spacings.
  std::array<Vec3, 3> axes{Vec3{1, 0, 0}, Vec3{0, 1, 0}, Vec3{0, 0, 1}};
  if (!directions.empty()) {
    std::vector<std::vector<double>> spatial;
    for (const auto& d : directions) {
      if (d) spatial.push_back(*d);
    }
    if (spatial.size() > 3) throw Error(path, "more than 3 spatial axes are not supported");
    for (std::size_t a = 0; a < spatial.size(); ++a) {
      const auto& v = spatial[a];
      const Vec3 column{v.size() > 0 ? v[0] : 0, v.size() > 1 ? v[1] : 0, v.size() > 2 ? v[2] : 0};
      spacingMm[a] = length(column);
      axes[a] = normalize(column);
    }
    if (spatial.size() == 2) {
      // A single image: its slice axis is the normal, with a nominal 1 mm.
      axes[2] = normalize(cross(axes[0], axes[1]));
      spacingMm[2] = 1;
    }
  } else {
    for (double& s : spacingMm) {
      if (!std::isfinite(s) || s == 0) s = 1;
    }
  }
  double origin[3];
  reader->GetDataOrigin(origin);
  Mat4 patientFromIndex = affineFromAxes(axes, spacingMm, {origin[0], origin[1], origin[2]});
  if (directionsText) {
    const Vec3 flip = nrrdSpaceToLps(nrrdField(path, "space"), info.warnings);
    for (int row = 0; row < 3; ++row) {
      for (int col = 0; col < 4; ++col) patientFromIndex.m[row][col] *= flip[row];
    }
  } else {
    info.warnings.push_back("no 'space directions': axis-aligned volume assumed");
  }
  info.patientFromIndex = patientFromIndex;
  detail::checkAffine(info.patientFromIndex, path);

  detail::RawLayout layout;
  layout.dims = info.dims;
  layout.sampleType = sampleTypeFromVtk(reader->GetDataScalarType(), path);
  layout.bigEndian = reader->GetSwapBytes() ? !kHostBigEndian : kHostBigEndian;
  layout.compression =
      reader->gzipEncoding() ? detail::Compression::Deflate : detail::Compression::None;
  if (reader->dataFiles()->GetNumberOfValues() == 1) {
    layout.dataPath = reader->dataFiles()->GetValue(0);
    layout.fileOffsetBytes = 0;
  } else {
    layout.dataPath = path;
    layout.fileOffsetBytes = reader->attachedHeaderBytes();
  }
  return detail::openRawLayout(std::move(info), std::move(layout));
}

// ---------------------------------------------------------------------------------------------
// MetaImage

namespace {

SampleType sampleTypeFromMeta(vtkmetaio::MET_ValueEnumType type, const std::string& path) {
  switch (type) {
    case vtkmetaio::MET_CHAR:
      return SampleType::Int8;
    case vtkmetaio::MET_UCHAR:
      return SampleType::UInt8;
    case vtkmetaio::MET_SHORT:
      return SampleType::Int16;
    case vtkmetaio::MET_USHORT:
      return SampleType::UInt16;
    case vtkmetaio::MET_INT:
    case vtkmetaio::MET_LONG:  // 32 bits in MetaIO
      return SampleType::Int32;
    case vtkmetaio::MET_UINT:
    case vtkmetaio::MET_ULONG:
      return SampleType::UInt32;
    case vtkmetaio::MET_FLOAT:
      return SampleType::Float32;
    case vtkmetaio::MET_DOUBLE:
      return SampleType::Float64;
    default:
      throw Error(path, fmt::format("unsupported ElementType (MetaIO type {}); supported: 8/16/32-"
                                    "bit integers, MET_FLOAT, MET_DOUBLE",
                                    static_cast<int>(type)));
  }
}

}  // namespace

std::unique_ptr<VolumeSource> openMetaImage(const std::string& path) {
  requireRegularFile(path);
  // MetaIO parses the header and stops after ElementDataFile, the last field; reading through
  // our own stream tells where a LOCAL (.mha) payload starts.
  std::ifstream stream(path, std::ios::binary);
  vtkmetaio::MetaImage image;
  if (!stream || !image.ReadStream(0, &stream, false)) {
    throw Error(path, "not a readable MetaImage header");
  }
  const std::streamoff headerEnd = stream.tellg();

  const int nDims = image.NDims();
  if (nDims < 2 || nDims > 4) {
    throw Error(path, fmt::format("NDims = {}: only 2D and 3D images are supported", nDims));
  }
  if (nDims == 4 && image.DimSize(3) != 1) {
    throw Error(path, "4D images are not supported");
  }
  if (image.ElementNumberOfChannels() > 1) {
    throw Error(path, fmt::format("ElementNumberOfChannels = {}: only scalar images are supported",
                                  image.ElementNumberOfChannels()));
  }
  if (!image.BinaryData()) throw Error(path, "ASCII (BinaryData = False) data is not supported");

  VolumeInfo info;
  info.format = "metaimage";
  info.sourcePath = path;
  info.description = fileNameOf(path);
  info.dims = {image.DimSize(0), image.DimSize(1), nDims > 2 ? image.DimSize(2) : 1};

  // ITK's convention: space is LPS, TransformMatrix row a is the direction of index axis a.
  std::array<Vec3, 3> axes;
  std::array<double, 3> spacingMm{1, 1, 1};
  double origin[3] = {0, 0, 0};
  const int spatial = std::min(nDims, 3);
  for (int a = 0; a < spatial; ++a) {
    spacingMm[static_cast<std::size_t>(a)] = image.ElementSpacing(a);
    double v[3] = {0, 0, 0};
    for (int r = 0; r < spatial; ++r) v[r] = image.TransformMatrix(a, r);
    axes[static_cast<std::size_t>(a)] = normalize({v[0], v[1], v[2]});
  }
  for (int r = 0; r < spatial; ++r) origin[r] = image.Position(r);
  if (spatial == 2) axes[2] = normalize(cross(axes[0], axes[1]));
  info.patientFromIndex = affineFromAxes(axes, spacingMm, {origin[0], origin[1], origin[2]});
  detail::checkAffine(info.patientFromIndex, path);

  detail::RawLayout layout;
  layout.dims = info.dims;
  layout.sampleType = sampleTypeFromMeta(image.ElementType(), path);
  layout.bigEndian = image.BinaryDataByteOrderMSB();
  layout.compression =
      image.CompressedData() ? detail::Compression::Deflate : detail::Compression::None;
  layout.valueScale = image.ElementToIntensityFunctionSlope();
  layout.valueOffset = image.ElementToIntensityFunctionOffset();

  const std::string dataFile = trimmed(image.ElementDataFileName());
  const bool local = dataFile == "LOCAL" || dataFile == "Local" || dataFile == "local";
  if (dataFile.empty() || dataFile.starts_with("LIST") || dataFile.find('%') != std::string::npos) {
    throw Error(path, fmt::format("ElementDataFile = '{}': only LOCAL or a single data file is "
                                  "supported",
                                  dataFile));
  }
  if (local) {
    layout.dataPath = path;
  } else {
    const std::filesystem::path file(dataFile);
    layout.dataPath = file.is_absolute()
                          ? file.string()
                          : (std::filesystem::path(path).parent_path() / file).string();
  }
  const int headerSize = image.HeaderSize();
  if (headerSize > 0) {
    layout.fileOffsetBytes = static_cast<uint64_t>(headerSize);
  } else if (headerSize == -1) {
    // "HeaderSize = -1": the samples are the last bytes of the data file.
    if (image.CompressedData()) {
      throw Error(path, "HeaderSize = -1 is not supported with compressed data");
    }
    std::error_code ec;
    const uint64_t fileBytes = std::filesystem::file_size(layout.dataPath, ec);
    if (ec) throw Error(layout.dataPath, "cannot read the file: " + ec.message());
    const uint64_t dataBytes = detail::volumeBytes(info.dims, layout.sampleType, path);
    layout.fileOffsetBytes = fileBytes >= dataBytes ? fileBytes - dataBytes : 0;
  } else if (local) {
    if (headerEnd < 0) throw Error(path, "cannot locate the data after the header");
    layout.fileOffsetBytes = static_cast<uint64_t>(headerEnd);
  }
  return detail::openRawLayout(std::move(info), std::move(layout));
}

}  // namespace octoray
