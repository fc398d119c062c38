#include "octoray/dicom/volume_source.h"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>
#include <vector>

#include <xxhash.h>

#include <fmt/format.h>

#include "octoray/core/error.h"

namespace octoray {

namespace {

XXH128_hash_t hashFile(const std::string& path) {
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> file(std::fopen(path.c_str(), "rb"), std::fclose);
  if (!file) throw Error(path, fmt::format("cannot read the file: {}", std::strerror(errno)));
  std::unique_ptr<XXH3_state_t, XXH_errorcode (*)(XXH3_state_t*)> state(XXH3_createState(),
                                                                         XXH3_freeState);
  XXH3_128bits_reset(state.get());
  std::vector<char> buffer(std::size_t{1} << 20);
  while (true) {
    const std::size_t got = std::fread(buffer.data(), 1, buffer.size(), file.get());
    XXH3_128bits_update(state.get(), buffer.data(), got);
    if (got < buffer.size()) break;
  }
  if (std::ferror(file.get())) throw Error(path, "read error while hashing the file");
  return XXH3_128bits_digest(state.get());
}

}  // namespace

std::optional<std::string> sourceVoiFunction(std::string_view declared) {
  if (declared.empty() || declared == "LINEAR") return std::string();
  if (declared == "LINEAR_EXACT" || declared == "SIGMOID") return std::string(declared);
  return std::nullopt;
}

bool holdsHounsfieldUnits(const std::string& unit, const std::string& modality, bool integerValues,
                          double minimum, bool* guessed) {
  if (guessed) *guessed = false;
  if (unit == "HU" || modality == "CT") return true;
  if (!modality.empty()) return false;
  const bool looksLikeCt = integerValues && minimum <= -900 && minimum >= -3100;
  if (guessed) *guessed = looksLikeCt;
  return looksLikeCt;
}

std::string fileContentHash(const std::string& file) {
  XXH128_canonical_t digest;
  XXH128_canonicalFromHash(&digest, hashFile(file));
  std::string hex;
  for (unsigned char byte : digest.digest) hex += fmt::format("{:02x}", byte);
  return hex;
}

std::string combinedContentHash(std::vector<std::string> fileHashes) {
  // Sorted as hex (the same order as the bytes), then the bytes hashed.
  std::sort(fileHashes.begin(), fileHashes.end());
  std::vector<unsigned char> bytes;
  bytes.reserve(fileHashes.size() * 16);
  for (const auto& hex : fileHashes) {
    if (hex.size() != 32) throw Error("", fmt::format("'{}' is not a file content hash", hex));
    for (std::size_t i = 0; i < 32; i += 2) {
      bytes.push_back(static_cast<unsigned char>(std::stoi(hex.substr(i, 2), nullptr, 16)));
    }
  }
  XXH128_canonical_t combined;
  XXH128_canonicalFromHash(&combined, XXH3_128bits(bytes.data(), bytes.size()));
  std::string hex;
  for (unsigned char byte : combined.digest) hex += fmt::format("{:02x}", byte);
  return hex;
}

std::string sourceContentHash(const std::vector<std::string>& files) {
  std::vector<std::string> hashes;
  hashes.reserve(files.size());
  for (const auto& f : files) hashes.push_back(fileContentHash(f));
  return combinedContentHash(std::move(hashes));
}

void checkSlabRequest(const VolumeInfo& info, int64_t firstSlice, int64_t sliceCount,
                      std::size_t outSize) {
  if (firstSlice < 0 || sliceCount < 0 || firstSlice + sliceCount > info.dims[2]) {
    throw Error(info.sourcePath, fmt::format("slab [{}, {}) is outside the volume's {} slices",
                                             firstSlice, firstSlice + sliceCount, info.dims[2]));
  }
  const auto needed = static_cast<std::size_t>(info.sliceSamples() * sliceCount);
  if (outSize != needed) {
    throw Error(info.sourcePath,
                fmt::format("slab buffer holds {} samples, {} slices need {}", outSize,
                            sliceCount, needed));
  }
}

void checkGeometry(const Mat4& m, const std::string& path) {
  bool finite = true;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 4; ++c) finite = finite && std::isfinite(m.m[r][c]);
  }
  const Vec3 spacing{length(m.column(0)), length(m.column(1)), length(m.column(2))};
  for (const double sp : {spacing.x, spacing.y, spacing.z}) {
    if (!finite || !(sp >= 1e-6 && sp <= 1e6)) {
      throw Error(path, fmt::format("spacing {} x {} x {} mm is outside [1e-6, 1e6] mm or the "
                                    "position is not finite: the geometry is not usable",
                                    spacing.x, spacing.y, spacing.z));
    }
  }
  // A position a kilometre or more from the scanner's origin is damage, and at 1e300 the
  // slice step (a difference of positions) is lost to rounding.
  const Vec3 origin = m.column(3);
  for (const double o : {origin.x, origin.y, origin.z}) {
    if (!(std::abs(o) <= 1e6)) {
      throw Error(path, fmt::format("position ({}, {}, {}) mm is over 1e6 mm from the origin: the "
                                    "geometry is not usable",
                                    origin.x, origin.y, origin.z));
    }
  }
  const double det = dot(m.column(0), cross(m.column(1), m.column(2)));
  if (!std::isfinite(det) || !(std::abs(det) > 1e-9 * spacing.x * spacing.y * spacing.z)) {
    throw Error(path, "the index-to-patient affine is singular (parallel axes)");
  }
}

}  // namespace octoray
