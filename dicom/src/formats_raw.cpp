// Raw volumes, and the slab reader shared by every "header + raw samples" format.

#include <zlib.h>

#include <algorithm>
#include <bit>
#include <cctype>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <vector>

#include <fmt/format.h>

#include "octoray/core/error.h"
#include "octoray/core/text.h"
#include "octoray/dicom/formats.h"
#include "raw_slab_reader.h"

namespace octoray {

namespace {

std::string normalizedTypeName(const std::string& name) {
  std::string s = asciiLower(name);
  const auto first = s.find_first_not_of(" \t\r\n");
  const auto last = s.find_last_not_of(" \t\r\n");
  if (first == std::string::npos) return {};
  s = s.substr(first, last - first + 1);
  if (s.starts_with("met_")) s = s.substr(4);
  // "unsigned  short int" and friends: collapse runs of blanks.
  std::string collapsed;
  for (char c : s) {
    if (std::isspace(static_cast<unsigned char>(c))) {
      if (!collapsed.empty() && collapsed.back() != ' ') collapsed += ' ';
    } else {
      collapsed += c;
    }
  }
  return collapsed;
}

}  // namespace

SampleType parseSampleType(const std::string& name) {
  struct Spelling {
    const char* name;
    SampleType type;
  };
  // Our own names, C/NRRD spellings and MetaImage's MET_* names (without the prefix; MetaIO's
  // LONG is 32 bits).
  static constexpr Spelling kSpellings[] = {
      {"uint8", SampleType::UInt8},
      {"uint8_t", SampleType::UInt8},
      {"uchar", SampleType::UInt8},
      {"unsigned char", SampleType::UInt8},
      {"int8", SampleType::Int8},
      {"int8_t", SampleType::Int8},
      {"char", SampleType::Int8},
      {"signed char", SampleType::Int8},
      {"uint16", SampleType::UInt16},
      {"uint16_t", SampleType::UInt16},
      {"ushort", SampleType::UInt16},
      {"unsigned short", SampleType::UInt16},
      {"unsigned short int", SampleType::UInt16},
      {"int16", SampleType::Int16},
      {"int16_t", SampleType::Int16},
      {"short", SampleType::Int16},
      {"short int", SampleType::Int16},
      {"signed short", SampleType::Int16},
      {"signed short int", SampleType::Int16},
      {"uint32", SampleType::UInt32},
      {"uint32_t", SampleType::UInt32},
      {"uint", SampleType::UInt32},
      {"unsigned int", SampleType::UInt32},
      {"ulong", SampleType::UInt32},
      {"int32", SampleType::Int32},
      {"int32_t", SampleType::Int32},
      {"int", SampleType::Int32},
      {"signed int", SampleType::Int32},
      {"long", SampleType::Int32},
      {"float32", SampleType::Float32},
      {"float", SampleType::Float32},
      {"float64", SampleType::Float64},
      {"double", SampleType::Float64},
  };
  const std::string key = normalizedTypeName(name);
  for (const auto& spelling : kSpellings) {
    if (key == spelling.name) return spelling.type;
  }
  throw Error("", fmt::format("unsupported sample type '{}' (expected uint8, int8, uint16, int16, "
                              "uint32, int32, float32 or float64)",
                              name));
}

std::size_t sampleBytes(SampleType type) {
  switch (type) {
    case SampleType::UInt8:
    case SampleType::Int8:
      return 1;
    case SampleType::UInt16:
    case SampleType::Int16:
      return 2;
    case SampleType::UInt32:
    case SampleType::Int32:
    case SampleType::Float32:
      return 4;
    case SampleType::Float64:
      return 8;
  }
  return 0;
}

namespace detail {

uint64_t volumeBytes(const std::array<int64_t, 3>& dims, SampleType type, const std::string& path) {
  uint64_t bytes = sampleBytes(type);
  for (int64_t d : dims) {
    if (d <= 0) {
      throw Error(path, fmt::format("invalid dimensions {}x{}x{}: every size must be positive",
                                    dims[0], dims[1], dims[2]));
    }
    if (__builtin_mul_overflow(bytes, static_cast<uint64_t>(d), &bytes) ||
        bytes > static_cast<uint64_t>(std::numeric_limits<int64_t>::max())) {
      throw Error(path,
                  fmt::format("dimensions {}x{}x{} are too large", dims[0], dims[1], dims[2]));
    }
  }
  return bytes;
}

std::pair<double, double> sampleTypeRange(SampleType type) {
  switch (type) {
    case SampleType::UInt8: return {0, 255};
    case SampleType::Int8: return {-128, 127};
    case SampleType::UInt16: return {0, 65535};
    case SampleType::Int16: return {-32768, 32767};
    case SampleType::UInt32: return {0, 4294967295.0};
    case SampleType::Int32: return {-2147483648.0, 2147483647.0};
    default: break;
  }
  return {-std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity()};
}

bool integerValued(SampleType type, double valueScale, double valueOffset) {
  const bool integerSamples = type != SampleType::Float32 && type != SampleType::Float64;
  return integerSamples && std::isfinite(valueScale) && std::isfinite(valueOffset) &&
         valueScale == std::round(valueScale) && valueOffset == std::round(valueOffset);
}

void checkAffine(const Mat4& patientFromIndex, const std::string& path) {
  for (const auto& row : patientFromIndex.m) {
    for (double v : row) {
      if (!std::isfinite(v)) throw Error(path, "the voxel-to-patient transform is not finite");
    }
  }
  try {
    (void)patientFromIndex.inverseAffine();
  } catch (const Error& e) {
    throw Error(path, e.reason());
  }
}

namespace {

// Samples converted per step: bounds the byte buffer to a few MiB whatever the slab size.
constexpr std::size_t kChunkSamples = std::size_t{1} << 19;

template <typename Unsigned>
Unsigned byteSwapped(Unsigned v) {
  if constexpr (sizeof(Unsigned) == 2) return __builtin_bswap16(v);
  if constexpr (sizeof(Unsigned) == 4) return __builtin_bswap32(v);
  if constexpr (sizeof(Unsigned) == 8) return __builtin_bswap64(v);
  return v;
}

template <typename T, typename Unsigned>
void convertSamples(const unsigned char* bytes, std::size_t count, bool swap, double scale,
                    double offset, float* out) {
  static_assert(sizeof(T) == sizeof(Unsigned));
  const bool identity = scale == 1.0 && offset == 0.0;
  for (std::size_t n = 0; n < count; ++n) {
    Unsigned bits;
    std::memcpy(&bits, bytes + n * sizeof(T), sizeof(T));
    if (swap) bits = byteSwapped(bits);
    const T value = std::bit_cast<T>(bits);
    out[n] = identity ? static_cast<float>(value)
                      : static_cast<float>(static_cast<double>(value) * scale + offset);
  }
}

}  // namespace

void convertSamples(SampleType type, const unsigned char* bytes, std::size_t count, bool swap,
                    double scale, double offset, float* out) {
  switch (type) {
    case SampleType::UInt8:
      return convertSamples<uint8_t, uint8_t>(bytes, count, false, scale, offset, out);
    case SampleType::Int8:
      return convertSamples<int8_t, uint8_t>(bytes, count, false, scale, offset, out);
    case SampleType::UInt16:
      return convertSamples<uint16_t, uint16_t>(bytes, count, swap, scale, offset, out);
    case SampleType::Int16:
      return convertSamples<int16_t, uint16_t>(bytes, count, swap, scale, offset, out);
    case SampleType::UInt32:
      return convertSamples<uint32_t, uint32_t>(bytes, count, swap, scale, offset, out);
    case SampleType::Int32:
      return convertSamples<int32_t, uint32_t>(bytes, count, swap, scale, offset, out);
    case SampleType::Float32:
      return convertSamples<float, uint32_t>(bytes, count, swap, scale, offset, out);
    case SampleType::Float64:
      return convertSamples<double, uint64_t>(bytes, count, swap, scale, offset, out);
  }
}

namespace {

// Bytes of a compressed stream by position. Inflating only goes forward, so a read before the
// current position starts again from the beginning of the stream; a volume is normally read
// front to back, so that is rare.
class InflateReader {
 public:
  InflateReader(std::string path, uint64_t fileOffsetBytes)
      : path_(std::move(path)), fileOffsetBytes_(fileOffsetBytes), input_(1 << 16) {
    file_.open(path_, std::ios::binary);
    if (!file_) throw Error(path_, "cannot open the file for reading");
    start();
  }
  ~InflateReader() { inflateEnd(&stream_); }
  InflateReader(const InflateReader&) = delete;
  InflateReader& operator=(const InflateReader&) = delete;

  // Fills dst[0, n) with the decompressed bytes at `position`; returns how many there were.
  std::size_t readAt(uint64_t position, unsigned char* dst, std::size_t n) {
    if (position < position_) {
      inflateEnd(&stream_);
      start();
    }
    std::vector<unsigned char> scratch;
    while (position_ < position) {
      scratch.resize(static_cast<std::size_t>(std::min<uint64_t>(position - position_, 1 << 20)));
      if (inflateInto(scratch.data(), scratch.size()) < scratch.size()) return 0;
    }
    return inflateInto(dst, n);
  }

  // Decompressed bytes the stream has delivered so far: after a short read, all it holds.
  uint64_t delivered() const { return position_; }

  // Reads on to the end of the gzip or zlib member that holds the bytes delivered so far, so
  // that zlib checks its trailer (gzip's CRC-32 and length, zlib's Adler-32) once the last
  // sample has been read: without it a flipped bit that still inflates would pass as data.
  // Throws if the check fails or the file ends before the trailer.
  void checkTrailer() {
    std::vector<unsigned char> scratch(1 << 16);
    while (!memberEnded_) {
      stream_.next_out = scratch.data();
      stream_.avail_out = static_cast<uInt>(scratch.size());
      if (!inflateStep()) {
        throw Error(path_, "compressed data ends before its checksum (the file is truncated)");
      }
      position_ += scratch.size() - stream_.avail_out;
    }
  }

 private:
  Error corrupt(int rc) const {
    return Error(path_, fmt::format("corrupt compressed data ({})",
                                    stream_.msg ? stream_.msg : zError(rc)));
  }

  // The next block of the file as zlib's input; false at the end of the file.
  bool refill() {
    file_.read(reinterpret_cast<char*>(input_.data()), static_cast<std::streamsize>(input_.size()));
    const auto got = static_cast<uInt>(file_.gcount());
    stream_.next_in = input_.data();
    stream_.avail_in = got;
    return got > 0;
  }

  void start() {
    file_.clear();
    file_.seekg(static_cast<std::streamoff>(fileOffsetBytes_));
    stream_ = {};
    // 15 + 32: a window of up to 32 KiB, with a gzip or zlib header detected automatically.
    if (inflateInit2(&stream_, 15 + 32) != Z_OK) throw Error(path_, "cannot start zlib");
    position_ = 0;
    memberEnded_ = false;
  }

  std::size_t inflateInto(unsigned char* dst, std::size_t n) {
    stream_.next_out = dst;
    stream_.avail_out = static_cast<uInt>(n);
    while (stream_.avail_out > 0) {
      if (memberEnded_) {
        // gzip allows several members back to back; more data is wanted, so go on.
        inflateReset(&stream_);
        memberEnded_ = false;
      }
      if (!inflateStep()) break;  // end of file: the caller reports it
    }
    const std::size_t produced = n - stream_.avail_out;
    position_ += produced;
    return produced;
  }

  // One call of inflate into the output window stream_ points at, refilling its input first if
  // it is empty; false when the file has no more input. Throws if the data is corrupt.
  bool inflateStep() {
    if (stream_.avail_in == 0 && !refill()) return false;
    const int rc = inflate(&stream_, Z_NO_FLUSH);
    if (rc == Z_STREAM_END) {
      memberEnded_ = true;
    } else if (rc != Z_OK && !(rc == Z_BUF_ERROR && stream_.avail_in == 0)) {
      throw corrupt(rc);
    }
    return true;
  }

  std::string path_;
  uint64_t fileOffsetBytes_;
  std::ifstream file_;
  std::vector<unsigned char> input_;
  z_stream stream_{};
  uint64_t position_ = 0;  // decompressed bytes delivered so far
  bool memberEnded_ = false;
};

class RawSource final : public VolumeSource {
 public:
  RawSource(VolumeInfo info, RawLayout layout)
      : info_(std::move(info)), layout_(std::move(layout)) {
    totalBytes_ = volumeBytes(layout_.dims, layout_.sampleType, layout_.dataPath);
    swap_ = layout_.bigEndian != (std::endian::native == std::endian::big);
    if (layout_.compression == Compression::None) {
      openUncompressed();
    } else {
      inflater_ = std::make_unique<InflateReader>(layout_.dataPath, layout_.fileOffsetBytes);
      // Reading the first sample now turns a file that is not compressed data at all into an
      // error at open rather than at the first slab.
      unsigned char first[8];
      const std::size_t want = sampleBytes(layout_.sampleType);
      if (inflater_->readAt(layout_.streamOffsetBytes, first, want) != want) throwTruncated();
    }
  }

  const VolumeInfo& info() const override { return info_; }

  void readSlab(int64_t firstSlice, int64_t sliceCount, std::span<float> out) override {
    checkSlabRequest(info_, firstSlice, sliceCount, out.size());
    const std::size_t bytesPerSample = sampleBytes(layout_.sampleType);
    const auto firstSample = static_cast<uint64_t>(firstSlice * info_.sliceSamples());
    buffer_.resize(std::min(out.size(), kChunkSamples) * bytesPerSample);
    for (std::size_t done = 0; done < out.size();) {
      const std::size_t count = std::min(out.size() - done, kChunkSamples);
      const uint64_t streamPos = (firstSample + done) * bytesPerSample;
      readBytes(streamPos, count * bytesPerSample);
      detail::convertSamples(layout_.sampleType, buffer_.data(), count, swap_, layout_.valueScale,
                             layout_.valueOffset, out.data() + done);
      done += count;
    }
  }

 private:
  void openUncompressed() {
    std::error_code ec;
    const uint64_t fileBytes = std::filesystem::file_size(layout_.dataPath, ec);
    if (ec) throw Error(layout_.dataPath, "cannot read the file: " + ec.message());
    const uint64_t headerBytes = layout_.fileOffsetBytes + layout_.streamOffsetBytes;
    if (fileBytes < headerBytes || fileBytes - headerBytes < totalBytes_) {
      throw Error(layout_.dataPath,
                  fmt::format("expected {} bytes of data after a {}-byte header, file has {}",
                              totalBytes_, headerBytes, fileBytes));
    }
    if (fileBytes - headerBytes > totalBytes_) {
      info_.warnings.push_back(fmt::format(
          "{} holds {} bytes of data, the volume needs {}: the rest is ignored (are the "
          "dimensions and the sample type right?)",
          layout_.dataPath, fileBytes - headerBytes, totalBytes_));
    }
    file_.open(layout_.dataPath, std::ios::binary);
    if (!file_) throw Error(layout_.dataPath, "cannot open the file for reading");
  }

  // Reads buffer_[0, n) from byte `streamPos` of the sample data.
  void readBytes(uint64_t streamPos, std::size_t n) {
    auto* dst = buffer_.data();
    if (inflater_) {
      if (inflater_->readAt(layout_.streamOffsetBytes + streamPos, dst, n) != n) throwTruncated();
      if (streamPos + n == totalBytes_) inflater_->checkTrailer();
      return;
    }
    file_.clear();
    file_.seekg(static_cast<std::streamoff>(layout_.fileOffsetBytes + layout_.streamOffsetBytes +
                                            streamPos));
    file_.read(reinterpret_cast<char*>(dst), static_cast<std::streamsize>(n));
    if (static_cast<std::size_t>(file_.gcount()) != n) {
      throw Error(
          layout_.dataPath,
          fmt::format("read failed at data byte {} (the file shrank while open?)", streamPos));
    }
  }

  [[noreturn]] void throwTruncated() const {
    const uint64_t delivered = inflater_->delivered();
    const uint64_t held =
        delivered > layout_.streamOffsetBytes ? delivered - layout_.streamOffsetBytes : 0;
    throw Error(layout_.dataPath,
                fmt::format("compressed data ends early: expected {} bytes of samples, the stream "
                            "holds {}",
                            totalBytes_, held));
  }

  VolumeInfo info_;
  RawLayout layout_;
  uint64_t totalBytes_ = 0;
  bool swap_ = false;
  std::ifstream file_;
  std::unique_ptr<InflateReader> inflater_;
  std::vector<unsigned char> buffer_;
};

}  // namespace

std::unique_ptr<VolumeSource> openRawLayout(VolumeInfo info, RawLayout layout) {
  if (info.dims != layout.dims) {
    throw Error(info.sourcePath, "internal: volume and data layout disagree on the dimensions");
  }
  info.sourceFiles = {info.sourcePath};
  if (layout.dataPath != info.sourcePath) info.sourceFiles.push_back(layout.dataPath);
  std::sort(info.sourceFiles.begin(), info.sourceFiles.end());
  info.integerValues = integerValued(layout.sampleType, layout.valueScale, layout.valueOffset);
  if (info.integerValues) {
    // The storage type's range, mapped through the value scale and offset.
    const auto [lo, hi] = sampleTypeRange(layout.sampleType);
    const double a = lo * layout.valueScale + layout.valueOffset;
    const double b = hi * layout.valueScale + layout.valueOffset;
    info.valueLowerBound = std::min(a, b);
    info.valueUpperBound = std::max(a, b);
  }
  return std::make_unique<RawSource>(std::move(info), std::move(layout));
}

}  // namespace detail

std::unique_ptr<VolumeSource> openRawVolume(const std::string& path, const RawOptions& options) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    throw Error(path, "not a readable file");
  }
  detail::volumeBytes(options.dims, options.sampleType, path);
  const Vec3 s = options.spacingMm;
  for (double v : {s.x, s.y, s.z}) {
    if (!std::isfinite(v) || v == 0) {
      throw Error(path, fmt::format("invalid spacing {} x {} x {} mm: every spacing must be a "
                                    "finite non-zero number",
                                    s.x, s.y, s.z));
    }
  }
  const Vec3 o = options.originMm;
  if (!std::isfinite(o.x) || !std::isfinite(o.y) || !std::isfinite(o.z)) {
    throw Error(path, "invalid origin: not a finite position");
  }

  VolumeInfo info;
  info.dims = options.dims;
  info.patientFromIndex = Mat4::fromColumns({s.x, 0, 0}, {0, s.y, 0}, {0, 0, s.z}, o);
  detail::checkAffine(info.patientFromIndex, path);
  info.format = "raw";
  info.sourcePath = path;
  info.description = std::filesystem::path(path).filename().string();

  detail::RawLayout layout;
  layout.dataPath = path;
  layout.dims = options.dims;
  layout.sampleType = options.sampleType;
  layout.bigEndian = options.bigEndian;
  layout.fileOffsetBytes = options.headerBytes;
  return detail::openRawLayout(std::move(info), std::move(layout));
}

}  // namespace octoray
