#pragma once
// Helpers shared by the format tests: voxel values from a known function, encoders for every
// sample type and byte order, gzip/zlib payloads, hand-made TIFFs, and whole-volume checks.

#include <gtest/gtest.h>
#include <zlib.h>

#include <algorithm>
#include <bit>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <string>
#include <vector>

#include "octoray/core/error.h"
#include "octoray/dicom/formats.h"

namespace octoray::formats_test {

namespace fs = std::filesystem;

// A deterministic integer per voxel that reaches far into every type's range.
inline uint64_t voxelHash(int64_t i, int64_t j, int64_t k) {
  return static_cast<uint64_t>(i * 2654435761LL + j * 40503LL + k * 9973LL + 17) *
         0x9E3779B97F4A7C15ULL;
}

template <typename T>
T typedValue(int64_t i, int64_t j, int64_t k) {
  const uint64_t h = voxelHash(i, j, k);
  if constexpr (std::is_floating_point_v<T>) {
    return static_cast<T>(static_cast<double>(h >> 40) * 0.37 - 1e6);
  } else {
    return static_cast<T>(h >> (64 - 8 * sizeof(T)));  // wraps: covers negatives too
  }
}

template <typename T>
inline std::string encode(const std::array<int64_t, 3>& dims, bool bigEndian) {
  std::string bytes;
  for (int64_t k = 0; k < dims[2]; ++k)
    for (int64_t j = 0; j < dims[1]; ++j)
      for (int64_t i = 0; i < dims[0]; ++i) {
        T v = typedValue<T>(i, j, k);
        char b[sizeof(T)];
        std::memcpy(b, &v, sizeof(T));
        if (bigEndian != (std::endian::native == std::endian::big)) std::reverse(b, b + sizeof(T));
        bytes.append(b, sizeof(T));
      }
  return bytes;
}

inline std::string encodeAs(SampleType type, const std::array<int64_t, 3>& dims, bool bigEndian) {
  switch (type) {
    case SampleType::UInt8:
      return encode<uint8_t>(dims, bigEndian);
    case SampleType::Int8:
      return encode<int8_t>(dims, bigEndian);
    case SampleType::UInt16:
      return encode<uint16_t>(dims, bigEndian);
    case SampleType::Int16:
      return encode<int16_t>(dims, bigEndian);
    case SampleType::UInt32:
      return encode<uint32_t>(dims, bigEndian);
    case SampleType::Int32:
      return encode<int32_t>(dims, bigEndian);
    case SampleType::Float32:
      return encode<float>(dims, bigEndian);
    case SampleType::Float64:
      return encode<double>(dims, bigEndian);
  }
  return {};
}

inline float expectedAs(SampleType type, int64_t i, int64_t j, int64_t k) {
  switch (type) {
    case SampleType::UInt8:
      return static_cast<float>(typedValue<uint8_t>(i, j, k));
    case SampleType::Int8:
      return static_cast<float>(typedValue<int8_t>(i, j, k));
    case SampleType::UInt16:
      return static_cast<float>(typedValue<uint16_t>(i, j, k));
    case SampleType::Int16:
      return static_cast<float>(typedValue<int16_t>(i, j, k));
    case SampleType::UInt32:
      return static_cast<float>(typedValue<uint32_t>(i, j, k));
    case SampleType::Int32:
      return static_cast<float>(typedValue<int32_t>(i, j, k));
    case SampleType::Float32:
      return typedValue<float>(i, j, k);
    case SampleType::Float64:
      return static_cast<float>(typedValue<double>(i, j, k));
  }
  return 0;
}

inline void writeFile(const fs::path& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  ASSERT_TRUE(out.good()) << path;
}

// The whole file as bytes.
inline std::string readFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

// Level 0 stores the bytes uncompressed: a flipped byte in them still inflates, and only the
// trailer's checksum can tell.
inline std::string gzipBytes(const std::string& bytes, int level = 6) {
  z_stream z{};
  EXPECT_EQ(deflateInit2(&z, level, Z_DEFLATED, 15 + 16, 8, Z_DEFAULT_STRATEGY), Z_OK);
  std::string out(deflateBound(&z, bytes.size()) + 64, '\0');
  z.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(bytes.data()));
  z.avail_in = static_cast<uInt>(bytes.size());
  z.next_out = reinterpret_cast<Bytef*>(out.data());
  z.avail_out = static_cast<uInt>(out.size());
  EXPECT_EQ(deflate(&z, Z_FINISH), Z_STREAM_END);
  out.resize(z.total_out);
  deflateEnd(&z);
  return out;
}

inline std::string zlibBytes(const std::string& bytes, int level = 6) {
  uLongf size = compressBound(bytes.size());
  std::string out(size, '\0');
  EXPECT_EQ(compress2(reinterpret_cast<Bytef*>(out.data()), &size,
                      reinterpret_cast<const Bytef*>(bytes.data()), bytes.size(), level),
            Z_OK);
  out.resize(size);
  return out;
}

// Reads the whole volume in slabs of `slabSlices` and checks every value against `expected`.
inline void expectValues(VolumeSource& source, int64_t slabSlices,
                         const std::function<float(int64_t, int64_t, int64_t)>& expected) {
  const auto& dims = source.info().dims;
  for (int64_t first = 0; first < dims[2]; first += slabSlices) {
    const int64_t count = std::min(slabSlices, dims[2] - first);
    std::vector<float> slab(static_cast<std::size_t>(source.info().sliceSamples() * count));
    source.readSlab(first, count, slab);
    std::size_t n = 0;
    for (int64_t k = first; k < first + count; ++k)
      for (int64_t j = 0; j < dims[1]; ++j)
        for (int64_t i = 0; i < dims[0]; ++i, ++n) {
          ASSERT_EQ(slab[n], expected(i, j, k)) << "at " << i << "," << j << "," << k;
        }
  }
}

inline void expectAffineNear(const Mat4& actual, const Mat4& expected, double tolerance) {
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) {
      EXPECT_NEAR(actual.m[r][c], expected.m[r][c], tolerance) << "element " << r << "," << c;
    }
}

// Expects `call` to throw octoray::Error whose message mentions `mention`.
template <typename F>
inline void expectErrorMentioning(F&& call, const std::string& mention) {
  try {
    call();
    ADD_FAILURE() << "no octoray::Error thrown (expected one mentioning " << mention << ")";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(mention), std::string::npos) << e.what();
  }
}

// A TIFF made by hand for the reader's tests, so that no TIFF library writes what libtiff
// reads: the 8-byte header, one IFD right after it (entries sorted by tag), the entries'
// out-of-line values, then `blocks` (the strips or tiles, as they lie in the file) in order.
// The offset and byte-count entries of the blocks are added here.
struct TiffEntry {
  uint16_t tag;
  uint16_t type;  // 3: SHORT, 4: LONG
  std::vector<uint32_t> values;
};

inline std::string tiffBytes(std::vector<TiffEntry> entries, const std::vector<std::string>& blocks,
                             bool tiled, bool bigEndian) {
  std::string out;
  const auto put = [&](auto value) {
    char b[sizeof value];
    std::memcpy(b, &value, sizeof value);
    if (bigEndian != (std::endian::native == std::endian::big)) std::reverse(b, b + sizeof value);
    out.append(b, sizeof value);
  };
  const auto valueBytes = [](const TiffEntry& e) {
    return e.values.size() * (e.type == 3 ? 2 : 4);
  };
  std::vector<uint32_t> counts;
  for (const auto& block : blocks) counts.push_back(static_cast<uint32_t>(block.size()));
  entries.push_back(
      {static_cast<uint16_t>(tiled ? 324 : 273), 4, std::vector<uint32_t>(blocks.size())});
  entries.push_back({static_cast<uint16_t>(tiled ? 325 : 279), 4, counts});
  std::sort(entries.begin(), entries.end(),
            [](const TiffEntry& a, const TiffEntry& b) { return a.tag < b.tag; });
  uint32_t outOfLine = 8 + 2 + 12 * static_cast<uint32_t>(entries.size()) + 4;
  uint32_t data = outOfLine;
  for (const auto& e : entries)
    if (valueBytes(e) > 4) data += static_cast<uint32_t>(valueBytes(e));
  for (auto& e : entries) {
    if (e.tag != (tiled ? 324 : 273)) continue;
    uint32_t at = data;
    for (std::size_t b = 0; b < blocks.size(); ++b) {
      e.values[b] = at;
      at += counts[b];
    }
  }
  out += bigEndian ? "MM" : "II";
  put(uint16_t{42});
  put(uint32_t{8});
  put(static_cast<uint16_t>(entries.size()));
  for (const auto& e : entries) {
    put(e.tag);
    put(e.type);
    put(static_cast<uint32_t>(e.values.size()));
    if (valueBytes(e) > 4) {
      put(outOfLine);
      outOfLine += static_cast<uint32_t>(valueBytes(e));
      continue;
    }
    const std::size_t start = out.size();
    for (uint32_t v : e.values) e.type == 3 ? put(static_cast<uint16_t>(v)) : put(v);
    out.append(4 - (out.size() - start), '\0');
  }
  put(uint32_t{0});  // no next page
  for (const auto& e : entries) {
    if (valueBytes(e) <= 4) continue;
    for (uint32_t v : e.values) e.type == 3 ? put(static_cast<uint16_t>(v)) : put(v);
  }
  for (const auto& block : blocks) out += block;
  return out;
}

inline constexpr SampleType kAllTypes[] = {
    SampleType::UInt8,  SampleType::Int8,  SampleType::UInt16,  SampleType::Int16,
    SampleType::UInt32, SampleType::Int32, SampleType::Float32, SampleType::Float64};

}  // namespace octoray::formats_test
