// NIfTI-1/2 (.nii, .nii.gz, and .hdr/.img pairs): vtkNIFTIImageReader reads and byte-swaps the
// header; the samples are then streamed by the shared raw slab reader from vox_offset (inflated
// forward for .gz), so neither form is ever loaded whole.

#include <vtkNIFTIImageHeader.h>
#include <vtkNIFTIImageReader.h>
#include <vtkNew.h>

#include <zlib.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <filesystem>
#include <fstream>

#include <fmt/format.h>

#include "octoray/core/error.h"
#include "octoray/dicom/formats.h"
#include "raw_slab_reader.h"
#include "vtk_messages.h"

namespace octoray {

namespace {

SampleType sampleTypeFromNifti(int datatype, const std::string& path) {
  switch (datatype) {
    case 2:  // DT_UINT8
      return SampleType::UInt8;
    case 4:  // DT_INT16
      return SampleType::Int16;
    case 8:  // DT_INT32
      return SampleType::Int32;
    case 16:  // DT_FLOAT32
      return SampleType::Float32;
    case 64:  // DT_FLOAT64
      return SampleType::Float64;
    case 256:  // DT_INT8
      return SampleType::Int8;
    case 512:  // DT_UINT16
      return SampleType::UInt16;
    case 768:  // DT_UINT32
      return SampleType::UInt32;
    default:
      throw Error(path, fmt::format("unsupported NIfTI datatype {} (supported: 8/16/32-bit "
                                    "integers, float32, float64)",
                                    datatype));
  }
}

// The leading fields of the two on-disk headers (nifti1.h, nifti2.h); the 348-byte NIfTI-1
// header is also the Analyze 7.5 layout. Only what must be checked before VTK sees the file.
struct Nifti1Prefix {
  int32_t sizeofHdr;  // 4: 348
  char unused1[36];   // 36: data_type .. hkey_un0
  int16_t dim[8];     // 16: dim[0] = number of axes, dim[1..7] sizes
  char unused2[14];   // 14: intent_p1..p3, intent_code
  int16_t datatype;   // 2: DT_* code
  int16_t bitpix;     // 2: bits per voxel
};
static_assert(sizeof(Nifti1Prefix) == 76);  // 74 bytes of fields, padded to 4
static_assert(offsetof(Nifti1Prefix, dim) == 40);
static_assert(offsetof(Nifti1Prefix, datatype) == 70);
static_assert(offsetof(Nifti1Prefix, bitpix) == 72);

struct Nifti2Prefix {
  int32_t sizeofHdr;  // 4: 540
  char magic[8];      // 8: "n+2\0\r\n\032\n" or "ni2..."
  int16_t datatype;   // 2: DT_* code
  int16_t bitpix;     // 2: bits per voxel
  int64_t dim[8];     // 64: dim[0] = number of axes, dim[1..7] sizes
};
static_assert(sizeof(Nifti2Prefix) == 80);
static_assert(offsetof(Nifti2Prefix, datatype) == 12);
static_assert(offsetof(Nifti2Prefix, bitpix) == 14);
static_assert(offsetof(Nifti2Prefix, dim) == 16);

template <typename T>
T byteSwapped(T v) {
  auto bytes = std::bit_cast<std::array<unsigned char, sizeof(T)>>(v);
  std::reverse(bytes.begin(), bytes.end());
  return std::bit_cast<T>(bytes);
}

// Checks the header fields VTK trusts (its reader crashes on an unknown datatype) before VTK
// reads the file: header size, dims, datatype and bitpix. Reads through zlib, which passes
// uncompressed files through as they are.
void checkNiftiHeader(const std::string& path) {
  std::array<char, 80> bytes{};
  int got = -1;
  if (gzFile in = gzopen(path.c_str(), "rb")) {
    got = gzread(in, bytes.data(), static_cast<unsigned>(bytes.size()));
    gzclose(in);
  }
  if (got < static_cast<int>(sizeof(Nifti1Prefix))) {
    throw Error(path, "not a NIfTI or Analyze file (shorter than a header)");
  }
  int32_t sizeofHdr = 0;
  std::memcpy(&sizeofHdr, bytes.data(), sizeof sizeofHdr);
  const bool swapped = sizeofHdr != 348 && sizeofHdr != 540;
  if (swapped) sizeofHdr = byteSwapped(sizeofHdr);
  int64_t ndim = 0, datatype = 0, bitpix = 0;
  std::array<int64_t, 8> dim{};
  const auto value = [&](auto field) { return swapped ? byteSwapped(field) : field; };
  if (sizeofHdr == 348) {
    Nifti1Prefix h;
    std::memcpy(&h, bytes.data(), sizeof h);
    for (std::size_t i = 0; i < 8; ++i) dim[i] = value(h.dim[i]);
    datatype = value(h.datatype);
    bitpix = value(h.bitpix);
  } else if (sizeofHdr == 540 && got >= static_cast<int>(sizeof(Nifti2Prefix))) {
    Nifti2Prefix h;
    std::memcpy(&h, bytes.data(), sizeof h);
    for (std::size_t i = 0; i < 8; ++i) dim[i] = value(h.dim[i]);
    datatype = value(h.datatype);
    bitpix = value(h.bitpix);
  } else {
    throw Error(path, "not a NIfTI or Analyze file (sizeof_hdr is neither 348 nor 540)");
  }
  ndim = dim[0];
  if (ndim < 1 || ndim > 7) {
    throw Error(path, fmt::format("invalid dim[0] = {} (number of axes, 1 to 7)", ndim));
  }
  // Axes past the third only count volumes, which are skipped: their sizes are not checked.
  for (int64_t i = 1; i <= std::min<int64_t>(ndim, 3); ++i) {
    if (dim[static_cast<std::size_t>(i)] < 1) {
      throw Error(path, fmt::format("invalid dim[{}] = {}: every size must be positive", i,
                                    dim[static_cast<std::size_t>(i)]));
    }
  }
  const SampleType type = sampleTypeFromNifti(static_cast<int>(datatype), path);
  const auto expectedBits = static_cast<int64_t>(8 * sampleBytes(type));
  if (bitpix != expectedBits) {
    throw Error(path, fmt::format("bitpix {} does not match datatype {} ({} bits per voxel)",
                                  bitpix, datatype, expectedBits));
  }
}

// The NIfTI-1 standard's quaternion form (nifti1.h, "METHOD 2"): rotation from (b, c, d) with
// a = sqrt(1 - b^2 - c^2 - d^2), voxel sizes pixdim[1..3] (non-positive read as 1), and qfac
// = pixdim[0] flipping the slice axis.
Mat4 rasFromIndexByQuaternion(vtkNIFTIImageHeader* header) {
  double b = header->GetQuaternB(), c = header->GetQuaternC(), d = header->GetQuaternD();
  double a = 1.0 - (b * b + c * c + d * d);
  if (a < 1e-7) {
    // Not quite a unit quaternion: normalise (b, c, d) and take a 180-degree rotation.
    const double n = 1.0 / std::sqrt(b * b + c * c + d * d);
    b *= n;
    c *= n;
    d *= n;
    a = 0;
  } else {
    a = std::sqrt(a);
  }
  auto voxelSize = [&](int i) {
    const double v = header->GetPixDim(i);
    return v > 0 && std::isfinite(v) ? v : 1.0;
  };
  const double qfac = header->GetPixDim(0) < 0 ? -1.0 : 1.0;
  const double dx = voxelSize(1), dy = voxelSize(2), dz = voxelSize(3) * qfac;
  const Vec3 r0{a * a + b * b - c * c - d * d, 2 * (b * c + a * d), 2 * (b * d - a * c)};
  const Vec3 r1{2 * (b * c - a * d), a * a + c * c - b * b - d * d, 2 * (c * d + a * b)};
  const Vec3 r2{2 * (b * d + a * c), 2 * (c * d - a * b), a * a + d * d - c * c - b * b};
  return Mat4::fromColumns(dx * r0, dy * r1, dz * r2,
                           {header->GetQOffsetX(), header->GetQOffsetY(), header->GetQOffsetZ()});
}

Mat4 rasFromIndexBySform(vtkNIFTIImageHeader* header) {
  double rows[3][4];
  header->GetSRowX(rows[0]);
  header->GetSRowY(rows[1]);
  header->GetSRowZ(rows[2]);
  Mat4 m;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 4; ++c) m.m[r][c] = rows[r][c];
  }
  return m;
}

// The file holding the samples: the .nii itself, or the .img beside a .hdr.
std::string niftiDataPath(const std::string& path, const std::string& magic) {
  if (magic == "n+1" || magic == "n+2") return path;
  std::string base = path;
  std::string gz;
  if (base.size() > 3 && base.ends_with(".gz")) {
    base.resize(base.size() - 3);
    gz = ".gz";
  }
  if (base.size() > 4 && (base.ends_with(".hdr") || base.ends_with(".HDR"))) {
    base.resize(base.size() - 4);
    for (const std::string& candidate :
         {base + ".img" + gz, base + ".img", base + ".img.gz", base + ".IMG"}) {
      std::error_code ec;
      if (std::filesystem::is_regular_file(candidate, ec)) return candidate;
    }
    throw Error(path, "the .img file holding the samples is missing");
  }
  return path;
}

bool startsWithGzipMagic(const std::string& path) {
  std::ifstream file(path, std::ios::binary);
  unsigned char magic[2] = {0, 0};
  file.read(reinterpret_cast<char*>(magic), 2);
  return file.gcount() == 2 && magic[0] == 0x1f && magic[1] == 0x8b;
}

}  // namespace

std::unique_ptr<VolumeSource> openNifti(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) throw Error(path, "not a readable file");
  checkNiftiHeader(path);
  vtkNew<vtkNIFTIImageReader> reader;
  detail::VtkMessages messages(reader.GetPointer());
  // CanReadFile checks the header without the pipeline, whose failures are noisy.
  if (!reader->CanReadFile(path.c_str())) throw Error(path, "not a NIfTI or Analyze file");
  reader->SetFileName(path.c_str());
  reader->UpdateInformation();
  vtkNIFTIImageHeader* header = reader->GetNIFTIHeader();
  if (!messages.errors().empty() || !header) {
    throw Error(path, messages.errors().empty()
                          ? std::string("not a readable NIfTI header")
                          : "not a readable NIfTI header: " + messages.errors().front());
  }

  VolumeInfo info;
  info.format = "nifti";
  info.sourcePath = path;
  info.description = std::filesystem::path(path).filename().string();
  for (const auto& warning : messages.warnings()) info.warnings.push_back(warning);

  const auto ndim = header->GetDim(0);
  if (ndim < 1 || ndim > 7) throw Error(path, fmt::format("invalid dim[0] = {}", ndim));
  for (int i = 0; i < 3; ++i)
    info.dims[static_cast<std::size_t>(i)] = i < ndim ? header->GetDim(i + 1) : 1;
  int64_t volumes = 1;
  for (int i = 4; i <= ndim; ++i) volumes *= std::max<int64_t>(header->GetDim(i), 1);
  if (volumes > 1) {
    info.warnings.push_back(
        fmt::format("{} volumes (4D or more): only the first is read", volumes));
  }

  // Index -> RAS by the sform when set (the full affine, shear included), else the qform, else
  // the Analyze-style voxel sizes; then to LPS.
  Mat4 rasFromIndex;
  if (header->GetSFormCode() > 0) {
    rasFromIndex = rasFromIndexBySform(header);
  } else if (header->GetQFormCode() > 0) {
    rasFromIndex = rasFromIndexByQuaternion(header);
  } else {
    info.warnings.push_back("no qform or sform: axis-aligned volume at the origin assumed");
    for (int i = 0; i < 3; ++i) {
      const double v = header->GetPixDim(i + 1);
      rasFromIndex.m[i][i] = v > 0 && std::isfinite(v) ? v : 1.0;
    }
  }
  Mat4 lpsFromRas;
  lpsFromRas.m[0][0] = -1;
  lpsFromRas.m[1][1] = -1;
  info.patientFromIndex = lpsFromRas * rasFromIndex;
  detail::checkAffine(info.patientFromIndex, path);

  detail::RawLayout layout;
  layout.dims = info.dims;
  layout.sampleType = sampleTypeFromNifti(header->GetDataType(), path);
  layout.bigEndian = reader->GetDataByteOrder() == VTK_FILE_BYTE_ORDER_BIG_ENDIAN;
  layout.dataPath = niftiDataPath(path, header->GetMagic());
  const auto voxOffset = header->GetVoxOffset();
  // VTK reads a NaN vox_offset as the smallest int64.
  if (voxOffset < 0) throw Error(path, "invalid vox_offset (negative or not a number)");
  // In a one-file .nii the samples follow the header and its 4-byte extension flag.
  const std::string magic = header->GetMagic();
  const int64_t firstSampleByte = magic == "n+1" ? 352 : magic == "n+2" ? 544 : 0;
  if (voxOffset < firstSampleByte) {
    throw Error(path, fmt::format("vox_offset {} points into the header: the samples of a .nii "
                                  "file start at byte {} or later",
                                  voxOffset, firstSampleByte));
  }
  if (startsWithGzipMagic(layout.dataPath)) {
    layout.compression = detail::Compression::Deflate;
    layout.streamOffsetBytes = static_cast<uint64_t>(voxOffset);
  } else {
    layout.fileOffsetBytes = static_cast<uint64_t>(voxOffset);
  }
  // scl_slope = 0 means "no scaling" (NIfTI-1 standard). A field that is not a finite number
  // counts as 0, as nifti1_io reads it, and the warning says so.
  double slope = header->GetSclSlope(), intercept = header->GetSclInter();
  if (!std::isfinite(slope)) {
    info.warnings.push_back(fmt::format("scl_slope is {}: the samples are read unscaled", slope));
    slope = 0;
  }
  if (slope != 0 && !std::isfinite(intercept)) {
    info.warnings.push_back(fmt::format("scl_inter is {}: read as 0", intercept));
    intercept = 0;
  }
  if (slope != 0) {
    layout.valueScale = slope;
    layout.valueOffset = intercept;
  }
  return detail::openRawLayout(std::move(info), std::move(layout));
}

}  // namespace octoray
