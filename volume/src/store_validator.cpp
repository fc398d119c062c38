#include "octoray/volume/store_validator.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <fstream>
#include <list>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <unordered_map>

#include <fmt/format.h>

#include "octoray/core/error.h"
#include "octoray/volume/store_reader.h"

namespace octoray::volume {

const char* toString(CheckStatus status) {
  switch (status) {
    case CheckStatus::Passed:
      return "PASS";
    case CheckStatus::Failed:
      return "FAIL";
    case CheckStatus::NotRun:
      return "NOT RUN";
  }
  return "?";
}

bool ValidationReport::passed() const {
  return !checks.empty() &&
         std::all_of(checks.begin(), checks.end(), [](const CheckResult& c) { return c.passed(); });
}

const CheckResult* ValidationReport::find(std::string_view name) const {
  for (const CheckResult& c : checks) {
    if (c.name == name) return &c;
  }
  return nullptr;
}

namespace {

// One check's results, gathered from many threads. Keeps the failures with the lowest node
// ids, so the report does not depend on scheduling.
class CheckCollector {
 public:
  CheckCollector(std::string name, int maxFailures) : maxFailures_(maxFailures) {
    result_.name = std::move(name);
  }
  void count(int64_t items = 1) { checked_ += items; }
  void fail(int64_t nodeId, std::string message) {
    ++failed_;
    std::lock_guard lock(mutex_);
    auto& f = result_.failures;
    if (static_cast<int>(f.size()) >= maxFailures_) {
      auto last = std::max_element(f.begin(), f.end(), byNode);
      if (last == f.end() || nodeId >= last->nodeId) return;
      f.erase(last);
    }
    f.push_back({nodeId, std::move(message)});
  }
  CheckResult result() {
    std::lock_guard lock(mutex_);
    CheckResult r = result_;
    std::sort(r.failures.begin(), r.failures.end(), byNode);
    r.checked = checked_.load();
    r.failedCount = failed_.load();
    r.status = r.failedCount > 0 ? CheckStatus::Failed : CheckStatus::Passed;
    return r;
  }

 private:
  static bool byNode(const CheckFailure& a, const CheckFailure& b) { return a.nodeId < b.nodeId; }

  int maxFailures_;
  std::atomic<int64_t> checked_{0}, failed_{0};
  std::mutex mutex_;
  CheckResult result_;
};

// Decompressed bricks shared by the worker threads, least recently used evicted past a byte
// budget. Bricks that fail to read are remembered as bad and never read again.
class BrickCache {
 public:
  BrickCache(const StoreReader& store, uint64_t budgetBytes)
      : store_(store),
        budgetBytes_(budgetBytes),
        bad_(static_cast<std::size_t>(store.layout().nodeCount())) {}

  // The brick, or nullptr when it does not read (its error in `error` when given).
  std::shared_ptr<const Brick> get(int64_t id, std::string* error = nullptr) {
    if (bad_[static_cast<std::size_t>(id)].load() && !error) return nullptr;
    {
      std::lock_guard lock(mutex_);
      if (auto it = entries_.find(id); it != entries_.end()) {
        lru_.splice(lru_.begin(), lru_, it->second.position);
        return it->second.brick;
      }
    }
    std::shared_ptr<const Brick> brick;
    try {
      brick = std::make_shared<const Brick>(store_.readBrickUnchecked(id));
    } catch (const std::exception& e) {
      bad_[static_cast<std::size_t>(id)] = true;
      if (error) *error = e.what();
      return nullptr;
    }
    std::lock_guard lock(mutex_);
    if (auto it = entries_.find(id); it != entries_.end()) return it->second.brick;
    lru_.push_front(id);
    entries_.emplace(id, Entry{brick, lru_.begin()});
    bytes_ += brick->byteSize();
    while (bytes_ > budgetBytes_ && lru_.size() > 1) {
      const auto victim = entries_.find(lru_.back());
      bytes_ -= victim->second.brick->byteSize();
      entries_.erase(victim);
      lru_.pop_back();
    }
    return brick;
  }

 private:
  struct Entry {
    std::shared_ptr<const Brick> brick;
    std::list<int64_t>::iterator position;
  };
  const StoreReader& store_;
  uint64_t budgetBytes_;
  std::vector<std::atomic<bool>> bad_;
  std::mutex mutex_;
  std::unordered_map<int64_t, Entry> entries_;
  std::list<int64_t> lru_;
  uint64_t bytes_ = 0;
};

template <typename T>
std::span<const T> samplesOf(const Brick& b) {
  if constexpr (std::is_same_v<T, float>) {
    return b.f32;
  } else {
    return b.u16;
  }
}

template <typename T>
bool sameSample(T a, T b) {
  if constexpr (std::is_same_v<T, float>) {
    return a == b || (std::isnan(a) && std::isnan(b));
  } else {
    return a == b;
  }
}

// Where each stored sample of a brick lies along one axis: its level position clamped to the
// level, the brick that owns that position and the position in the owner's stored samples.
struct AxisMap {
  std::vector<int64_t> ownerStep;  // owner brick - this brick: -1, 0 or +1
  std::vector<int> ownerLocal;     // stored index of the clamped position in the owner
  std::vector<bool> moved;         // position outside the level: clamped to the edge
};

AxisMap mapAxis(int64_t brick, int64_t B, int64_t A, int64_t levelDim) {
  const int64_t E = B + 2 * A;
  AxisMap m;
  for (int64_t t = 0; t < E; ++t) {
    const int64_t g = brick * B - A + t;
    const int64_t gc = std::clamp<int64_t>(g, 0, levelDim - 1);
    const int64_t owner = gc / B;
    m.ownerStep.push_back(owner - brick);
    m.ownerLocal.push_back(static_cast<int>(gc - owner * B + A));
    m.moved.push_back(g != gc);
  }
  return m;
}

// The checks that read bricks, run node by node.
template <typename T>
class NodeChecker {
 public:
  NodeChecker(const StoreReader& store, BrickCache& cache, int maxFailures)
      : store_(store),
        layout_(store.layout()),
        cache_(cache),
        checksums_("checksums", maxFailures),
        ranges_("ranges", maxFailures),
        borders_("borders", maxFailures),
        filter_("filter", maxFailures),
        constants_("constants", maxFailures) {}

  void check(int64_t id) {
    const NodeRecord& record = store_.node(id);
    checksums_.count();
    std::string error;
    const std::shared_ptr<const Brick> brick = cache_.get(id, &error);
    if (!brick) {
      checksums_.fail(id, error);
    }
    constants_.count();
    if (record.flags & kNodeConstant) {
      // The constant's own value must lie in the node's (subtree) range.
      double value;
      if (store_.sampleFormat() == SampleFormat::UInt16) {
        value = store_.physical(static_cast<double>(record.constantSample));
      } else {
        float f;
        std::memcpy(&f, &record.constantSample, sizeof f);
        value = f;
      }
      if (!(value >= record.minValue && value <= record.maxValue)) {
        constants_.fail(id, fmt::format("constant node's value {} lies outside its range [{}, {}]",
                                        value, record.minValue, record.maxValue));
      }
    }
    if (!brick) return;
    const std::span<const T> samples = samplesOf<T>(*brick);
    checkRanges(id, record, samples);
    checkBorders(id, samples);
    if (layout_.nodeKey(id).level < layout_.leafLevel()) checkFilter(id, samples);
  }

  std::vector<CheckResult> results() {
    return {checksums_.result(), ranges_.result(), borders_.result(), filter_.result(),
            constants_.result()};
  }

 private:
  float physical(T stored) const {
    return static_cast<float>(store_.physical(static_cast<double>(stored)));
  }

  void checkRanges(int64_t id, const NodeRecord& r, std::span<const T> samples) {
    ranges_.count();
    std::optional<T> lo, hi;
    for (T s : samples) {
      if constexpr (std::is_same_v<T, float>) {
        if (std::isnan(s)) continue;
      }
      if (!lo || s < *lo) lo = s;
      if (!hi || s > *hi) hi = s;
    }
    if (lo && (physical(*lo) < r.minValue || physical(*hi) > r.maxValue)) {
      ranges_.fail(id, fmt::format("stored samples span [{}, {}], outside the node's [{}, {}]",
                                   physical(*lo), physical(*hi), r.minValue, r.maxValue));
      return;
    }
    for (int64_t child : layout_.children(id)) {
      const NodeRecord& c = store_.node(child);
      if (c.minValue < r.minValue || c.maxValue > r.maxValue) {
        ranges_.fail(id, fmt::format("child {} spans [{}, {}], outside the node's [{}, {}]", child,
                                     c.minValue, c.maxValue, r.minValue, r.maxValue));
        return;
      }
    }
  }

  // Every stored sample that is not the brick's own interior sample equals the sample it
  // replicates. A sample owned by another brick is compared with the face neighbour one step
  // towards the owner along the first axis where they differ; that neighbour's sample is
  // either its interior or itself checked the same way, so every border is checked by
  // induction with face neighbours only.
  void checkBorders(int64_t id, std::span<const T> samples) {
    borders_.count();
    const NodeKey key = layout_.nodeKey(id);
    const int64_t B = layout_.brickSize(), A = layout_.border(), E = layout_.storedEdge();
    const Index3& d = layout_.levelDims(key.level);
    std::array<AxisMap, 3> axes;
    for (std::size_t a = 0; a < 3; ++a) axes[a] = mapAxis(key.brick[a], B, A, d[a]);
    std::array<std::array<std::shared_ptr<const Brick>, 2>, 3> neighbours;
    std::array<std::array<bool, 2>, 3> loaded{};
    int64_t mismatches = 0;
    std::string first;
    std::array<int64_t, 3> t{};
    for (t[2] = 0; t[2] < E; ++t[2])
      for (t[1] = 0; t[1] < E; ++t[1])
        for (t[0] = 0; t[0] < E; ++t[0]) {
          int axis = -1;
          bool moved = false;
          for (std::size_t a = 0; a < 3; ++a) {
            moved = moved || axes[a].moved[static_cast<std::size_t>(t[a])];
            if (axis < 0 && axes[a].ownerStep[static_cast<std::size_t>(t[a])] != 0)
              axis = static_cast<int>(a);
          }
          if (axis < 0 && !moved) continue;  // an interior sample: the original
          std::array<int64_t, 3> src = t;
          const T* sourceSamples = samples.data();
          int64_t sourceNode = id;
          if (axis < 0) {
            for (std::size_t a = 0; a < 3; ++a)
              src[a] = axes[a].ownerLocal[static_cast<std::size_t>(t[a])];
          } else {
            const auto a = static_cast<std::size_t>(axis);
            const int64_t step = axes[a].ownerStep[static_cast<std::size_t>(t[a])];
            const std::size_t side = step > 0 ? 1 : 0;
            sourceNode = layout_.neighbor(id, axis, static_cast<int>(step));
            if (!loaded[a][side]) {
              neighbours[a][side] = sourceNode >= 0 ? cache_.get(sourceNode) : nullptr;
              loaded[a][side] = true;
            }
            if (!neighbours[a][side]) continue;  // unreadable: reported by `checksums`
            sourceSamples = samplesOf<T>(*neighbours[a][side]).data();
            src[a] = axes[a].ownerLocal[static_cast<std::size_t>(t[a])];
          }
          const T got = samples[static_cast<std::size_t>(t[0] + E * (t[1] + E * t[2]))];
          const T expected = sourceSamples[src[0] + E * (src[1] + E * src[2])];
          if (sameSample(got, expected)) continue;
          if (mismatches++ == 0) {
            first = fmt::format("stored sample ({},{},{}) is {} but node {} holds {} at ({},{},{})",
                                t[0], t[1], t[2], physical(got), sourceNode, physical(expected),
                                src[0], src[1], src[2]);
          }
        }
    if (mismatches > 0) {
      borders_.fail(id, fmt::format("{} border sample(s) differ; first: {}", mismatches, first));
    }
  }

  // Every interior sample inside the level equals the builder's box filter of the 2x2x2
  // finer samples (clamped at the finer level's edge), computed in the builder's order.
  void checkFilter(int64_t id, std::span<const T> samples) {
    const NodeKey key = layout_.nodeKey(id);
    const int64_t B = layout_.brickSize(), A = layout_.border(), E = layout_.storedEdge();
    const Index3& cd = layout_.levelDims(key.level);
    const Index3& fd = layout_.levelDims(key.level + 1);
    // The children by their offset (0 or 1 per axis) from 2 * brick.
    std::array<std::shared_ptr<const Brick>, 8> children;
    for (int64_t child : layout_.children(id)) {
      const NodeKey ck = layout_.nodeKey(child);
      const int64_t slot = (ck.brick[0] - 2 * key.brick[0]) + 2 * (ck.brick[1] - 2 * key.brick[1]) +
                           4 * (ck.brick[2] - 2 * key.brick[2]);
      children[static_cast<std::size_t>(slot)] = cache_.get(child);
      if (!children[static_cast<std::size_t>(slot)]) return;  // reported by `checksums`
    }
    filter_.count();
    // Per axis and interior index: the two fine samples as (child offset, stored index).
    struct Fine {
      int child[2];
      int64_t local[2];
      bool inside;
    };
    std::array<std::vector<Fine>, 3> axes;
    for (std::size_t a = 0; a < 3; ++a) {
      for (int64_t t = A; t < A + B; ++t) {
        const int64_t s = key.brick[a] * B + t - A;
        Fine f{};
        f.inside = s < cd[a];
        const int64_t pos[2] = {2 * s, std::min(2 * s + 1, fd[a] - 1)};
        for (int i = 0; i < 2; ++i) {
          const int64_t childBrick = pos[i] / B;
          f.child[i] = static_cast<int>(childBrick - 2 * key.brick[a]);
          f.local[i] = pos[i] - childBrick * B + A;
        }
        axes[a].push_back(f);
      }
    }
    const auto fine = [&](const Fine& x, int ix, const Fine& y, int iy, const Fine& z, int iz) {
      const Brick& c =
          *children[static_cast<std::size_t>(x.child[ix] + 2 * y.child[iy] + 4 * z.child[iz])];
      return samplesOf<T>(
          c)[static_cast<std::size_t>(x.local[ix] + E * (y.local[iy] + E * z.local[iz]))];
    };
    int64_t mismatches = 0;
    std::string first;
    for (int64_t z = 0; z < B; ++z) {
      const Fine& fz = axes[2][static_cast<std::size_t>(z)];
      if (!fz.inside) continue;
      for (int64_t y = 0; y < B; ++y) {
        const Fine& fy = axes[1][static_cast<std::size_t>(y)];
        if (!fy.inside) continue;
        for (int64_t x = 0; x < B; ++x) {
          const Fine& fx = axes[0][static_cast<std::size_t>(x)];
          if (!fx.inside) continue;
          // The builder's order: the even slice's 2x2 block (rows, then columns), then the odd's.
          double sum = 0;
          for (int iz = 0; iz < 2; ++iz)
            for (int iy = 0; iy < 2; ++iy)
              for (int ix = 0; ix < 2; ++ix)
                sum += static_cast<double>(fine(fx, ix, fy, iy, fz, iz));
          T expected;
          if constexpr (std::is_same_v<T, float>) {
            expected = static_cast<float>(sum / 8.0);
          } else {
            expected = static_cast<uint16_t>((static_cast<int64_t>(sum) + 4) / 8);
          }
          const T got = samples[static_cast<std::size_t>((x + A) + E * ((y + A) + E * (z + A)))];
          if (sameSample(got, expected)) continue;
          if (mismatches++ == 0) {
            first = fmt::format("sample ({},{},{}) is {}, the filtered children give {}", x + A,
                                y + A, z + A, physical(got), physical(expected));
          }
        }
      }
    }
    if (mismatches > 0) {
      filter_.fail(id, fmt::format("{} sample(s) differ from the box filter of the children; "
                                   "first: {}",
                                   mismatches, first));
    }
  }

  const StoreReader& store_;
  const OctreeLayout& layout_;
  BrickCache& cache_;
  CheckCollector checksums_, ranges_, borders_, filter_, constants_;
};

CheckResult notRun(const std::string& name, const std::string& why) {
  CheckResult r;
  r.name = name;
  r.status = CheckStatus::NotRun;
  r.notes.push_back(why);
  return r;
}

CheckResult failedCheck(const std::string& name, int64_t checked, std::string message) {
  CheckResult r;
  r.name = name;
  r.status = CheckStatus::Failed;
  r.checked = checked;
  r.failedCount = 1;
  r.failures.push_back({-1, std::move(message)});
  return r;
}

// The reader's open errors that concern the geometry rather than the file's integrity.
bool isGeometryReason(const std::string& reason) {
  for (const char* word : {"affine", "dimension", "brick size", "border", "levels"}) {
    if (reason.find(word) != std::string::npos) return true;
  }
  return false;
}

CheckResult checkGeometry(const StoreReader& store) {
  CheckResult r;
  r.name = "geometry";
  const StoreHeader& h = store.header();
  const auto fail = [&](std::string message) {
    ++r.failedCount;
    r.failures.push_back({-1, std::move(message)});
  };
  for (int a = 0; a < 3; ++a) {
    ++r.checked;
    if (h.dims[a] <= 0) fail(fmt::format("dimension {} is {}", a, h.dims[a]));
  }
  ++r.checked;
  const auto& m = h.patientFromIndex;
  if (!std::all_of(std::begin(m), std::end(m), [](double v) { return std::isfinite(v); })) {
    fail("the index-to-patient affine has non-finite entries");
  } else {
    const auto col = [&](int c) { return std::array<double, 3>{m[c], m[4 + c], m[8 + c]}; };
    const auto c0 = col(0), c1 = col(1), c2 = col(2);
    const double det = c0[0] * (c1[1] * c2[2] - c1[2] * c2[1]) -
                       c1[0] * (c0[1] * c2[2] - c0[2] * c2[1]) +
                       c2[0] * (c0[1] * c1[2] - c0[2] * c1[1]);
    double volume = 1;
    for (const auto& c : {c0, c1, c2}) {
      const double spacingMm = std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
      ++r.checked;
      if (!(spacingMm >= 1e-4 && spacingMm <= 1e4)) {
        fail(fmt::format("voxel spacing {} mm is outside 1e-4..1e4 mm", spacingMm));
      }
      volume *= spacingMm;
    }
    // Singular, or so sheared that the axes are nearly coplanar.
    if (!(std::abs(det) > 1e-6 * volume))
      fail(fmt::format("the affine is singular (determinant {})", det));
  }
  ++r.checked;
  const OctreeLayout& layout = store.layout();
  if (h.brickSize != 16 && h.brickSize != 32 && h.brickSize != 64) {
    fail(fmt::format("brick size {} is not 16, 32 or 64", h.brickSize));
  }
  if (h.border != 1 && h.border != 2) fail(fmt::format("border {} is not 1 or 2", h.border));
  if (static_cast<int64_t>(h.levels) != layout.levels() ||
      static_cast<int64_t>(h.nodeCount) != layout.nodeCount()) {
    fail(fmt::format("{} levels and {} nodes, the dimensions give {} and {}", h.levels, h.nodeCount,
                     layout.levels(), layout.nodeCount()));
  }
  const Index3& top = layout.levelBricks(0);
  if (top[0] != 1 || top[1] != 1 || top[2] != 1) fail("the root level has more than one brick");
  if (h.sampleFormat == static_cast<uint32_t>(SampleFormat::UInt16) &&
      !(std::isfinite(h.valueScale) && std::isfinite(h.valueOffset) && h.valueScale != 0)) {
    fail("invalid value mapping");
  }
  r.status = r.failedCount > 0 ? CheckStatus::Failed : CheckStatus::Passed;
  return r;
}

template <typename T>
std::vector<CheckResult> checkNodes(const StoreReader& store,
                                    const StoreValidationOptions& options) {
  BrickCache cache(store, options.cacheBudgetBytes);
  NodeChecker<T> checker(store, cache, std::max(1, options.maxFailuresPerCheck));
  const int64_t total = store.layout().nodeCount();
  std::atomic<int64_t> done{0};
  std::mutex progressMutex;
  tbb::parallel_for(tbb::blocked_range<int64_t>(0, total, 16), [&](const auto& range) {
    for (int64_t id = range.begin(); id != range.end(); ++id) checker.check(id);
    const int64_t now = done += static_cast<int64_t>(range.size());
    if (options.progress) {
      std::lock_guard lock(progressMutex);
      options.progress(now, total);
    }
  });
  return checker.results();
}

}  // namespace

ValidationReport validateStore(const std::string& path, const StoreValidationOptions& options) {
  ValidationReport report;
  report.path = path;
  report.kind = "store";
  const char* const nodeChecks[] = {"checksums", "ranges", "borders", "filter", "constants"};
  std::unique_ptr<StoreReader> store;
  try {
    store = std::make_unique<StoreReader>(path);
    // The provenance must be a JSON object (its checksum is already verified).
    const auto provenance = nlohmann::json::parse(store->provenanceJson(), nullptr, false);
    if (provenance.is_discarded() || !provenance.is_object()) {
      throw Error(path, "provenance: not a JSON object");
    }
  } catch (const std::exception& e) {
    const auto* error = dynamic_cast<const Error*>(&e);
    const std::string reason = error ? error->reason() : e.what();
    const bool geometry = isGeometryReason(reason);
    report.checks.push_back(geometry ? CheckResult{"header", CheckStatus::Passed, 1, 0, {}, {}}
                                     : failedCheck("header", 1, reason));
    report.checks.push_back(geometry ? failedCheck("geometry", 1, reason)
                                     : notRun("geometry", "the store does not open"));
    for (const char* name : nodeChecks)
      report.checks.push_back(notRun(name, "the store does not open"));
    return report;
  }
  report.checks.push_back(CheckResult{"header", CheckStatus::Passed, 1, 0, {}, {}});
  report.checks.push_back(checkGeometry(*store));
  if (!report.checks.back().passed()) {
    for (const char* name : nodeChecks)
      report.checks.push_back(notRun(name, "the geometry is invalid"));
    return report;
  }
  std::vector<CheckResult> nodes = store->sampleFormat() == SampleFormat::UInt16
                                       ? checkNodes<uint16_t>(*store, options)
                                       : checkNodes<float>(*store, options);
  for (CheckResult& r : nodes) report.checks.push_back(std::move(r));
  return report;
}

}  // namespace octoray::volume
