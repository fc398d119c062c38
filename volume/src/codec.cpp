#include "codec.h"

#include <lz4.h>
#include <xxhash.h>
#include <zstd.h>

#include <cstring>

#include "octoray/core/error.h"

namespace octoray::volume::detail {

std::size_t compress(Codec codec, int zstdLevel, std::span<const uint8_t> input,
                     std::vector<uint8_t>& out) {
  const std::size_t start = out.size();
  switch (codec) {
    case Codec::None:
      out.insert(out.end(), input.begin(), input.end());
      return input.size();
    case Codec::Lz4: {
      const int bound = LZ4_compressBound(static_cast<int>(input.size()));
      out.resize(start + static_cast<std::size_t>(bound));
      const int n = LZ4_compress_default(reinterpret_cast<const char*>(input.data()),
                                         reinterpret_cast<char*>(out.data() + start),
                                         static_cast<int>(input.size()), bound);
      if (n <= 0) throw Error("", "LZ4 compression failed");
      out.resize(start + static_cast<std::size_t>(n));
      return static_cast<std::size_t>(n);
    }
    case Codec::Zstd: {
      const std::size_t bound = ZSTD_compressBound(input.size());
      out.resize(start + bound);
      const std::size_t n =
          ZSTD_compress(out.data() + start, bound, input.data(), input.size(), zstdLevel);
      if (ZSTD_isError(n)) throw Error("", std::string("zstd compression failed: ") + ZSTD_getErrorName(n));
      out.resize(start + n);
      return n;
    }
  }
  throw Error("", "unknown codec");
}

bool decompress(Codec codec, std::span<const uint8_t> input, std::span<uint8_t> output) {
  switch (codec) {
    case Codec::None:
      if (input.size() != output.size()) return false;
      std::memcpy(output.data(), input.data(), input.size());
      return true;
    case Codec::Lz4: {
      const int n = LZ4_decompress_safe(reinterpret_cast<const char*>(input.data()),
                                        reinterpret_cast<char*>(output.data()),
                                        static_cast<int>(input.size()),
                                        static_cast<int>(output.size()));
      return n >= 0 && static_cast<std::size_t>(n) == output.size();
    }
    case Codec::Zstd: {
      const std::size_t n = ZSTD_decompress(output.data(), output.size(), input.data(), input.size());
      return !ZSTD_isError(n) && n == output.size();
    }
  }
  return false;
}

std::size_t compressSamples(Codec codec, int zstdLevel, std::span<const uint8_t> samples,
                            std::size_t sampleBytes, std::vector<uint8_t>& out) {
  if (sampleBytes <= 1) return compress(codec, zstdLevel, samples, out);
  const std::size_t count = samples.size() / sampleBytes;
  thread_local std::vector<uint8_t> planes;  // reused: no allocation or zeroing per brick
  planes.resize(samples.size());
  if (sampleBytes == 2) {
    // The common case (16-bit CT), written so the compiler vectorises it.
    uint8_t* low = planes.data();
    uint8_t* high = planes.data() + count;
    const uint8_t* s = samples.data();
    for (std::size_t i = 0; i < count; ++i) {
      low[i] = s[2 * i];
      high[i] = s[2 * i + 1];
    }
  } else {
    for (std::size_t b = 0; b < sampleBytes; ++b) {
      uint8_t* plane = planes.data() + b * count;
      for (std::size_t i = 0; i < count; ++i) plane[i] = samples[i * sampleBytes + b];
    }
  }
  return compress(codec, zstdLevel, planes, out);
}

bool decompressSamples(Codec codec, std::span<const uint8_t> input, std::span<uint8_t> samples,
                       std::size_t sampleBytes) {
  if (sampleBytes <= 1) return decompress(codec, input, samples);
  std::vector<uint8_t> planes(samples.size());
  if (!decompress(codec, input, planes)) return false;
  const std::size_t count = samples.size() / sampleBytes;
  for (std::size_t b = 0; b < sampleBytes; ++b) {
    const uint8_t* plane = planes.data() + b * count;
    for (std::size_t i = 0; i < count; ++i) samples[i * sampleBytes + b] = plane[i];
  }
  return true;
}

uint64_t checksum(const void* data, std::size_t bytes) { return XXH3_64bits(data, bytes); }

const char* codecName(Codec codec) {
  switch (codec) {
    case Codec::None: return "none";
    case Codec::Lz4: return "lz4";
    case Codec::Zstd: return "zstd";
  }
  return "unknown";
}

}  // namespace octoray::volume::detail
