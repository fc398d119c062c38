#include "octoray/volume/store_reader.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "codec.h"
#include "octoray/core/error.h"
#include "octoray/core/text.h"
#include "octoray/dicom/volume_source.h"

namespace octoray::volume {
namespace {

// Reads exactly `bytes` at `offset`; false on a short read (truncated file) or an I/O error.
bool readAt(int fd, void* buffer, std::size_t bytes, uint64_t offset) {
  auto* p = static_cast<char*>(buffer);
  while (bytes > 0) {
    const ssize_t n = ::pread(fd, p, bytes, static_cast<off_t>(offset));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    p += n;
    bytes -= static_cast<std::size_t>(n);
    offset += static_cast<uint64_t>(n);
  }
  return true;
}

}  // namespace

bool isStoreFile(const std::filesystem::path& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) return false;
  if (asciiLower(path.extension().string()) == ".octoray") return true;
  std::ifstream in(path, std::ios::binary);
  char magic[sizeof(kStoreMagic)] = {};
  in.read(magic, sizeof(magic));
  return in.gcount() == sizeof(magic) && std::equal(magic, magic + sizeof(magic), kStoreMagic);
}

StoreHeader parseStoreHeader(const void* bytes, std::size_t size, uint64_t fileBytes,
                             const std::string& path) {
  if (size < sizeof(StoreHeader)) {
    throw Error(path, fmt::format("header: file too short ({} bytes) to be an octoray store", size));
  }
  StoreHeader h;
  std::memcpy(&h, bytes, sizeof h);
  if (std::memcmp(h.magic, kStoreMagic, sizeof h.magic) != 0) {
    throw Error(path, "header: not an octoray store (bad magic)");
  }
  if (h.version != kStoreVersion) {
    // Another version's header may be laid out differently, so its checksum cannot be checked
    // here; a version number no release will reach is damage, not the future.
    if (h.version == 0 || h.version > 1000) {
      throw Error(path, fmt::format("header: corrupted (version field reads {})", h.version));
    }
    throw Error(path, fmt::format("header: store version {} is not supported (this build reads "
                                  "version {})", h.version, kStoreVersion));
  }
  if (detail::checksum(&h, offsetof(StoreHeader, headerChecksum)) != h.headerChecksum) {
    throw Error(path, "header: checksum mismatch (header corrupted)");
  }
  if (h.headerBytes != sizeof(StoreHeader)) throw Error(path, "header: wrong header size");
  if (h.fileBytes != fileBytes) {
    throw Error(path, fmt::format("header: file is {} bytes, header says {} (truncated or "
                                  "extended)", fileBytes, h.fileBytes));
  }
  if (h.sampleFormat > 1 || h.codec > 2) throw Error(path, "header: unknown sample format or codec");
  const auto within = [&](uint64_t offset, uint64_t length) {
    return offset >= sizeof(StoreHeader) && offset <= fileBytes && length <= fileBytes - offset;
  };
  // Counts are compared by division: a forged nodeCount must not wrap the multiplication.
  if (h.nodeCount > fileBytes / sizeof(NodeRecord) || !within(h.nodeTableOffset, h.nodeTableBytes) ||
      !within(h.provenanceOffset, h.provenanceBytes) ||
      h.nodeTableBytes != h.nodeCount * sizeof(NodeRecord)) {
    throw Error(path, "header: node table or provenance outside the file");
  }
  for (double v : h.patientFromIndex) {
    if (!std::isfinite(v)) throw Error(path, "header: non-finite affine");
  }
  {
    Mat4 m;
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 4; ++c) m.m[r][c] = h.patientFromIndex[r * 4 + c];
    }
    try {
      checkGeometry(m, path);
    } catch (const Error& e) {
      throw Error(path, "header: " + e.reason());
    }
  }
  if (!std::isfinite(h.valueScale) || !std::isfinite(h.valueOffset) || h.valueScale == 0) {
    throw Error(path, "header: invalid value mapping");
  }
  if ((h.flags & ~uint32_t{kStoreHasGradients}) != 0) {
    throw Error(path, fmt::format("header: unknown flags 0x{:x}", h.flags));
  }
  // The shader scales every gradient norm by it: with gradients it must be a positive number,
  // without them it is unused and written as 0.
  const bool gradients = (h.flags & kStoreHasGradients) != 0;
  if (!std::isfinite(h.gradientScale) || h.gradientScale < 0 ||
      (gradients && h.gradientScale == 0)) {
    throw Error(path, fmt::format("header: gradient scale {} is not a {} number", h.gradientScale,
                                  gradients ? "positive" : "finite non-negative"));
  }
  return h;
}

StoreSource parseStoreSource(const std::string& provenanceJson) {
  StoreSource s;
  const nlohmann::json provenance = nlohmann::json::parse(provenanceJson, nullptr, false);
  if (!provenance.is_object()) return s;
  const auto found = provenance.find("source");
  if (found == provenance.end() || !found->is_object()) return s;
  const nlohmann::json& source = *found;
  const auto text = [&](const char* key) {
    const auto v = source.find(key);
    return v != source.end() && v->is_string() ? v->get<std::string>() : std::string();
  };
  s.format = text("format");
  s.modality = text("modality");
  s.description = text("description");
  s.seriesUid = text("seriesUid");
  s.unit = text("unit");
  s.contentHash = text("contentHash");
  const auto integer = source.find("integerValues");
  if (integer != source.end() && integer->is_boolean()) s.integerValues = integer->get<bool>();
  const auto windows = source.find("windows");
  if (windows != source.end() && windows->is_array()) {
    for (const nlohmann::json& w : *windows) {
      if (!w.is_object()) continue;
      const auto center = w.find("center"), width = w.find("width"), explanation = w.find("explanation"),
                 function = w.find("function");
      if (center == w.end() || width == w.end() || !center->is_number() || !width->is_number()) continue;
      SourceWindow window;
      window.center = center->get<double>();
      window.width = width->get<double>();
      if (!std::isfinite(window.center) || !std::isfinite(window.width) || !(window.width > 0)) continue;
      if (explanation != w.end() && explanation->is_string()) window.explanation = explanation->get<std::string>();
      // The defined terms only, as the DICOM reader takes them.
      if (function != w.end() && function->is_string()) {
        window.function = sourceVoiFunction(function->get<std::string>()).value_or("");
      }
      s.windows.push_back(std::move(window));
    }
  }
  return s;
}

StoreReader::StoreReader(const std::string& path) : path_(path) {
  fd_ = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd_ < 0) throw Error(path, std::string("cannot open: ") + std::strerror(errno));
  try {
    struct stat st {};
    if (::fstat(fd_, &st) != 0) throw Error(path, "cannot stat");
    const auto fileBytes = static_cast<uint64_t>(st.st_size);
    char raw[sizeof(StoreHeader)] = {};
    const std::size_t got = std::min<uint64_t>(fileBytes, sizeof raw);
    if (!readAt(fd_, raw, got, 0)) throw Error(path, "header: cannot read");
    header_ = parseStoreHeader(raw, got, fileBytes, path);

    try {
      layout_ = OctreeLayout({header_.dims[0], header_.dims[1], header_.dims[2]},
                             static_cast<int>(header_.brickSize), static_cast<int>(header_.border));
    } catch (const Error& e) {
      throw Error(path, "header: " + e.reason());
    }
    if (layout_.levels() != static_cast<int>(header_.levels) ||
        layout_.nodeCount() != static_cast<int64_t>(header_.nodeCount)) {
      throw Error(path, "header: levels or node count disagree with the dimensions");
    }

    nodes_.resize(header_.nodeCount);
    if (!readAt(fd_, nodes_.data(), header_.nodeTableBytes, header_.nodeTableOffset) ||
        detail::checksum(nodes_.data(), header_.nodeTableBytes) != header_.nodeTableChecksum) {
      throw Error(path, "node table: checksum mismatch (node table corrupted)");
    }
    provenance_.resize(header_.provenanceBytes);
    if (!readAt(fd_, provenance_.data(), provenance_.size(), header_.provenanceOffset) ||
        detail::checksum(provenance_.data(), provenance_.size()) != header_.provenanceChecksum) {
      throw Error(path, "provenance: checksum mismatch");
    }
    source_ = parseStoreSource(provenance_);
    for (std::size_t i = 0; i < nodes_.size(); ++i) {
      const NodeRecord& n = nodes_[i];
      const uint64_t bytes = uint64_t{n.payloadBytes} + n.gradientBytes;
      const bool constant = (n.flags & kNodeConstant) != 0;
      const bool badConstant = constant && (bytes != 0 || (sampleFormat() == SampleFormat::UInt16 &&
                                                           n.constantSample > 65535));
      if (badConstant || (!constant && (n.payloadBytes == 0 ||
           n.payloadOffset < sizeof(StoreHeader) || n.payloadOffset > header_.nodeTableOffset ||
           bytes > header_.nodeTableOffset - n.payloadOffset)) ||
          !(n.minValue <= n.maxValue)) {
        throw Error(path, fmt::format("node table: node {} has an invalid record", i));
      }
    }
  } catch (...) {
    ::close(fd_);
    throw;
  }
}

StoreReader::~StoreReader() {
  if (fd_ >= 0) ::close(fd_);
}

const NodeRecord& StoreReader::node(int64_t id) const {
  if (id < 0 || static_cast<std::size_t>(id) >= nodes_.size()) {
    throw Error(path_, fmt::format("node {} out of range", id));
  }
  return nodes_[static_cast<std::size_t>(id)];
}

Mat4 StoreReader::patientFromIndex() const {
  Mat4 m;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) m.m[r][c] = header_.patientFromIndex[r * 4 + c];
  return m;
}

Brick StoreReader::readBrick(int64_t id) const {
  Brick brick = readBrickUnchecked(id);
  checkRange(brick, node(id), id);
  return brick;
}

Brick StoreReader::readBrickUnchecked(int64_t id) const {
  const NodeRecord& n = node(id);
  Brick brick;
  brick.nodeId = id;
  brick.edge = layout_.storedEdge();
  brick.format = sampleFormat();
  const auto samples = static_cast<std::size_t>(layout_.storedSamples());
  const bool hasGradients = (header_.flags & kStoreHasGradients) != 0;
  if (n.flags & kNodeConstant) {
    if (brick.format == SampleFormat::UInt16) {
      brick.u16.assign(samples, static_cast<uint16_t>(n.constantSample));
    } else {
      float value;
      std::memcpy(&value, &n.constantSample, sizeof value);
      brick.f32.assign(samples, value);
    }
    // A constant brick has a zero gradient: direction undefined (encoded as 128), norm 0.
    if (hasGradients) {
      brick.gradients.assign(samples * 4, 128);
      for (std::size_t i = 0; i < samples; ++i) brick.gradients[4 * i + 3] = 0;
    }
    return brick;
  }
  std::vector<uint8_t> payload(uint64_t{n.payloadBytes} + n.gradientBytes);
  if (!readAt(fd_, payload.data(), payload.size(), n.payloadOffset)) {
    throw Error(path_, fmt::format("node {}: payload cannot be read (file truncated?)", id));
  }
  if (detail::checksum(payload.data(), payload.size()) != n.payloadChecksum) {
    throw Error(path_, fmt::format("node {}: payload checksum mismatch (brick corrupted)", id));
  }
  const std::span<const uint8_t> values(payload.data(), n.payloadBytes);
  bool ok;
  const auto codec = static_cast<Codec>(header_.codec);
  if (brick.format == SampleFormat::UInt16) {
    brick.u16.resize(samples);
    ok = detail::decompressSamples(codec, values,
                                   {reinterpret_cast<uint8_t*>(brick.u16.data()), samples * 2}, 2);
  } else {
    brick.f32.resize(samples);
    ok = detail::decompressSamples(codec, values,
                                   {reinterpret_cast<uint8_t*>(brick.f32.data()), samples * 4}, 4);
  }
  if (ok && hasGradients) {
    brick.gradients.resize(samples * 4);
    ok = detail::decompressSamples(codec, {payload.data() + n.payloadBytes, n.gradientBytes},
                                   brick.gradients, 4);
  }
  if (!ok) throw Error(path_, fmt::format("node {}: payload does not decompress", id));
  return brick;
}

// The samples of every brick lie in its node's recorded [min, max] (the builder records the
// range over the brick, border included, and its descendants). A node table whose ranges lie
// (with checksums recomputed to match) would make the renderer skip visible bricks as empty:
// it is an error naming the store and the node instead of a wrong picture. One pass over
// samples already in cache, next to a decompression that touches every byte.
void StoreReader::checkRange(const Brick& brick, const NodeRecord& n, int64_t id) const {
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  bool finite = true;
  if (brick.format == SampleFormat::UInt16) {
    uint16_t a = 65535, b = 0;
    for (const uint16_t v : brick.u16) {
      a = std::min(a, v);
      b = std::max(b, v);
    }
    if (!brick.u16.empty()) lo = physical(a), hi = physical(b);
  } else {
    for (const float v : brick.f32) {
      finite = finite && std::isfinite(v);
      lo = std::min(lo, static_cast<double>(v));
      hi = std::max(hi, static_cast<double>(v));
    }
  }
  // Ranges are stored as float: allow their rounding.
  const auto slack = [](double v) { return 1e-6 * std::max(1.0, std::abs(v)); };
  if (!finite || lo < n.minValue - slack(n.minValue) || hi > n.maxValue + slack(n.maxValue)) {
    throw Error(path_, fmt::format("node {} (level {}): samples span [{}, {}], outside the node's "
                                   "recorded range [{}, {}] (node table inconsistent: the store is "
                                   "damaged)",
                                   id, layout_.nodeKey(id).level, lo, hi, n.minValue, n.maxValue));
  }
}

bool storeHoldsIntegerValues(const StoreReader& store) {
  const StoreSource& source = store.source();
  const StoreHeader& h = store.header();
  return source.integerValues ? *source.integerValues
                              : store.sampleFormat() == SampleFormat::UInt16 && h.valueScale == 1.0 &&
                                    h.valueOffset == std::round(h.valueOffset);
}

bool storeHoldsHounsfieldUnits(const StoreReader& store, bool* guessed) {
  const StoreSource& source = store.source();
  return holdsHounsfieldUnits(source.unit, source.modality, storeHoldsIntegerValues(store), store.node(0).minValue,
                              guessed);
}

}  // namespace octoray::volume
