#pragma once
// Lossless payload compression and checksums for the store (internal to volume/).

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "octoray/volume/store_format.h"

namespace octoray::volume::detail {

// Appends the compressed form of `input` to `out`; returns the number of bytes appended.
std::size_t compress(Codec codec, int zstdLevel, std::span<const uint8_t> input,
                     std::vector<uint8_t>& out);
// Decompresses exactly `output.size()` bytes; returns false when the data is corrupt.
bool decompress(Codec codec, std::span<const uint8_t> input, std::span<uint8_t> output);
// Samples are byte-shuffled before compression (byte 0 of every sample, then byte 1, ...,
// as Blosc does): CT's high bytes form long runs, its noisy low bytes are passed over quickly.
std::size_t compressSamples(Codec codec, int zstdLevel, std::span<const uint8_t> samples,
                            std::size_t sampleBytes, std::vector<uint8_t>& out);
bool decompressSamples(Codec codec, std::span<const uint8_t> input, std::span<uint8_t> samples,
                       std::size_t sampleBytes);
uint64_t checksum(const void* data, std::size_t bytes);
const char* codecName(Codec codec);

}  // namespace octoray::volume::detail
