// Export of any VolumeSource as NIfTI-1, streamed slab by slab, through a temporary file.

#include "octoray/core/atomic_file.h"
#include "octoray/dicom/nifti_export.h"

#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <limits>
#include <vector>

#include <fmt/format.h>

#include "octoray/core/error.h"
#include "octoray/core/text.h"

namespace octoray {

namespace {

// The NIfTI-1 header as the standard (nifti1.h) lays it out. VTK 9.1 installs only a forward
// declaration of nifti_1_header, so the layout is spelled out here and checked.
struct Nifti1Header {
  int32_t sizeofHdr;     // 4: must be 348
  char dataType[10];     // 10: unused
  char dbName[18];       // 18: unused
  int32_t extents;       // 4: unused
  int16_t sessionError;  // 2: unused
  char regular;          // 1: unused
  char dimInfo;          // 1: MRI slice ordering
  int16_t dim[8];        // 16: dim[0] = number of dimensions, dim[1..] sizes
  float intentP1;        // 4
  float intentP2;        // 4
  float intentP3;        // 4
  int16_t intentCode;    // 2
  int16_t datatype;      // 2: DT_* code
  int16_t bitpix;        // 2: bits per voxel
  int16_t sliceStart;    // 2
  float pixdim[8];       // 32: pixdim[0] = qfac, pixdim[1..3] voxel sizes
  float voxOffset;       // 4: byte offset of the samples in a .nii
  float sclSlope;        // 4: physical = stored * slope + inter
  float sclInter;        // 4
  int16_t sliceEnd;      // 2
  char sliceCode;        // 1
  char xyztUnits;        // 1: NIFTI_UNITS_*
  float calMax;          // 4: display range
  float calMin;          // 4
  float sliceDuration;   // 4
  float tOffset;         // 4
  int32_t glmax;         // 4: unused
  int32_t glmin;         // 4: unused
  char descrip[80];      // 80
  char auxFile[24];      // 24
  int16_t qformCode;     // 2: NIFTI_XFORM_* of the quaternion form
  int16_t sformCode;     // 2: NIFTI_XFORM_* of the affine rows
  float quaternB;        // 4
  float quaternC;        // 4
  float quaternD;        // 4
  float qoffsetX;        // 4
  float qoffsetY;        // 4
  float qoffsetZ;        // 4
  float srowX[4];        // 16: first row of the index -> RAS affine
  float srowY[4];        // 16
  float srowZ[4];        // 16
  char intentName[16];   // 16
  char magic[4];         // 4: "n+1\0" for a single .nii file
};
static_assert(sizeof(Nifti1Header) == 348);
static_assert(offsetof(Nifti1Header, dim) == 40);
static_assert(offsetof(Nifti1Header, datatype) == 70);
static_assert(offsetof(Nifti1Header, pixdim) == 76);
static_assert(offsetof(Nifti1Header, voxOffset) == 108);
static_assert(offsetof(Nifti1Header, xyztUnits) == 123);
static_assert(offsetof(Nifti1Header, descrip) == 148);
static_assert(offsetof(Nifti1Header, qformCode) == 252);
static_assert(offsetof(Nifti1Header, srowX) == 280);
static_assert(offsetof(Nifti1Header, magic) == 344);

constexpr int16_t kDtInt16 = 4;
constexpr int16_t kDtFloat32 = 16;
constexpr int16_t kXformScannerAnat = 1;
constexpr char kUnitsMm = 2;
constexpr int64_t kSlabSlices = 8;
constexpr std::size_t kDataOffsetBytes = 352;  // header + the 4-byte "no extensions" flag

// Quaternion form of a rotation (nifti1_io's nifti_mat44_to_quatern, for an orthonormal r).
void setQuaternion(Nifti1Header& h, const double r[3][3]) {
  double a = r[0][0] + r[1][1] + r[2][2] + 1.0, b, c, d;
  if (a > 0.5) {
    a = 0.5 * std::sqrt(a);
    b = 0.25 * (r[2][1] - r[1][2]) / a;
    c = 0.25 * (r[0][2] - r[2][0]) / a;
    d = 0.25 * (r[1][0] - r[0][1]) / a;
  } else {
    const double xd = 1.0 + r[0][0] - (r[1][1] + r[2][2]);
    const double yd = 1.0 + r[1][1] - (r[0][0] + r[2][2]);
    const double zd = 1.0 + r[2][2] - (r[0][0] + r[1][1]);
    if (xd > 1.0) {
      b = 0.5 * std::sqrt(xd);
      c = 0.25 * (r[0][1] + r[1][0]) / b;
      d = 0.25 * (r[0][2] + r[2][0]) / b;
      a = 0.25 * (r[2][1] - r[1][2]) / b;
    } else if (yd > 1.0) {
      c = 0.5 * std::sqrt(yd);
      b = 0.25 * (r[0][1] + r[1][0]) / c;
      d = 0.25 * (r[1][2] + r[2][1]) / c;
      a = 0.25 * (r[0][2] - r[2][0]) / c;
    } else {
      d = 0.5 * std::sqrt(zd);
      b = 0.25 * (r[0][2] + r[2][0]) / d;
      c = 0.25 * (r[1][2] + r[2][1]) / d;
      a = 0.25 * (r[1][0] - r[0][1]) / d;
    }
    if (a < 0) {  // the same rotation with a >= 0, as the standard stores it
      b = -b;
      c = -c;
      d = -d;
    }
  }
  h.quaternB = static_cast<float>(b);
  h.quaternC = static_cast<float>(c);
  h.quaternD = static_cast<float>(d);
}

// Fills the geometry: sform = RAS-from-index (shear kept); qform when the 3x3 part is a
// rotation times a scale (possibly with a slice flip, qfac = -1), else qform_code 0.
void setGeometry(Nifti1Header& h, const Mat4& patientFromIndex) {
  Mat4 rasFromLps;
  rasFromLps.m[0][0] = -1;
  rasFromLps.m[1][1] = -1;
  const Mat4 rasFromIndex = rasFromLps * patientFromIndex;
  for (int c = 0; c < 4; ++c) {
    h.srowX[c] = static_cast<float>(rasFromIndex.m[0][c]);
    h.srowY[c] = static_cast<float>(rasFromIndex.m[1][c]);
    h.srowZ[c] = static_cast<float>(rasFromIndex.m[2][c]);
  }
  h.sformCode = kXformScannerAnat;

  Vec3 axes[3];
  double spacingMm[3];
  for (int a = 0; a < 3; ++a) {
    spacingMm[a] = length(rasFromIndex.column(a));
    axes[a] = normalize(rasFromIndex.column(a));
  }
  h.pixdim[0] = 1;
  for (int a = 0; a < 3; ++a) h.pixdim[a + 1] = static_cast<float>(spacingMm[a]);
  const bool orthogonal = std::abs(dot(axes[0], axes[1])) < 1e-6 &&
                          std::abs(dot(axes[0], axes[2])) < 1e-6 &&
                          std::abs(dot(axes[1], axes[2])) < 1e-6;
  if (!orthogonal) return;  // a shear (gantry tilt) has no quaternion form: qform_code stays 0
  if (dot(cross(axes[0], axes[1]), axes[2]) < 0) {
    h.pixdim[0] = -1;  // qfac: a left-handed grid is a rotation with the slice axis flipped
    axes[2] = -1.0 * axes[2];
  }
  const double r[3][3] = {{axes[0].x, axes[1].x, axes[2].x},
                          {axes[0].y, axes[1].y, axes[2].y},
                          {axes[0].z, axes[1].z, axes[2].z}};
  setQuaternion(h, r);
  h.qoffsetX = static_cast<float>(rasFromIndex.m[0][3]);
  h.qoffsetY = static_cast<float>(rasFromIndex.m[1][3]);
  h.qoffsetZ = static_cast<float>(rasFromIndex.m[2][3]);
  h.qformCode = kXformScannerAnat;
}

// Plain or gzip output with one write call; errors name the final path.
class NiftiOutput {
 public:
  NiftiOutput(const std::string& tempPath, bool gzip, std::string finalPath)
      : finalPath_(std::move(finalPath)) {
    if (gzip) {
      gz_ = gzopen(tempPath.c_str(), "wb6");
      if (gz_) gzbuffer(gz_, 1 << 18);
    } else {
      file_ = std::fopen(tempPath.c_str(), "wb");
    }
    if (!gz_ && !file_) throw Error(finalPath_, "cannot create the temporary output file");
  }
  ~NiftiOutput() {
    if (gz_) gzclose(gz_);
    if (file_) std::fclose(file_);
  }
  NiftiOutput(const NiftiOutput&) = delete;
  NiftiOutput& operator=(const NiftiOutput&) = delete;

  void write(const void* data, std::size_t bytes) {
    const auto* p = static_cast<const char*>(data);
    while (bytes > 0) {
      const std::size_t n = std::min<std::size_t>(bytes, 1 << 24);
      const bool ok = gz_ ? gzwrite(gz_, p, static_cast<unsigned>(n)) == static_cast<int>(n)
                          : std::fwrite(p, 1, n, file_) == n;
      if (!ok) throw Error(finalPath_, "write failed (disk full?)");
      p += n;
      bytes -= n;
    }
  }

  void close() {
    const bool ok = gz_ ? gzclose(gz_) == Z_OK : std::fclose(file_) == 0;
    gz_ = nullptr;
    file_ = nullptr;
    if (!ok) throw Error(finalPath_, "write failed while closing the file (disk full?)");
  }

 private:
  std::string finalPath_;
  gzFile gz_ = nullptr;
  std::FILE* file_ = nullptr;
};

// Removes the temporary file unless the export completed.
struct TempFileGuard {
  std::string path;
  bool keep = false;
  ~TempFileGuard() {
    if (!keep) {
      std::error_code ec;
      std::filesystem::remove(path, ec);
    }
  }
};

bool endsWithGz(const std::string& path) {
  if (path.size() < 3) return false;
  return asciiLower(path.substr(path.size() - 3)) == ".gz";
}

}  // namespace

void exportNifti(VolumeSource& source, const std::string& path, const NiftiExportOptions& options) {
  const VolumeInfo& info = source.info();
  checkOutputIsNotAnInput(path, info.sourceFiles);
  for (int64_t d : info.dims) {
    if (d < 1 || d > std::numeric_limits<int16_t>::max()) {
      throw Error(path, fmt::format("NIfTI-1 cannot hold dimensions {}x{}x{} (each 1..32767)",
                                    info.dims[0], info.dims[1], info.dims[2]));
    }
  }
  const int64_t slices = info.dims[2];
  const auto sliceSamples = static_cast<std::size_t>(info.sliceSamples());
  std::vector<float> slab(sliceSamples * static_cast<std::size_t>(std::min(slices, kSlabSlices)));
  // Progress counts the slices of every pass: the int16 range check reads the volume once more.
  const int passes = info.integerValues ? 2 : 1;
  int64_t slicesDone = 0;
  auto forEachSlab = [&](auto&& visit) {
    for (int64_t first = 0; first < slices; first += kSlabSlices) {
      const int64_t count = std::min(kSlabSlices, slices - first);
      std::span<float> values(slab.data(), sliceSamples * static_cast<std::size_t>(count));
      source.readSlab(first, count, values);
      slicesDone += count;
      if (options.progress) options.progress(slicesDone, slices * passes);
      if (!visit(values)) return;
    }
  };

  // Pass 1 (integer sources only): int16 if every value is an integer that fits.
  bool asInt16 = info.integerValues;
  float minValue = 0, maxValue = 0;
  if (asInt16) {
    bool first = true;
    forEachSlab([&](std::span<const float> values) {
      for (float v : values) {
        if (!(v >= -32768.0f && v <= 32767.0f) || v != std::nearbyint(v)) {
          asInt16 = false;
          return false;
        }
        minValue = first ? v : std::min(minValue, v);
        maxValue = first ? v : std::max(maxValue, v);
        first = false;
      }
      return true;
    });
    slicesDone = slices * (passes - 1);  // a pass stopped early still counts as done
  }

  Nifti1Header header{};
  header.sizeofHdr = 348;
  header.dim[0] = 3;
  for (int i = 0; i < 3; ++i)
    header.dim[i + 1] = static_cast<int16_t>(info.dims[static_cast<std::size_t>(i)]);
  for (int i = 4; i < 8; ++i) header.dim[i] = 1;
  for (int i = 4; i < 8; ++i) header.pixdim[i] = 1;
  header.datatype = asInt16 ? kDtInt16 : kDtFloat32;
  header.bitpix = asInt16 ? 16 : 32;
  header.voxOffset = static_cast<float>(kDataOffsetBytes);
  header.sclSlope = 1;
  header.sclInter = 0;
  header.xyztUnits = kUnitsMm;
  if (asInt16) {
    header.calMin = minValue;
    header.calMax = maxValue;
  }
  setGeometry(header, info.patientFromIndex);
  const std::string description = fmt::format("octoray: {}", info.description);
  std::strncpy(header.descrip, description.c_str(), sizeof(header.descrip) - 1);
  std::memcpy(header.magic, "n+1", 4);

  TempFileGuard temp{fmt::format("{}.partial-{}", path, static_cast<long>(::getpid()))};
  NiftiOutput out(temp.path, endsWithGz(path), path);
  out.write(&header, sizeof(header));
  const char noExtensions[4] = {0, 0, 0, 0};
  out.write(noExtensions, sizeof(noExtensions));

  // Pass 2: the samples, slab by slab.
  std::vector<int16_t> converted;
  forEachSlab([&](std::span<const float> values) {
    if (asInt16) {
      converted.resize(values.size());
      for (std::size_t n = 0; n < values.size(); ++n) {
        converted[n] = static_cast<int16_t>(values[n]);
      }
      out.write(converted.data(), converted.size() * sizeof(int16_t));
    } else {
      out.write(values.data(), values.size_bytes());
    }
    return true;
  });
  out.close();

  std::error_code ec;
  std::filesystem::rename(temp.path, path, ec);
  if (ec) throw Error(path, "cannot move the finished file into place: " + ec.message());
  temp.keep = true;
}

}  // namespace octoray
