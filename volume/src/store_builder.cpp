#include "octoray/core/atomic_file.h"
#include "octoray/volume/store_builder.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <deque>
#include <future>
#include <limits>
#include <nlohmann/json.hpp>
#include <optional>

#include <fmt/format.h>

#include "codec.h"
#include "octoray/core/error.h"
#include "octoray/volume/octree_layout.h"
#include "store_file_writer.h"

namespace octoray::volume {
namespace {

using detail::AtomicFileWriter;

// Value conversion between physical values and stored samples.
struct ValueMapping {
  SampleFormat format = SampleFormat::UInt16;
  double scale = 1, offset = -1024;
};

// One compressed brick, ready to be appended.
struct EncodedBrick {
  int64_t nodeId = -1;
  NodeRecord record{};
  std::vector<uint8_t> payload;
};

// The slices of one level that its next row of bricks (and the coarser level) still needs.
template <typename T>
struct LevelWindow {
  Index3 dims{};
  int64_t firstZ = 0;                     // level z of slices.front()
  using Slice = std::shared_ptr<const std::vector<T>>;
  std::deque<Slice> slices;
  int64_t nextRow = 0;                    // next brick row (bz) to emit
  Slice evenSlice;                        // waiting for its odd partner to make a coarse slice

  int64_t endZ() const { return firstZ + static_cast<int64_t>(slices.size()); }
  const T* slice(int64_t z) const {
    z = std::clamp<int64_t>(z, 0, dims[2] - 1);
    return slices[static_cast<std::size_t>(z - firstZ)]->data();
  }
};

template <typename T>
class Builder {
 public:
  Builder(VolumeSource& source, const BuildOptions& options, ValueMapping mapping,
          AtomicFileWriter& file)
      : source_(source),
        options_(options),
        mapping_(mapping),
        file_(file),
        layout_(source.info().dims, options.brickSize, options.border),
        windows_(static_cast<std::size_t>(layout_.levels())),
        records_(static_cast<std::size_t>(layout_.nodeCount())) {
    for (int l = 0; l < layout_.levels(); ++l) windows_[static_cast<std::size_t>(l)].dims = layout_.levelDims(l);
    planMemory();
    setUpGradients();
  }

  const OctreeLayout& layout() const { return layout_; }
  const std::vector<NodeRecord>& records() const { return records_; }
  BuildReport& report() { return report_; }
  float gradientScale() const { return static_cast<float>(gradientScale_); }

  void run() {
    const VolumeInfo& info = source_.info();
    const int64_t sliceSamples = info.sliceSamples();
    // The next slab is read on another thread while this one is cut into bricks.
    const auto readSlab = [this, &info, sliceSamples](int64_t z, std::vector<float>& slab) {
      const int64_t count = std::min(slabSlices_, info.dims[2] - z);
      slab.resize(static_cast<std::size_t>(sliceSamples * count));
      source_.readSlab(z, count, slab);
    };
    std::vector<float> current, next;
    std::future<void> pending = std::async(std::launch::async, readSlab, int64_t{0}, std::ref(next));
    for (int64_t z = 0; z < info.dims[2]; z += slabSlices_) {
      pending.get();
      std::swap(current, next);
      if (options_.cancel && options_.cancel->load()) throw BuildCancelled();
      if (z + slabSlices_ < info.dims[2]) {
        pending = std::async(std::launch::async, readSlab, z + slabSlices_, std::ref(next));
      }
      const int64_t count = std::min(slabSlices_, info.dims[2] - z);
      try {
        for (int64_t s = 0; s < count; ++s) {
          if constexpr (std::is_same_v<T, float>) {
            // Float stores keep samples as they are: a NaN or an infinity would poison every
            // range, filter and table downstream, so it is refused here, named.
            const float* in = current.data() + s * sliceSamples;
            for (int64_t i = 0; i < sliceSamples; ++i) {
              if (!std::isfinite(in[i])) {
                throw Error(info.sourcePath,
                            fmt::format("slice {}, column {}, row {}: the sample is {}; a store "
                                        "holds finite values only",
                                        z + s, i % info.dims[0], i / info.dims[0], in[i]));
              }
            }
          }
          std::vector<T> slice(static_cast<std::size_t>(sliceSamples));  // one pass of zeroing
          convert(std::span<const float>(current.data() + s * sliceSamples,
                                         static_cast<std::size_t>(sliceSamples)), slice);
          pushSlice(layout_.leafLevel(), std::move(slice));
        }
      } catch (...) {
        if (pending.valid()) pending.wait();  // never leave the reader running on our buffers
        throw;
      }
      if (options_.progress) options_.progress(z + count, info.dims[2]);
    }
    for (int l = layout_.leafLevel(); l >= 0; --l) finishLevel(l);
  }

 private:
  void planMemory() {
    const VolumeInfo& info = source_.info();
    uint64_t windowBytes = 0;
    for (int l = 0; l < layout_.levels(); ++l) {
      const Index3& d = layout_.levelDims(l);
      windowBytes += static_cast<uint64_t>(layout_.storedEdge() + 4) * static_cast<uint64_t>(d[0] * d[1]) * sizeof(T);
    }
    const uint64_t sliceFloatBytes = static_cast<uint64_t>(info.sliceSamples()) * sizeof(float);
    const uint64_t budget = options_.memoryBudgetBytes;
    slabSlices_ = std::clamp<int64_t>(static_cast<int64_t>(budget / 16 / std::max<uint64_t>(sliceFloatBytes, 1)), 1, 16);
    const uint64_t perBrick = static_cast<uint64_t>(layout_.storedSamples()) *
                              (sizeof(T) * 2 + (options_.gradients ? 8 : 0)) + 4096;
    const uint64_t fixed = windowBytes + 2 * static_cast<uint64_t>(slabSlices_) * sliceFloatBytes;
    if (fixed + 16 * perBrick > budget) {
      throw Error(info.sourcePath, fmt::format("memory budget of {} MiB is too small for slices of "
                                               "{}x{}: the build needs at least {} MiB",
                                               budget >> 20, info.dims[0], info.dims[1],
                                               (fixed + 16 * perBrick + (1 << 20) - 1) >> 20));
    }
    batchBricks_ = static_cast<int64_t>((budget - fixed) / perBrick);
  }

  void setUpGradients() {
    if (!options_.gradients) return;
    const Mat4& m = source_.info().patientFromIndex;
    const Vec3 s = source_.info().spacingMm();
    // Gradient norms above this (physical units per mm) saturate the 8-bit norm channel.
    gradientScale_ = 2048.0 / std::max(1e-6, std::min({s.x, s.y, s.z}));
    indexFromPatientLinear_ = m.inverseAffine();
  }

  void convert(std::span<const float> in, std::vector<T>& out) {
    if constexpr (std::is_same_v<T, float>) {
      std::copy(in.begin(), in.end(), out.begin());
    } else {
      const double scale = mapping_.scale, offset = mapping_.offset;
      // Integer sources with a unit scale (all CT): an exact integer subtraction that the
      // compiler vectorises; values of float magnitude below 2^24 convert exactly.
      const bool integerPath = source_.info().integerValues && scale == 1 &&
                               offset == std::round(offset) && std::abs(offset) < (1 << 24);
      const auto offsetInt = static_cast<int32_t>(offset);
      std::atomic<int64_t> clamped{0};
      tbb::parallel_for(tbb::blocked_range<std::size_t>(0, in.size(), 1 << 16), [&](const auto& r) {
        int64_t localClamped = 0;
        if (integerPath) {
          for (std::size_t i = r.begin(); i != r.end(); ++i) {
            const float v = std::clamp(in[i], -16777216.0f, 16777216.0f);  // NaN stays NaN
            const int32_t stored = (v == v ? static_cast<int32_t>(v) : 0) - offsetInt;
            const int32_t c = std::clamp(stored, 0, 65535);
            localClamped += (c != stored) | (v != in[i]);
            out[i] = static_cast<uint16_t>(c);
          }
        } else {
          for (std::size_t i = r.begin(); i != r.end(); ++i) {
            const double stored = std::round((in[i] - offset) / scale);
            const double c = std::clamp(stored, 0.0, 65535.0);
            localClamped += (c != stored) || !std::isfinite(in[i]);
            out[i] = static_cast<uint16_t>(std::isfinite(c) ? c : 0.0);
          }
        }
        clamped += localClamped;
      });
      report_.clampedSamples += clamped.load();
    }
  }

  // A new slice of `level`: emit the rows it completes, then feed the coarser level (so a
  // parent row is always emitted after its children's rows).
  void pushSlice(int level, std::vector<T> slice) {
    LevelWindow<T>& w = windows_[static_cast<std::size_t>(level)];
    auto added = std::make_shared<const std::vector<T>>(std::move(slice));
    w.slices.push_back(added);
    std::optional<std::vector<T>> coarse;
    if (level > 0) {
      if (!w.evenSlice) {
        w.evenSlice = added;
      } else {
        coarse = downsample(w, *w.evenSlice, *added);
        w.evenSlice.reset();
      }
    }
    emitReadyRows(level, false);
    if (coarse) pushSlice(level - 1, std::move(*coarse));
  }

  void finishLevel(int level) {
    LevelWindow<T>& w = windows_[static_cast<std::size_t>(level)];
    emitReadyRows(level, true);
    if (level > 0 && w.evenSlice) {
      // Odd depth: the last coarse slice averages the last slice with itself (edge clamp).
      pushSlice(level - 1, downsample(w, *w.evenSlice, *w.evenSlice));
      w.evenSlice.reset();
    }
  }

  // The coarse slice averaging two fine slices over 2x2 in-plane blocks (clamped at edges).
  std::vector<T> downsample(const LevelWindow<T>& fine, const std::vector<T>& a, const std::vector<T>& b) {
    const Index3& fd = fine.dims;
    const Index3& cd = windows_[static_cast<std::size_t>(&fine - windows_.data()) - 1].dims;
    std::vector<T> coarse(static_cast<std::size_t>(cd[0] * cd[1]));
    tbb::parallel_for(int64_t{0}, cd[1], [&](int64_t y) {
      const int64_t y0 = 2 * y, y1 = std::min(2 * y + 1, fd[1] - 1);
      for (int64_t x = 0; x < cd[0]; ++x) {
        const int64_t x0 = 2 * x, x1 = std::min(2 * x + 1, fd[0] - 1);
        const double sum = double(a[y0 * fd[0] + x0]) + a[y0 * fd[0] + x1] + a[y1 * fd[0] + x0] +
                           a[y1 * fd[0] + x1] + b[y0 * fd[0] + x0] + b[y0 * fd[0] + x1] +
                           b[y1 * fd[0] + x0] + b[y1 * fd[0] + x1];
        if constexpr (std::is_same_v<T, float>) {
          coarse[static_cast<std::size_t>(y * cd[0] + x)] = static_cast<float>(sum / 8.0);
        } else {
          // Round half up, in integers: exactly reproducible by the validator.
          coarse[static_cast<std::size_t>(y * cd[0] + x)] = static_cast<uint16_t>((static_cast<int64_t>(sum) + 4) / 8);
        }
      }
    });
    return coarse;
  }

  void emitReadyRows(int level, bool final) {
    LevelWindow<T>& w = windows_[static_cast<std::size_t>(level)];
    // A row reads A slices beyond its bricks, one more for central-difference gradients.
    const int64_t B = layout_.brickSize(), A = layout_.border() + (options_.gradients ? 1 : 0);
    const int64_t rows = layout_.levelBricks(level)[2];
    while (w.nextRow < rows) {
      const int64_t needEnd = std::min((w.nextRow + 1) * B + A, w.dims[2]);
      if (w.endZ() < needEnd && !final) break;
      emitRow(level, w.nextRow);
      ++w.nextRow;
      // Drop slices no later row needs (keep the first the next row reads).
      const int64_t keepFrom = std::max<int64_t>(0, w.nextRow * B - A);
      while (w.firstZ < keepFrom && !w.slices.empty()) {
        w.slices.pop_front();
        ++w.firstZ;
      }
    }
  }

  void emitRow(int level, int64_t bz) {
    const Index3& nb = layout_.levelBricks(level);
    const int64_t count = nb[0] * nb[1];
    for (int64_t start = 0; start < count; start += batchBricks_) {
      const int64_t n = std::min(batchBricks_, count - start);
      std::vector<EncodedBrick> batch(static_cast<std::size_t>(n));
      tbb::parallel_for(int64_t{0}, n, [&](int64_t i) {
        const int64_t flat = start + i;
        const NodeKey key{level, {flat % nb[0], flat / nb[0], bz}};
        batch[static_cast<std::size_t>(i)] = encodeBrick(key);
      });
      for (EncodedBrick& b : batch) {
        if (!b.payload.empty()) b.record.payloadOffset = file_.append(b.payload);
        records_[static_cast<std::size_t>(b.nodeId)] = b.record;
        report_.constantNodes += (b.record.flags & kNodeConstant) ? 1 : 0;
      }
    }
  }

  EncodedBrick encodeBrick(const NodeKey& key) {
    const LevelWindow<T>& w = windows_[static_cast<std::size_t>(key.level)];
    const int64_t B = layout_.brickSize(), A = layout_.border(), E = layout_.storedEdge();
    const Index3& d = w.dims;
    std::vector<T> samples(static_cast<std::size_t>(E * E * E));
    T lo = std::numeric_limits<T>::max(), hi = std::numeric_limits<T>::lowest();
    const int64_t x0 = key.brick[0] * B - A;
    const bool xInside = x0 >= 0 && x0 + E <= d[0];
    T* out = samples.data();
    for (int64_t z = 0; z < E; ++z) {
      const T* slice = w.slice(key.brick[2] * B - A + z);
      for (int64_t y = 0; y < E; ++y) {
        const T* row = slice + std::clamp<int64_t>(key.brick[1] * B - A + y, 0, d[1] - 1) * d[0];
        if (xInside) {
          std::memcpy(out, row + x0, static_cast<std::size_t>(E) * sizeof(T));
        } else {
          for (int64_t x = 0; x < E; ++x) out[x] = row[std::clamp<int64_t>(x0 + x, 0, d[0] - 1)];
        }
        for (int64_t x = 0; x < E; ++x) {
          lo = std::min(lo, out[x]);
          hi = std::max(hi, out[x]);
        }
        out += E;
      }
    }
    EncodedBrick encoded;
    encoded.nodeId = layout_.nodeId(key);
    NodeRecord& r = encoded.record;
    r.minValue = static_cast<float>(physical(lo));
    r.maxValue = static_cast<float>(physical(hi));
    const bool constant = lo == hi;
    // The range also bounds every descendant's range: emptiness of a node is then sound for
    // its whole subtree (children are always emitted before their parent).
    for (int64_t child : layout_.children(encoded.nodeId)) {
      const NodeRecord& c = records_[static_cast<std::size_t>(child)];
      r.minValue = std::min(r.minValue, c.minValue);
      r.maxValue = std::max(r.maxValue, c.maxValue);
    }
    if (constant) {
      // Its own value, apart from the range, which may be wider (varying descendants).
      r.flags = kNodeConstant;
      if constexpr (std::is_same_v<T, float>) {
        std::memcpy(&r.constantSample, &lo, sizeof lo);
      } else {
        r.constantSample = lo;
      }
      return encoded;
    }
    const std::span<const uint8_t> bytes(reinterpret_cast<const uint8_t*>(samples.data()), samples.size() * sizeof(T));
    r.payloadBytes = static_cast<uint32_t>(detail::compressSamples(options_.codec, options_.zstdLevel, bytes, sizeof(T), encoded.payload));
    if (options_.gradients) {
      const std::vector<uint8_t> gradients = computeGradients(key);
      r.gradientBytes = static_cast<uint32_t>(detail::compressSamples(options_.codec, options_.zstdLevel, gradients, 4, encoded.payload));
    }
    r.payloadChecksum = detail::checksum(encoded.payload.data(), encoded.payload.size());
    return encoded;
  }

  double physical(T stored) const {
    if constexpr (std::is_same_v<T, float>) return stored;
    return stored * mapping_.scale + mapping_.offset;
  }

  // Central differences on the level's own grid (neighbours from the window, clamped at the
  // volume's edge), turned into a patient-space gradient through the level's affine.
  std::vector<uint8_t> computeGradients(const NodeKey& key) const {
    const LevelWindow<T>& w = windows_[static_cast<std::size_t>(key.level)];
    const int64_t B = layout_.brickSize(), A = layout_.border(), E = layout_.storedEdge();
    const Index3& d = w.dims;
    const double levelScale = static_cast<double>(layout_.levelScale(key.level));
    const auto& inv = indexFromPatientLinear_.m;  // d(index)/d(patient), leaf index units
    std::vector<uint8_t> out(static_cast<std::size_t>(E * E * E * 4));
    const auto at = [&](int64_t x, int64_t y, int64_t z) {
      const T* s = w.slice(z);
      return physical(s[std::clamp<int64_t>(y, 0, d[1] - 1) * d[0] + std::clamp<int64_t>(x, 0, d[0] - 1)]);
    };
    std::size_t o = 0;
    for (int64_t z = 0; z < E; ++z) {
      const int64_t gz = std::clamp<int64_t>(key.brick[2] * B - A + z, 0, d[2] - 1);
      for (int64_t y = 0; y < E; ++y) {
        const int64_t gy = std::clamp<int64_t>(key.brick[1] * B - A + y, 0, d[1] - 1);
        for (int64_t x = 0; x < E; ++x, o += 4) {
          const int64_t gx = std::clamp<int64_t>(key.brick[0] * B - A + x, 0, d[0] - 1);
          // Derivatives per level sample; one level sample is levelScale leaf samples.
          const double di = (at(gx + 1, gy, gz) - at(gx - 1, gy, gz)) / (2.0 * levelScale);
          const double dj = (at(gx, gy + 1, gz) - at(gx, gy - 1, gz)) / (2.0 * levelScale);
          const double dk = (at(gx, gy, std::min(gz + 1, d[2] - 1)) - at(gx, gy, std::max<int64_t>(gz - 1, 0))) / (2.0 * levelScale);
          // grad_patient = (d index / d patient)^T * grad_index
          const double gxp = inv[0][0] * di + inv[1][0] * dj + inv[2][0] * dk;
          const double gyp = inv[0][1] * di + inv[1][1] * dj + inv[2][1] * dk;
          const double gzp = inv[0][2] * di + inv[1][2] * dj + inv[2][2] * dk;
          const double norm = std::sqrt(gxp * gxp + gyp * gyp + gzp * gzp);
          const double s = norm > 0 ? 1.0 / norm : 0.0;
          const auto encode = [](double v) { return static_cast<uint8_t>(std::lround((v * 0.5 + 0.5) * 255.0)); };
          out[o + 0] = encode(gxp * s);
          out[o + 1] = encode(gyp * s);
          out[o + 2] = encode(gzp * s);
          out[o + 3] = static_cast<uint8_t>(std::lround(std::min(1.0, norm / gradientScale_) * 255.0));
        }
      }
    }
    return out;
  }

  VolumeSource& source_;
  const BuildOptions& options_;
  ValueMapping mapping_;
  AtomicFileWriter& file_;
  OctreeLayout layout_;
  std::vector<LevelWindow<T>> windows_;
  std::vector<NodeRecord> records_;
  BuildReport report_;
  int64_t slabSlices_ = 4;
  int64_t batchBricks_ = 64;
  double gradientScale_ = 0;
  Mat4 indexFromPatientLinear_;
};

// UInt16 when every value is an integer and fits 65536 steps: CT in HU as HU + 1024 (the
// usual convention; values outside [-1024, 64511] are clamped and counted), other integer
// data from the lower bound of its storage type. Float32 otherwise.
ValueMapping chooseMapping(const VolumeInfo& info, BuildOptions::Format format) {
  ValueMapping m;
  const bool ct = info.integerValues && info.unit == "HU";
  const bool boundedIntegers = info.integerValues && std::isfinite(info.valueLowerBound) &&
                               std::isfinite(info.valueUpperBound) &&
                               info.valueUpperBound - info.valueLowerBound <= 65535;
  const bool useUInt16 = format == BuildOptions::Format::UInt16 ||
                         (format == BuildOptions::Format::Auto && (ct || boundedIntegers));
  if (!useUInt16) {
    m.format = SampleFormat::Float32;
    m.scale = 1;
    m.offset = 0;
    return m;
  }
  m.format = SampleFormat::UInt16;
  m.scale = 1;
  if (info.unit == "HU") {
    m.offset = -1024.0;
  } else {
    m.offset = std::isfinite(info.valueLowerBound) ? info.valueLowerBound : 0.0;
  }
  return m;
}

std::string provenance(const VolumeInfo& info, const BuildOptions& options) {
  // Geometry and processing only: no patient name, no paths (they may name patients).
  nlohmann::json j = nlohmann::json::parse(options.provenanceJson.empty() ? "{}" : options.provenanceJson,
                                           nullptr, false);
  if (j.is_discarded() || !j.is_object()) throw Error("", "provenance JSON is not an object");
  j["source"] = {{"format", info.format}, {"modality", info.modality},
                 {"description", info.description}, {"seriesUid", info.seriesUid},
                 {"unit", info.unit}, {"integerValues", info.integerValues},
                 {"tiltDegrees", info.tiltDegrees},
                 {"resampled", info.resampled}, {"warnings", info.warnings.size()}};
  if (!options.sourceContentHash.empty()) j["source"]["contentHash"] = options.sourceContentHash;
  if (!info.windows.empty()) {
    nlohmann::json windows = nlohmann::json::array();
    for (const SourceWindow& w : info.windows) {
      nlohmann::json window{{"center", w.center}, {"width", w.width}, {"explanation", w.explanation}};
      if (!w.function.empty()) window["function"] = w.function;
      windows.push_back(std::move(window));
    }
    j["source"]["windows"] = windows;
  }
  j["builder"] = {{"software", "octoray"}, {"storeVersion", kStoreVersion},
                  {"brickSize", options.brickSize}, {"border", options.border},
                  {"gradients", options.gradients}, {"codec", detail::codecName(options.codec)}};
  // DICOM text (a description, a window's explanation) is in the file's character set, often
  // not UTF-8 (ISO_IR 100): its bytes that are not UTF-8 become U+FFFD instead of failing the
  // build.
  return j.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

template <typename T>
BuildReport buildWith(VolumeSource& source, const std::string& outPath, const BuildOptions& options,
                      ValueMapping mapping) {
  const auto start = std::chrono::steady_clock::now();
  const VolumeInfo& info = source.info();
  const std::string provenanceText = provenance(info, options);
  AtomicFileWriter file(outPath);
  std::vector<uint8_t> zeros(sizeof(StoreHeader), 0);
  file.append(zeros);  // the header is written last, once every offset is known

  Builder<T> builder(source, options, mapping, file);
  builder.run();

  StoreHeader h{};
  std::memcpy(h.magic, kStoreMagic, sizeof h.magic);
  h.version = kStoreVersion;
  h.headerBytes = sizeof(StoreHeader);
  for (int a = 0; a < 3; ++a) h.dims[a] = info.dims[static_cast<std::size_t>(a)];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) h.patientFromIndex[r * 4 + c] = info.patientFromIndex.m[r][c];
  h.brickSize = static_cast<uint32_t>(options.brickSize);
  h.border = static_cast<uint32_t>(options.border);
  h.levels = static_cast<uint32_t>(builder.layout().levels());
  h.sampleFormat = static_cast<uint32_t>(mapping.format);
  h.valueScale = mapping.scale;
  h.valueOffset = mapping.offset;
  h.codec = static_cast<uint32_t>(options.codec);
  h.flags = options.gradients ? uint32_t{kStoreHasGradients} : 0u;
  h.gradientScale = builder.gradientScale();
  const auto& records = builder.records();
  h.nodeCount = records.size();
  h.nodeTableBytes = records.size() * sizeof(NodeRecord);
  h.nodeTableChecksum = detail::checksum(records.data(), h.nodeTableBytes);
  h.nodeTableOffset = file.append({reinterpret_cast<const uint8_t*>(records.data()), h.nodeTableBytes});
  h.provenanceBytes = provenanceText.size();
  h.provenanceChecksum = detail::checksum(provenanceText.data(), provenanceText.size());
  h.provenanceOffset = file.append({reinterpret_cast<const uint8_t*>(provenanceText.data()), provenanceText.size()});
  h.fileBytes = file.size();
  h.headerChecksum = detail::checksum(&h, offsetof(StoreHeader, headerChecksum));
  file.writeAt(0, {reinterpret_cast<const uint8_t*>(&h), sizeof h});
  file.commit();

  BuildReport report = builder.report();
  report.voxels = info.sampleCount();
  report.nodes = static_cast<int64_t>(records.size());
  report.levels = builder.layout().levels();
  report.bytesOnDisk = h.fileBytes;
  report.uncompressedBytes = static_cast<uint64_t>(report.nodes) * static_cast<uint64_t>(builder.layout().storedSamples()) * sizeof(T);
  report.sampleFormat = mapping.format;
  report.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return report;
}

}  // namespace

BuildReport buildStore(VolumeSource& source, const std::string& outPath, const BuildOptions& options) {
  const VolumeInfo& info = source.info();
  if (info.sampleCount() <= 0) throw Error(info.sourcePath, "volume has no samples");
  // What the reader (and the validator) would refuse is refused before anything is written.
  checkGeometry(info.patientFromIndex, info.sourcePath);
  checkOutputIsNotAnInput(outPath, info.sourceFiles);
  const ValueMapping mapping = chooseMapping(info, options.format);
  try {
    if (mapping.format == SampleFormat::UInt16) return buildWith<uint16_t>(source, outPath, options, mapping);
    return buildWith<float>(source, outPath, options, mapping);
  } catch (const Error& e) {
    if (!e.path().empty()) throw;
    throw Error(outPath, e.reason());
  }
}

}  // namespace octoray::volume
