#include "octoray/viewer/mpr.h"

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "octoray/core/error.h"

namespace octoray::viewer {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Standard screen axes (radiological convention, LPS): axial looks from the feet (right = +X
// patient left, down = +Y posterior); coronal from the front (right = +X, down = -Z);
// sagittal from the patient's left... with anterior on the screen's left (right = +Y, down = -Z).
void standardAxes(ViewId v, Vec3& right, Vec3& down) {
  switch (v) {
    case ViewId::Axial: right = {1, 0, 0}; down = {0, 1, 0}; return;
    case ViewId::Coronal: right = {1, 0, 0}; down = {0, 0, -1}; return;
    case ViewId::Sagittal: right = {0, 1, 0}; down = {0, 0, -1}; return;
    case ViewId::Volume: break;
  }
  throw Error("", "the 3D view has no MPR plane");
}

Vec3 rotate(const Mat4& r, Vec3 v) { return r.transformVector(v); }

}  // namespace

// ---- Grid ----------------------------------------------------------------------------------

Grid::Grid(std::array<int64_t, 3> d, const Mat4& m)
    : dims(d), patientFromIndex(m), indexFromPatient(m.inverseAffine()) {}

Grid Grid::of(const volume::StoreReader& store) {
  const auto& d = store.header().dims;
  return Grid({d[0], d[1], d[2]}, store.patientFromIndex());
}

Vec3 Grid::centre() const {
  return patientFromIndex.transformPoint({0.5 * static_cast<double>(dims[0] - 1),
                                          0.5 * static_cast<double>(dims[1] - 1),
                                          0.5 * static_cast<double>(dims[2] - 1)});
}

double Grid::extentAlong(Vec3 direction) const {
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (int c = 0; c < 8; ++c) {
    const Vec3 corner{(c & 1) ? static_cast<double>(dims[0]) - 0.5 : -0.5,
                      (c & 2) ? static_cast<double>(dims[1]) - 0.5 : -0.5,
                      (c & 4) ? static_cast<double>(dims[2]) - 0.5 : -0.5};
    const double t = dot(patientFromIndex.transformPoint(corner), direction);
    lo = std::min(lo, t);
    hi = std::max(hi, t);
  }
  return hi - lo;
}

double Grid::sliceStepMm(Vec3 normal) const {
  int best = 0;
  double bestCos = -1;
  for (int a = 0; a < 3; ++a) {
    const Vec3 axis = patientFromIndex.column(a);
    const double c = std::abs(dot(normalize(axis), normal));
    if (c > bestCos) {
      bestCos = c;
      best = a;
    }
  }
  const double step = std::abs(dot(patientFromIndex.column(best), normal));
  return step > 1e-6 ? step : minSpacingMm();
}

double Grid::minSpacingMm() const {
  return std::min({length(patientFromIndex.column(0)), length(patientFromIndex.column(1)),
                   length(patientFromIndex.column(2))});
}

// ---- Planes --------------------------------------------------------------------------------

Mat4 rotationAbout(Vec3 axis, double radians) {
  axis = normalize(axis);
  const double c = std::cos(radians), s = std::sin(radians), t = 1 - c;
  const double x = axis.x, y = axis.y, z = axis.z;
  Mat4 r;
  r.m[0] = {t * x * x + c, t * x * y - s * z, t * x * z + s * y, 0};
  r.m[1] = {t * x * y + s * z, t * y * y + c, t * y * z - s * x, 0};
  r.m[2] = {t * x * z - s * y, t * y * z + s * x, t * z * z + c, 0};
  return r;
}

void viewAxes(ViewId v, const Mat4& rotation, Vec3& right, Vec3& down, Vec3& normal) {
  Vec3 r0, d0;
  standardAxes(v, r0, d0);
  normal = normalize(rotate(rotation, cross(r0, d0)));
  // The standard right axis projected onto the rotated plane; when it is (nearly) along the
  // normal, the rotated right axis instead.
  Vec3 r = r0 - dot(r0, normal) * normal;
  if (length(r) < 1e-6) r = rotate(rotation, r0);
  right = normalize(r);
  down = normalize(cross(normal, right));
}

MprPlane mprPlane(ViewId v, const Session& s, const Grid& grid, int width, int height) {
  MprPlane p;
  p.width = std::max(1, width);
  p.height = std::max(1, height);
  viewAxes(v, s.mprRotation, p.right, p.down, p.normal);
  const MprViewState& view = s.mprViews[static_cast<std::size_t>(v)];
  const double fit = std::max(grid.extentAlong(p.right) / p.width,
                              grid.extentAlong(p.down) / p.height);
  p.mmPerPixel = fit / std::max(1e-6, view.zoom);
  // The view centre: the domain's centre moved onto the plane through the crosshair, panned.
  const Vec3 centre = grid.centre();
  const Vec3 onPlane = centre + dot(s.crosshair - centre, p.normal) * p.normal;
  const Vec3 viewCentre = onPlane + view.panRightMm * p.right + view.panDownMm * p.down;
  p.origin = viewCentre - (0.5 * p.width * p.mmPerPixel) * p.right -
             (0.5 * p.height * p.mmPerPixel) * p.down;
  return p;
}

std::string orientationLabel(Vec3 d) {
  const std::array<double, 3> c{d.x, d.y, d.z};
  const char* positive = "LPS";
  const char* negative = "RAI";
  std::array<int, 3> order{0, 1, 2};
  std::sort(order.begin(), order.end(),
            [&](int a, int b) { return std::abs(c[static_cast<std::size_t>(a)]) > std::abs(c[static_cast<std::size_t>(b)]); });
  std::string label;
  for (std::size_t i = 0; i < 2; ++i) {
    const int a = order[i];
    const double value = c[static_cast<std::size_t>(a)];
    if (i > 0 && std::abs(value) < 0.26) break;  // more than ~15 degrees off the main axis
    label += value >= 0 ? positive[a] : negative[a];
  }
  return label;
}

const char* voiFunctionName(VoiFunction function) {
  switch (function) {
    case VoiFunction::Linear: return "LINEAR";
    case VoiFunction::LinearExact: return "LINEAR_EXACT";
    case VoiFunction::Sigmoid: return "SIGMOID";
  }
  return "LINEAR";
}

VoiFunction voiFunction(const std::string& declared, bool integerValues) {
  if (declared == "SIGMOID") return VoiFunction::Sigmoid;
  if (declared == "LINEAR_EXACT") return VoiFunction::LinearExact;
  return integerValues ? VoiFunction::Linear : VoiFunction::LinearExact;
}

uint8_t windowGrey(double x, const WindowLevel& wl, VoiFunction function) {
  if (std::isnan(x)) return 0;
  if (function == VoiFunction::Sigmoid) {
    if (!(wl.window > 0)) return x > wl.level ? 255 : 0;
    const double y = 255.0 / (1.0 + std::exp(-4.0 * (x - wl.level) / wl.window));
    return static_cast<uint8_t>(std::clamp(std::lround(y), 0L, 255L));
  }
  if (function == VoiFunction::LinearExact) {
    const double c = wl.level, w = wl.window;
    if (!(w > 0) || x <= c - w / 2) return x > c ? 255 : 0;
    if (x > c + w / 2) return 255;
    return static_cast<uint8_t>(std::clamp(std::lround(((x - c) / w + 0.5) * 255.0), 0L, 255L));
  }
  const double c = wl.level, w = std::max(1.0, wl.window);
  if (x <= c - 0.5 - (w - 1) / 2) return 0;
  if (x > c - 0.5 + (w - 1) / 2) return 255;
  const double y = ((x - (c - 0.5)) / (w - 1) + 0.5) * 255.0;
  return static_cast<uint8_t>(std::clamp(std::lround(y), 0L, 255L));
}

// ---- StoreSlicer ---------------------------------------------------------------------------

StoreSlicer::StoreSlicer(const volume::StoreReader& store, volume::BrickCache& cache,
                         int loaderThreads)
    : store_(store), cache_(cache), grid_(Grid::of(store)) {
  root_ = cache_.find(0);
  if (!root_) {
    auto brick = std::make_shared<const volume::Brick>(store_.readBrick(0));
    cache_.insert(brick);
    root_ = brick;
  }
  volume::BrickLoaderOptions options;
  options.threads = std::max(1, loaderThreads);
  options.onLoaded = [this](int64_t id) {
    const auto& n = store_.node(id);
    bytesRead_ += n.payloadBytes + n.gradientBytes;
  };
  loader_ = std::make_unique<volume::BrickLoader>(store_, cache_, options);
}

StoreSlicer::~StoreSlicer() = default;

int StoreSlicer::targetLevel(double mmPerPixel) const {
  const auto& layout = store_.layout();
  const double spacing = std::max({length(grid_.patientFromIndex.column(0)),
                                   length(grid_.patientFromIndex.column(1)),
                                   length(grid_.patientFromIndex.column(2))});
  int level = layout.leafLevel();
  while (level > 0 && spacing * static_cast<double>(layout.levelScale(level - 1)) <= mmPerPixel) {
    --level;
  }
  return level;
}

void StoreSlicer::beginFrame() {
  std::lock_guard lock(mutex_);
  frameResolved_.clear();
  frameRequests_.clear();
}

void StoreSlicer::endFrame() {
  std::vector<volume::LoadRequest> requests;
  {
    std::lock_guard lock(mutex_);
    requests.reserve(frameRequests_.size());
    for (const auto& [id, priority] : frameRequests_) requests.push_back({id, priority});
    lastRequested_ = static_cast<int64_t>(requests.size());
    frameResolved_.clear();  // drop the frame's references to bricks
  }
  loader_->setRequests(requests);
}

bool StoreSlicer::bricksArrived() {
  bool arrived = !loader_->poll().empty();
  for (const auto& e : loader_->takeErrors()) {
    std::lock_guard lock(mutex_);
    if (failed_.emplace(e.id, e.message).second) newErrors_.push_back(e.message);
    arrived = true;  // the ancestor now stands in for good: the slice is as complete as it gets
  }
  return arrived;
}

std::vector<std::string> StoreSlicer::takeErrors() {
  std::lock_guard lock(mutex_);
  return std::exchange(newErrors_, {});
}

SlicerStats StoreSlicer::stats() const {
  const auto s = loader_->stats();
  SlicerStats out;
  out.requested = lastRequested_;
  out.queued = s.queued;
  out.loading = s.loading;
  out.loaded = s.loaded;
  out.bytesRead = bytesRead_.load();
  return out;
}

// The brick of node `id` (level, brick index) if cached, else its nearest cached ancestor
// (the root at worst), requesting `id` from the loader. mutex_ is held by the caller.
StoreSlicer::Resolved StoreSlicer::resolve(int64_t id, int level, const volume::Index3& brick,
                                           bool& missing) {
  const auto& layout = store_.layout();
  if (auto it = frameResolved_.find(id); it != frameResolved_.end()) {
    missing = it->second.level != level && !failed_.contains(id);
    return it->second;
  }
  Resolved r;
  missing = false;
  if (auto b = cache_.find(id)) {
    r = {std::move(b), level, brick};
  } else {
    // A brick that failed to load is not waited for: its ancestor stands in for good.
    missing = !failed_.contains(id);
    if (missing) frameRequests_[id] = static_cast<float>(level);
    int64_t ancestor = layout.parent(id);
    while (ancestor > 0) {
      if (auto found = cache_.find(ancestor)) {
        const auto key = layout.nodeKey(ancestor);
        r = {std::move(found), key.level, key.brick};
        break;
      }
      ancestor = layout.parent(ancestor);
    }
    if (!r.brick) r = {root_, 0, {0, 0, 0}};
  }
  frameResolved_[id] = r;
  return r;
}

// Trilinear value at leaf index position `q` from brick `r` (physical units).
double StoreSlicer::sampleAt(const Resolved& r, Vec3 q) const {
  const auto& layout = store_.layout();
  const double scale = static_cast<double>(layout.levelScale(r.level));
  const int B = layout.brickSize(), A = layout.border(), edge = layout.storedEdge();
  std::array<int, 3> i0{};
  std::array<double, 3> f{};
  for (int a = 0; a < 3; ++a) {
    const double x = (q[a] + 0.5) / scale - 0.5;  // position in the level's sample grid
    const double p = x - static_cast<double>(r.brickIndex[static_cast<std::size_t>(a)] * B) + A;
    double fl = std::floor(p);
    fl = std::clamp(fl, 0.0, static_cast<double>(edge - 2));
    i0[static_cast<std::size_t>(a)] = static_cast<int>(fl);
    f[static_cast<std::size_t>(a)] = std::clamp(p - fl, 0.0, 1.0);
  }
  const auto& b = *r.brick;
  auto at = [&](int x, int y, int z) -> double {
    const std::size_t idx = (static_cast<std::size_t>(z) * edge + y) * edge + x;
    return b.format == volume::SampleFormat::UInt16 ? static_cast<double>(b.u16[idx])
                                                    : static_cast<double>(b.f32[idx]);
  };
  const int x = i0[0], y = i0[1], z = i0[2];
  const double fx = f[0], fy = f[1], fz = f[2];
  const double c00 = at(x, y, z) * (1 - fx) + at(x + 1, y, z) * fx;
  const double c10 = at(x, y + 1, z) * (1 - fx) + at(x + 1, y + 1, z) * fx;
  const double c01 = at(x, y, z + 1) * (1 - fx) + at(x + 1, y, z + 1) * fx;
  const double c11 = at(x, y + 1, z + 1) * (1 - fx) + at(x + 1, y + 1, z + 1) * fx;
  const double c0 = c00 * (1 - fy) + c10 * fy;
  const double c1 = c01 * (1 - fy) + c11 * fy;
  return store_.physical(c0 * (1 - fz) + c1 * fz);
}

Slice StoreSlicer::slice(const SliceRequest& req) {
  const auto& layout = store_.layout();
  const MprPlane& plane = req.plane;
  Slice out;
  out.width = plane.width;
  out.height = plane.height;
  out.level = std::clamp(req.level, 0, layout.leafLevel());
  out.coarsestLevelUsed = out.level;
  out.hu.assign(static_cast<std::size_t>(plane.width) * static_cast<std::size_t>(plane.height),
                static_cast<float>(kNaN));

  // Slab: samples spaced at most half the smallest voxel spacing across the thickness.
  int samples = 1;
  double step = 0;
  if (req.slab != SlabMode::None && req.slabMm > 0) {
    samples = std::max(1, static_cast<int>(std::ceil(req.slabMm / (0.5 * grid_.minSpacingMm()))));
    step = req.slabMm / samples;
  }
  out.slabSamples = samples;

  const int level = out.level;
  const double scale = static_cast<double>(layout.levelScale(level));
  const auto& bricks = layout.levelBricks(level);
  const auto& levelDims = layout.levelDims(level);
  const int B = layout.brickSize();
  const Mat4& ifp = grid_.indexFromPatient;
  std::atomic<int64_t> missingCount{0};
  std::atomic<int> coarsest{level};
  std::unordered_map<int64_t, bool> missingIds;  // under mutex_

  tbb::parallel_for(tbb::blocked_range<int>(0, plane.height), [&](const tbb::blocked_range<int>& rows) {
    int64_t lastId = -1;
    Resolved last;
    for (int y = rows.begin(); y < rows.end(); ++y) {
      for (int x = 0; x < plane.width; ++x) {
        const Vec3 centre = plane.at(x + 0.5, y + 0.5);
        double acc = req.slab == SlabMode::MinIp ? std::numeric_limits<double>::infinity()
                     : req.slab == SlabMode::Mip ? -std::numeric_limits<double>::infinity()
                                                 : 0.0;
        int inside = 0;
        for (int s = 0; s < samples; ++s) {
          const double offset = samples == 1 ? 0.0 : -0.5 * req.slabMm + (s + 0.5) * step;
          const Vec3 q = ifp.transformPoint(centre + offset * plane.normal);
          bool outside = false;
          volume::Index3 brick{};
          for (int a = 0; a < 3; ++a) {
            const double d = static_cast<double>(grid_.dims[static_cast<std::size_t>(a)]);
            if (!(q[a] >= -0.5 && q[a] <= d - 0.5)) outside = true;
            const double lx = std::clamp((q[a] + 0.5) / scale - 0.5, 0.0,
                                         static_cast<double>(levelDims[static_cast<std::size_t>(a)] - 1));
            brick[static_cast<std::size_t>(a)] =
                std::min<int64_t>(static_cast<int64_t>(lx) / B, bricks[static_cast<std::size_t>(a)] - 1);
          }
          if (outside) continue;
          const int64_t id = layout.nodeId({level, brick});
          if (id != lastId) {
            bool missing = false;
            std::lock_guard lock(mutex_);
            last = resolve(id, level, brick, missing);
            lastId = id;
            if (missing && missingIds.emplace(id, true).second) ++missingCount;
            if (last.level < coarsest.load()) coarsest = std::min(coarsest.load(), last.level);
          }
          const double v = sampleAt(last, q);
          ++inside;
          switch (req.slab) {
            case SlabMode::None: acc = v; break;
            case SlabMode::Mip: acc = std::max(acc, v); break;
            case SlabMode::MinIp: acc = std::min(acc, v); break;
            case SlabMode::Mean: acc += v; break;
          }
        }
        if (inside == 0) continue;
        if (req.slab == SlabMode::Mean) acc /= inside;
        out.hu[static_cast<std::size_t>(y) * static_cast<std::size_t>(plane.width) +
               static_cast<std::size_t>(x)] = static_cast<float>(acc);
      }
    }
  });
  out.missingBricks = missingCount.load();
  out.coarsestLevelUsed = coarsest.load();
  return out;
}

std::vector<double> StoreSlicer::sampleLeaf(const std::vector<Vec3>& positions) {
  const auto& layout = store_.layout();
  const int level = layout.leafLevel();
  const auto& bricks = layout.levelBricks(level);
  const int B = layout.brickSize();
  std::vector<double> out(positions.size(), kNaN);
  std::unordered_map<int64_t, std::shared_ptr<const volume::Brick>> held;
  for (std::size_t i = 0; i < positions.size(); ++i) {
    const Vec3 q = grid_.indexFromPatient.transformPoint(positions[i]);
    volume::Index3 brick{};
    bool outside = false;
    for (int a = 0; a < 3; ++a) {
      const double d = static_cast<double>(grid_.dims[static_cast<std::size_t>(a)]);
      if (!(q[a] >= -0.5 && q[a] <= d - 0.5)) outside = true;
      const double lx = std::clamp(q[a], 0.0, d - 1);
      brick[static_cast<std::size_t>(a)] =
          std::min<int64_t>(static_cast<int64_t>(lx) / B, bricks[static_cast<std::size_t>(a)] - 1);
    }
    if (outside) continue;
    const int64_t id = layout.nodeId({level, brick});
    auto& b = held[id];
    if (!b) {
      b = cache_.find(id);
      if (!b) {
        b = std::make_shared<const volume::Brick>(store_.readBrick(id));  // throws on damage
        cache_.insert(b);
      }
    }
    out[i] = sampleAt({b, level, brick}, q);
  }
  return out;
}

}  // namespace octoray::viewer
