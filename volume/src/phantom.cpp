// The synthetic head phantom: a fixed anatomy in normalised coordinates (every axis spans
// (-1, 1), so the head fills any grid) evaluated row by row. Each row is painted as runs: most
// shapes are nested ellipsoids or cylinders whose intersection with a row is one interval,
// found with one square root per row, so the per-voxel work is a fill, a texture inside the few
// textured tissues, and the noise hash. Patient axes are LPS: +x left, +y posterior (the face
// is at -y), +z superior.

#include "octoray/volume/phantom.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <numbers>
#include <utility>
#include <vector>

#include <fmt/format.h>

#include "octoray/core/error.h"

namespace octoray::volume {

namespace {

// ---------------------------------------------------------------------------------------------
// Tissue values (HU) and the markers of textured tissues, which lie outside the output range.

constexpr int32_t kMinHu = -1024;
constexpr int32_t kMaxHu = 3071;

constexpr int32_t kAir = -1000;
constexpr int32_t kSinusAir = -900;
constexpr int32_t kAirwayAir = -980;
constexpr int32_t kFat = -90;
constexpr int32_t kOrbitalFat = -80;
constexpr int32_t kSkin = 40;
constexpr int32_t kMuscle = 45;
constexpr int32_t kTongue = 50;
constexpr int32_t kCsf = 5;
constexpr int32_t kGreyMatter = 41;
constexpr int32_t kWhiteMatter = 29;
constexpr int32_t kDeepGrey = 38;
constexpr int32_t kFalx = 70;
constexpr int32_t kDisc = 85;
constexpr int32_t kVitreous = 12;
constexpr int32_t kLens = 95;
constexpr int32_t kArteryContrast = 320;
constexpr int32_t kVeinContrast = 220;
constexpr int32_t kCorticalOuter = 1750;
constexpr int32_t kCorticalInner = 1500;
constexpr int32_t kFacialBone = 1300;
constexpr int32_t kVertebralCortex = 1100;
constexpr int32_t kArchBone = 950;
constexpr int32_t kThinBone = 500;

constexpr int32_t kDiploeMark = 5001;
constexpr int32_t kSpongyMark = 5002;
constexpr int32_t kGreyMark = 5003;
constexpr int32_t kWhiteMark = 5004;

// ---------------------------------------------------------------------------------------------
// Shapes whose intersection with a row (fixed y, z) is one interval of x.

struct Ellipsoid {
  double cx, cy, cz;
  double rx, ry, rz;

  // Half-width in x of the row's chord through this ellipsoid with every radius reduced by
  // `inset` (a shell boundary); negative when the row misses it.
  double halfWidth(double y, double z, double inset = 0) const {
    const double ax = rx - inset, ay = ry - inset, az = rz - inset;
    if (ax <= 0 || ay <= 0 || az <= 0) return -1;
    const double dy = (y - cy) / ay, dz = (z - cz) / az;
    const double t = 1 - dy * dy - dz * dz;
    return t > 0 ? ax * std::sqrt(t) : -1;
  }
};

// An elliptic cylinder along z between zMin and zMax.
struct CylinderZ {
  double cx, cy;
  double rx, ry;
  double zMin, zMax;

  double halfWidth(double y, double z, double inset = 0) const {
    const double ax = rx - inset, ay = ry - inset;
    if (z < zMin || z > zMax || ax <= 0 || ay <= 0) return -1;
    const double dy = (y - cy) / ay;
    const double t = 1 - dy * dy;
    return t > 0 ? ax * std::sqrt(t) : -1;
  }
};

// The anatomy. Radii and centres are in normalised coordinates.
constexpr Ellipsoid kHead{0, 0, 0.02, 0.84, 0.95, 0.96};
constexpr CylinderZ kNeck{0, 0.10, 0.45, 0.50, -2, -0.30};
constexpr double kSkinInset = 0.012, kFatInset = 0.030;

constexpr Ellipsoid kCranium{0, 0.06, 0.14, 0.72, 0.82, 0.78};
constexpr double kDiploeInset = 0.014, kInnerTableInset = 0.044, kDuraInset = 0.056;
constexpr double kCortexInset = 0.068, kWhiteInset = 0.115;

constexpr Ellipsoid kDeepNuclei[] = {{-0.09, 0.12, 0.08, 0.07, 0.10, 0.07},
                                     {0.09, 0.12, 0.08, 0.07, 0.10, 0.07},  // thalami
                                     {-0.20, -0.05, 0.10, 0.07, 0.12, 0.09},
                                     {0.20, -0.05, 0.10, 0.07, 0.12, 0.09}};  // striata
constexpr Ellipsoid kVentricles[] = {
    {-0.10, 0.05, 0.26, 0.06, 0.30, 0.07},  {0.10, 0.05, 0.26, 0.06, 0.30, 0.07},   // bodies
    {-0.09, -0.22, 0.20, 0.05, 0.10, 0.08}, {0.09, -0.22, 0.20, 0.05, 0.10, 0.08},  // frontal
    {-0.22, 0.20, 0.02, 0.04, 0.14, 0.05},  {0.22, 0.20, 0.02, 0.04, 0.14, 0.05},   // temporal
    {0, 0.10, 0.08, 0.012, 0.12, 0.08},                                             // third
    {0, 0.42, -0.22, 0.05, 0.04, 0.06}};                                            // fourth

// Face: maxillary sinuses in bony walls, frontal sinus, ethmoid cells, nasal cavity, orbits.
constexpr Ellipsoid kMaxillarySinuses[] = {{-0.20, -0.55, -0.40, 0.12, 0.14, 0.14},
                                           {0.20, -0.55, -0.40, 0.12, 0.14, 0.14}};
constexpr double kSinusWall = 0.015;
constexpr Ellipsoid kFrontalSinus{0, -0.72, 0.30, 0.12, 0.022, 0.07};
constexpr Ellipsoid kEthmoidCells[] = {
    {-0.08, -0.52, -0.05, 0.03, 0.04, 0.04},   {0.08, -0.52, -0.05, 0.03, 0.04, 0.04},
    {-0.08, -0.44, -0.03, 0.03, 0.035, 0.04},  {0.08, -0.44, -0.03, 0.03, 0.035, 0.04},
    {-0.07, -0.60, -0.08, 0.025, 0.03, 0.035}, {0.07, -0.60, -0.08, 0.025, 0.03, 0.035}};
constexpr CylinderZ kNasalCavity{0, -0.62, 0.06, 0.13, -0.56, -0.12};
constexpr double kSeptumHalfWidth = 0.006;
constexpr Ellipsoid kOrbitWalls[] = {{-0.27, -0.68, 0.0, 0.16, 0.16, 0.14},
                                     {0.27, -0.68, 0.0, 0.16, 0.16, 0.14}};
constexpr double kOrbitWall = 0.02, kGlobeInset = 0.06;
constexpr Ellipsoid kLenses[] = {{-0.27, -0.765, 0.0, 0.03, 0.012, 0.03},
                                 {0.27, -0.765, 0.0, 0.03, 0.012, 0.03}};

// Below the skull: mandible (the anterior half of an elliptic ring), the cervical spine and
// the airway in front of it.
constexpr CylinderZ kMandible{0, -0.08, 0.36, 0.40, -0.72, -0.52};
constexpr double kMandibleWall = 0.05, kMandibleBackY = -0.12;
constexpr CylinderZ kVertebralArch{0, 0.36, 0.12, 0.10, -2, -0.64};
constexpr CylinderZ kSpinalCanal{0, 0.38, 0.065, 0.05, -2, -0.64};
constexpr CylinderZ kVertebralBody{0, 0.20, 0.13, 0.10, -2, -0.64};
constexpr double kVertebralCortexInset = 0.014;
constexpr double kVertebraPeriod = 0.16, kDiscFraction = 0.22;
constexpr CylinderZ kAirway{0, 0.02, 0.07, 0.05, -2, -0.45};

constexpr double kBrainFoldPeriod = 0.22;    // normalised units
constexpr double kTrabecularPeriod = 0.012;  // normalised units ...
constexpr double kMinTrabecularVoxels = 6;   // ... but never finer than this many voxels

// ---------------------------------------------------------------------------------------------
// Tubes (vessels) along curved paths. A tube runs along one axis; its centre in the other two
// axes is tabulated per voxel of that axis, so a row meets a z- or y-tube in one interval and
// an x-tube is tested per voxel, but only in rows inside the tube's bounding box.

struct TubePath {
  int axis;           // 0, 1 or 2: the axis the tube runs along
  double tMin, tMax;  // its extent along that axis
  double radius;
  int32_t hu;
  std::function<std::pair<double, double>(double t)> centre;  // the other two coordinates
};

struct Tube {
  int axis = 2;
  int64_t first = 0;                    // first voxel index along `axis`
  std::vector<float> centreA, centreB;  // per voxel: the lower and the higher other axis
  float radius = 0;
  int32_t hu = 0;
  double minA = 0, maxA = 0, minB = 0, maxB = 0;  // bounding box of the centres

  bool covers(int64_t index) const {
    return index >= first && index < first + static_cast<int64_t>(centreA.size());
  }
};

double smoothStep(double edge0, double edge1, double x) {
  const double t = std::clamp((x - edge0) / (edge1 - edge0), 0.0, 1.0);
  return t * t * (3 - 2 * t);
}

std::vector<TubePath> vesselPaths() {
  std::vector<TubePath> paths;
  for (const double side : {-1.0, 1.0}) {
    // Internal carotid arteries with a siphon-like bend.
    paths.push_back({2, -2, 0.02, 0.016, kArteryContrast, [side](double z) {
                       return std::pair{side * (0.2 + 0.03 * std::sin(5 * z)),
                                        -0.02 + 0.06 * std::sin(4 * z + 1)};
                     }});
    // Vertebral arteries converging on the basilar artery.
    paths.push_back({2, -2, -0.45, 0.011, kArteryContrast, [side](double z) {
                       const double merge = smoothStep(-0.65, -0.45, z);
                       return std::pair{side * (0.17 - 0.15 * merge), 0.24 - 0.10 * merge};
                     }});
    // Middle cerebral arteries running laterally in the Sylvian fissure.
    paths.push_back(
        {0, side < 0 ? -0.56 : 0.2, side < 0 ? -0.2 : 0.56, 0.009, kArteryContrast, [](double x) {
           const double out = std::abs(x) - 0.2;
           return std::pair{0.019 + 0.04 * (std::sin(9 * std::abs(x)) - std::sin(1.8)),
                            0.069 + 0.05 * std::sin(14 * out) + 0.25 * out};
         }});
    // Anterior cerebral arteries curving forwards and up.
    paths.push_back({1, -0.45, 0.02, 0.008, kArteryContrast, [side](double y) {
                       const double along = (0.02 - y) / 0.47;
                       return std::pair{side * 0.014, 0.07 + 0.5 * along * along};
                     }});
    // Internal jugular veins.
    paths.push_back({2, -2, -0.56, 0.035, kVeinContrast, [side](double z) {
                       return std::pair{side * 0.26, 0.14 + 0.02 * std::sin(3 * z)};
                     }});
    // Small cortical branches over the convexity.
    paths.push_back({1, -0.35, 0.40, 0.005, kArteryContrast, [side](double y) {
                       return std::pair{side * (0.48 + 0.04 * std::sin(7 * y + 1)),
                                        0.28 + 0.06 * std::sin(5 * y)};
                     }});
    paths.push_back({1, -0.40, 0.35, 0.005, kArteryContrast, [side](double y) {
                       return std::pair{side * (0.30 + 0.05 * std::sin(6 * y + 2)),
                                        0.55 + 0.04 * std::sin(8 * y)};
                     }});
  }
  // Basilar artery.
  paths.push_back({2, -0.45, -0.10, 0.012, kArteryContrast, [](double z) {
                     return std::pair{0.01 * std::sin(8 * z), 0.14 - 0.05 * (z + 0.45)};
                   }});
  // Superior sagittal sinus following the inner table of the skull.
  const double innerRy = kCranium.ry - kInnerTableInset, innerRz = kCranium.rz - kInnerTableInset;
  paths.push_back(
      {1, kCranium.cy - 0.95 * innerRy, kCranium.cy + 0.95 * innerRy, 0.016, kVeinContrast,
       [innerRy, innerRz](double y) {
         const double u = (y - kCranium.cy) / innerRy;
         return std::pair{0.0, kCranium.cz + innerRz * std::sqrt(std::max(0.0, 1 - u * u)) - 0.03};
       }});
  return paths;
}

// ---------------------------------------------------------------------------------------------
// Deterministic noise: a hash of (i, j, k, seed). The row's key mixes (j, k, seed) once with
// splitmix64; each voxel then needs only a 32-bit integer finaliser, which vectorises.

constexpr uint64_t splitMix64(uint64_t x) {
  x += 0x9e3779b97f4a7c15ull;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
  return x ^ (x >> 31);
}

uint32_t rowKey(uint64_t seed, int64_t j, int64_t k) {
  const uint64_t position = (static_cast<uint64_t>(k) << 32) ^ static_cast<uint64_t>(j);
  return static_cast<uint32_t>(splitMix64(splitMix64(seed) ^ splitMix64(position)) >> 32);
}

// Chris Wellons' "lowbias32" integer hash.
inline uint32_t hash32(uint32_t x) {
  x ^= x >> 16;
  x *= 0x7feb352du;
  x ^= x >> 15;
  x *= 0x846ca68bu;
  x ^= x >> 16;
  return x;
}

// The band-limited phantom paints each row at this many points of its voxels, one per
// stratum on every axis (a Latin hypercube: sub-row s samples stratum (a s + b) mod N of
// axis x, y, z with a coprime to N).
constexpr int kSubRows = 16;
constexpr int subRowStratum(int axis, int s) {
  constexpr int a[3] = {1, 5, 11}, b[3] = {0, 3, 7};
  return (a[axis] * s + b[axis]) % kSubRows;
}

// Noise before the point-spread function: triangular in [-64, 64] HU (standard deviation
// about 26 HU), which the 1-voxel Gaussian turns into correlated noise of about 4 HU.
inline int32_t correlatedNoiseHu(uint32_t h) {
  const int32_t a = static_cast<int32_t>(h & 0xffu), b = static_cast<int32_t>((h >> 8) & 0xffu);
  return (a - b) / 4;
}

// Triangular noise in [-11, 11] HU (standard deviation about 5 HU).
inline int32_t noiseHu(uint32_t h) {
  const int32_t a = static_cast<int32_t>(h & 0xffu), b = static_cast<int32_t>((h >> 8) & 0xffu);
  return (a - b) * 3 / 64;
}

// Branch-free select. Written with masks because GCC (with the default -ftrapping-math) will
// not vectorise a conditional that guards a float comparison or conversion.
inline int32_t pick(bool condition, int32_t ifTrue, int32_t ifFalse) {
  return ifFalse ^ ((ifTrue ^ ifFalse) & -static_cast<int32_t>(condition));
}

// ---------------------------------------------------------------------------------------------
// Per-axis tables.

// A gyroid sin(x)cos(y) + sin(y)cos(z) + sin(z)cos(x) is a smooth, connected, sponge-like
// field: |g| small traces thin walls like trabeculae, g > threshold gives folded bands. Along a
// row it is A sin(x) + B cos(x) + C with A, B, C fixed per row.
struct GyroidTables {
  std::array<std::vector<float>, 3> sine, cosine;

  struct Row {
    const float* sine;
    const float* cosine;
    float a, b, c;
  };
  Row row(int64_t j, int64_t k) const {
    return {sine[0].data(), cosine[0].data(), cosine[1][j], sine[2][k], sine[1][j] * cosine[2][k]};
  }
  // The mirror-image gyroid sin(y)cos(x) + sin(z)cos(y) + sin(x)cos(z).
  Row mirroredRow(int64_t j, int64_t k) const {
    return {sine[0].data(), cosine[0].data(), cosine[2][k], sine[1][j], sine[2][k] * cosine[1][j]};
  }
};

// Voxel centres in normalised coordinates: n samples spread symmetrically over (-1, 1).
std::vector<double> normalisedCoords(int64_t n) {
  std::vector<double> coords(static_cast<std::size_t>(n));
  for (int64_t i = 0; i < n; ++i)
    coords[i] = (2.0 * static_cast<double>(i) + 1) / static_cast<double>(n) - 1;
  return coords;
}

// ---------------------------------------------------------------------------------------------
// The generator: shared, immutable tables and the row painter.

class HeadPhantom {
 public:
  explicit HeadPhantom(const PhantomOptions& options);

  const std::array<int64_t, 3>& dims() const { return dims_; }

  // Writes rows of slices [firstSlice, firstSlice + sliceCount) to `out` as T, in parallel.
  template <typename T>
  void generate(int64_t firstSlice, int64_t sliceCount, T* out) const;

 private:
  template <typename T>
  void generateHard(int64_t firstSlice, int64_t sliceCount, T* out) const;
  template <typename T>
  void generateBlurred(int64_t firstSlice, int64_t sliceCount, T* out) const;

  struct Row {
    int32_t* hu;
    int64_t j, k;
    double y, z;
    double dx = 0;  // where in its voxel the row samples x (normalised units; 0: the centre)
  };

  // Voxel indices [begin, end) of this row whose x lies within halfWidth of centreX (pass
  // centreX - row.dx for a row sampling off-centre).
  std::pair<int64_t, int64_t> span(double centreX, double halfWidth) const;
  void fill(const Row& row, double centreX, double halfWidth, int32_t value) const;

  void paintRow(const Row& row) const;
  void paintBody(const Row& row) const;
  void paintNeckStructures(const Row& row) const;
  void paintCranium(const Row& row) const;
  void paintBrainInterior(const Row& row) const;
  void paintFace(const Row& row) const;
  void paintVessels(const Row& row) const;
  void applyTextures(const Row& row) const;
  template <typename T>
  void finishRow(const Row& row, T* out) const;

  std::array<int64_t, 3> dims_;
  uint64_t seed_;
  std::array<std::vector<double>, 3> coords_;
  GyroidTables trabecular_, folds_, fineFolds_;
  std::vector<Tube> tubes_;
  std::vector<uint8_t> discSlice_;  // per slice: 1 where the spine holds a disc
  std::vector<float> psf_;          // normalised Gaussian taps, 2 r + 1 (empty: hard edges)
};

HeadPhantom::HeadPhantom(const PhantomOptions& options) : dims_(options.dims), seed_(options.seed) {
  if (options.psfSigmaVoxels > 0) {
    const double sigma = options.psfSigmaVoxels;
    const int radius = static_cast<int>(std::ceil(3.0 * sigma));
    double sum = 0;
    std::vector<double> taps;
    for (int d = -radius; d <= radius; ++d) {
      taps.push_back(std::exp(-0.5 * d * d / (sigma * sigma)));
      sum += taps.back();
    }
    for (double t : taps) psf_.push_back(static_cast<float>(t / sum));
  }
  for (int a = 0; a < 3; ++a) {
    const int64_t n = dims_[a];
    coords_[a] = normalisedCoords(n);
    // Trabecular period: fixed in normalised units at high resolution, a few voxels at low.
    const double trabecularVoxels =
        std::max(kMinTrabecularVoxels, kTrabecularPeriod * 0.5 * static_cast<double>(n));
    const double foldOmega = 2 * std::numbers::pi / kBrainFoldPeriod;
    const double fineFoldOmega = foldOmega * std::numbers::phi;
    for (GyroidTables* tables : {&trabecular_, &folds_, &fineFolds_}) {
      tables->sine[a].resize(static_cast<std::size_t>(n));
      tables->cosine[a].resize(static_cast<std::size_t>(n));
    }
    for (int64_t i = 0; i < n; ++i) {
      const double t = 2 * std::numbers::pi * static_cast<double>(i) / trabecularVoxels + 0.7 * a;
      trabecular_.sine[a][i] = static_cast<float>(std::sin(t));
      trabecular_.cosine[a][i] = static_cast<float>(std::cos(t));
      const double f = foldOmega * coords_[a][i] + 1.3 * a;
      folds_.sine[a][i] = static_cast<float>(std::sin(f));
      folds_.cosine[a][i] = static_cast<float>(std::cos(f));
      const double ff = fineFoldOmega * coords_[a][i] + 0.4 - 0.9 * a;
      fineFolds_.sine[a][i] = static_cast<float>(std::sin(ff));
      fineFolds_.cosine[a][i] = static_cast<float>(std::cos(ff));
    }
  }
  discSlice_.resize(static_cast<std::size_t>(dims_[2]));
  for (int64_t k = 0; k < dims_[2]; ++k) {
    const double phase = coords_[2][k] / kVertebraPeriod;
    discSlice_[k] = phase - std::floor(phase) < kDiscFraction ? 1 : 0;
  }
  for (const TubePath& path : vesselPaths()) {
    Tube tube;
    tube.axis = path.axis;
    tube.radius = static_cast<float>(path.radius);
    tube.hu = path.hu;
    tube.minA = tube.minB = 1e30;
    tube.maxA = tube.maxB = -1e30;
    const std::vector<double>& along = coords_[path.axis];
    for (int64_t n = 0; n < dims_[path.axis]; ++n) {
      if (along[n] < path.tMin || along[n] > path.tMax) continue;
      if (tube.centreA.empty()) tube.first = n;
      const auto [a, b] = path.centre(along[n]);
      tube.centreA.push_back(static_cast<float>(a));
      tube.centreB.push_back(static_cast<float>(b));
      tube.minA = std::min(tube.minA, a);
      tube.maxA = std::max(tube.maxA, a);
      tube.minB = std::min(tube.minB, b);
      tube.maxB = std::max(tube.maxB, b);
    }
    if (!tube.centreA.empty()) tubes_.push_back(std::move(tube));
  }
}

std::pair<int64_t, int64_t> HeadPhantom::span(double centreX, double halfWidth) const {
  if (halfWidth < 0) return {0, 0};
  // x_i = (2i + 1) / n - 1, so |x_i - c| <= h  <=>  (c - h + 1) n / 2 - 1/2 <= i <= (c + h + 1) n /
  // 2 - 1/2.
  const double scale = 0.5 * static_cast<double>(dims_[0]);
  const double lo = std::ceil((centreX - halfWidth + 1) * scale - 0.5);
  const double hi = std::floor((centreX + halfWidth + 1) * scale - 0.5) + 1;
  const auto clampIndex = [this](double v) {
    return static_cast<int64_t>(std::clamp(v, 0.0, static_cast<double>(dims_[0])));
  };
  const int64_t begin = clampIndex(lo), end = clampIndex(hi);
  return {begin, std::max(begin, end)};
}

void HeadPhantom::fill(const Row& row, double centreX, double halfWidth, int32_t value) const {
  const auto [begin, end] = span(centreX - row.dx, halfWidth);
  std::fill(row.hu + begin, row.hu + end, value);
}

void HeadPhantom::paintRow(const Row& row) const {
  std::fill(row.hu, row.hu + dims_[0], kAir);
  // Rows that miss the head and neck entirely are air (and the noise added later).
  if (std::max(kHead.halfWidth(row.y, row.z), kNeck.halfWidth(row.y, row.z)) < 0) return;
  paintBody(row);
  paintNeckStructures(row);
  paintCranium(row);
  applyTextures(row);
  paintBrainInterior(row);
  paintFace(row);
  paintVessels(row);
}

// Skin, subcutaneous fat and muscle: nested shells of the union of head and neck (both centred
// on x = 0, so their union in a row is the wider chord).
void HeadPhantom::paintBody(const Row& row) const {
  const auto bodyHalfWidth = [&row](double inset) {
    return std::max(kHead.halfWidth(row.y, row.z, inset), kNeck.halfWidth(row.y, row.z, inset));
  };
  fill(row, 0, bodyHalfWidth(0), kSkin);
  fill(row, 0, bodyHalfWidth(kSkinInset), kFat);
  fill(row, 0, bodyHalfWidth(kFatInset), kMuscle);
}

void HeadPhantom::paintNeckStructures(const Row& row) const {
  const double y = row.y, z = row.z;
  // Mandible: the anterior part of an elliptic ring, with the tongue inside it.
  if (y < kMandibleBackY) {
    fill(row, kMandible.cx, kMandible.halfWidth(y, z), kFacialBone);
    fill(row, kMandible.cx, kMandible.halfWidth(y, z, kMandibleWall), kTongue);
  }
  // Cervical spine: posterior arch around the canal, vertebral bodies separated by discs.
  fill(row, kVertebralArch.cx, kVertebralArch.halfWidth(y, z), kArchBone);
  fill(row, kSpinalCanal.cx, kSpinalCanal.halfWidth(y, z), kCsf);
  const bool disc = discSlice_[row.k] != 0;
  fill(row, kVertebralBody.cx, kVertebralBody.halfWidth(y, z), disc ? kDisc : kVertebralCortex);
  if (!disc) {
    fill(row, kVertebralBody.cx, kVertebralBody.halfWidth(y, z, kVertebralCortexInset),
         kSpongyMark);
  }
  fill(row, kAirway.cx, kAirway.halfWidth(y, z), kAirwayAir);
}

// Skull tables and diploë, the dura/CSF space, cortex and white matter: nested shells.
void HeadPhantom::paintCranium(const Row& row) const {
  const double y = row.y, z = row.z;
  if (kCranium.halfWidth(y, z) < 0) return;
  fill(row, kCranium.cx, kCranium.halfWidth(y, z), kCorticalOuter);
  fill(row, kCranium.cx, kCranium.halfWidth(y, z, kDiploeInset), kDiploeMark);
  fill(row, kCranium.cx, kCranium.halfWidth(y, z, kInnerTableInset), kCorticalInner);
  fill(row, kCranium.cx, kCranium.halfWidth(y, z, kDuraInset), kCsf);
  fill(row, kCranium.cx, kCranium.halfWidth(y, z, kCortexInset), kGreyMark);
  fill(row, kCranium.cx, kCranium.halfWidth(y, z, kWhiteInset), kWhiteMark);
}

// Textured tissues: trabecular diploë and vertebral bone, folded grey/white matter with CSF in
// the deepest folds. Each loop runs only over the interval its tissue can occupy in this row.
void HeadPhantom::applyTextures(const Row& row) const {
  int32_t* hu = row.hu;
  const auto trabecular = trabecular_.row(row.j, row.k);
  const auto spongy = [&](int64_t begin, int64_t end, int32_t mark, float base, float depth) {
    for (int64_t i = begin; i < end; ++i) {
      const float g =
          trabecular.a * trabecular.sine[i] + trabecular.b * trabecular.cosine[i] + trabecular.c;
      const int32_t value = static_cast<int32_t>(base - depth * std::abs(g));
      hu[i] = pick(hu[i] == mark, value, hu[i]);
    }
  };
  const auto [skullBegin, skullEnd] = span(kCranium.cx - row.dx, kCranium.halfWidth(row.y, row.z));
  spongy(skullBegin, skullEnd, kDiploeMark, 950.0f, 550.0f);
  const auto [spineBegin, spineEnd] =
      span(kVertebralBody.cx - row.dx, kVertebralBody.halfWidth(row.y, row.z));
  spongy(spineBegin, spineEnd, kSpongyMark, 520.0f, 380.0f);

  const auto [brainBegin, brainEnd] =
      span(kCranium.cx - row.dx, kCranium.halfWidth(row.y, row.z, kCortexInset));
  // Folds: a gyroid plus a mirrored one at a golden-ratio frequency, so the pattern never
  // repeats visibly. Grey matter reaches into the white core where the field is high, CSF
  // fills the deepest sulci.
  const auto folds = folds_.row(row.j, row.k);
  const auto fine = fineFolds_.mirroredRow(row.j, row.k);
  for (int64_t i = brainBegin; i < brainEnd; ++i) {
    const float g = folds.a * folds.sine[i] + folds.b * folds.cosine[i] + folds.c +
                    0.7f * (fine.a * fine.sine[i] + fine.b * fine.cosine[i] + fine.c);
    const int32_t v = hu[i];
    int32_t tissue = pick((v == kWhiteMark) & (g < 0.6f), kWhiteMatter, kGreyMatter);
    tissue = pick(g > 1.8f, kCsf, tissue);
    hu[i] = pick((v == kWhiteMark) | (v == kGreyMark), tissue, v);
  }
}

void HeadPhantom::paintBrainInterior(const Row& row) const {
  const double y = row.y, z = row.z;
  // Falx cerebri: a thin midline sheet between the hemispheres, above the ventricles.
  if (z > 0.3 && kCranium.halfWidth(y, z, kCortexInset) > 0) fill(row, 0, 0.004, kFalx);
  for (const Ellipsoid& e : kDeepNuclei) fill(row, e.cx, e.halfWidth(y, z), kDeepGrey);
  for (const Ellipsoid& e : kVentricles) fill(row, e.cx, e.halfWidth(y, z), kCsf);
}

void HeadPhantom::paintFace(const Row& row) const {
  const double y = row.y, z = row.z;
  for (const Ellipsoid& e : kMaxillarySinuses) {
    fill(row, e.cx, e.halfWidth(y, z), kThinBone);
    fill(row, e.cx, e.halfWidth(y, z, kSinusWall), kSinusAir);
  }
  fill(row, kFrontalSinus.cx, kFrontalSinus.halfWidth(y, z), kSinusAir);
  for (const Ellipsoid& e : kEthmoidCells) {
    fill(row, e.cx, e.halfWidth(y, z), kThinBone);
    fill(row, e.cx, e.halfWidth(y, z, 0.008), kSinusAir);
  }
  if (kNasalCavity.halfWidth(y, z) >= 0) {
    fill(row, kNasalCavity.cx, kNasalCavity.halfWidth(y, z), kSinusAir);
    fill(row, 0, kSeptumHalfWidth, kThinBone);
  }
  for (std::size_t side = 0; side < 2; ++side) {
    const Ellipsoid& e = kOrbitWalls[side];
    if (e.halfWidth(y, z) < 0) continue;
    fill(row, e.cx, e.halfWidth(y, z), kFacialBone);
    fill(row, e.cx, e.halfWidth(y, z, kOrbitWall), kOrbitalFat);
    fill(row, e.cx, e.halfWidth(y, z, kGlobeInset), kVitreous);
    fill(row, kLenses[side].cx, kLenses[side].halfWidth(y, z), kLens);
  }
}

void HeadPhantom::paintVessels(const Row& row) const {
  for (const Tube& tube : tubes_) {
    const double r = tube.radius;
    if (tube.axis == 2 || tube.axis == 1) {
      // Centre (x, other) tabulated per slice (z-tube) or per row (y-tube).
      const int64_t index = tube.axis == 2 ? row.k : row.j;
      if (!tube.covers(index)) continue;
      const double other = tube.axis == 2 ? row.y : row.z;
      const double d = other - tube.centreB[index - tube.first];
      if (std::abs(d) >= r) continue;
      fill(row, tube.centreA[index - tube.first], std::sqrt(r * r - d * d), tube.hu);
      continue;
    }
    // An x-tube: centre (y, z) tabulated per voxel of the row; test only inside its box.
    if (row.y < tube.minA - r || row.y > tube.maxA + r || row.z < tube.minB - r ||
        row.z > tube.maxB + r) {
      continue;
    }
    const int64_t begin = tube.first;
    const int64_t end = tube.first + static_cast<int64_t>(tube.centreA.size());
    const float y = static_cast<float>(row.y), z = static_cast<float>(row.z);
    const float r2 = tube.radius * tube.radius;
    const float* cy = tube.centreA.data() - begin;
    const float* cz = tube.centreB.data() - begin;
    int32_t* hu = row.hu;
    for (int64_t i = begin; i < end; ++i) {
      const float dy = y - cy[i], dz = z - cz[i];
      hu[i] = pick(dy * dy + dz * dz <= r2, tube.hu, hu[i]);
    }
  }
}

template <typename T>
void HeadPhantom::finishRow(const Row& row, T* out) const {
  const uint32_t key = rowKey(seed_, row.j, row.k);
  const int64_t n = dims_[0];
  for (int64_t i = 0; i < n; ++i) {
    const uint32_t h = hash32(key ^ (static_cast<uint32_t>(i) * 0x9e3779b9u));
    const int32_t value = std::clamp(row.hu[i] + noiseHu(h), kMinHu, kMaxHu);
    out[i] = static_cast<T>(value);
  }
}

template <typename T>
void HeadPhantom::generate(int64_t firstSlice, int64_t sliceCount, T* out) const {
  if (psf_.empty()) {
    generateHard(firstSlice, sliceCount, out);
  } else {
    generateBlurred(firstSlice, sliceCount, out);
  }
}

template <typename T>
void HeadPhantom::generateHard(int64_t firstSlice, int64_t sliceCount, T* out) const {
  const int64_t rowLength = dims_[0], rowsPerSlice = dims_[1];
  const int64_t rows = sliceCount * rowsPerSlice;
  // Chunks of at least ~32 K voxels keep scheduling overhead negligible for narrow volumes.
  const int64_t grain = std::max<int64_t>(1, (int64_t{1} << 15) / rowLength);
  tbb::parallel_for(tbb::blocked_range<int64_t>(0, rows, grain),
                    [&](const tbb::blocked_range<int64_t>& range) {
                      std::vector<int32_t> scratch(static_cast<std::size_t>(rowLength));
                      for (int64_t r = range.begin(); r < range.end(); ++r) {
                        const int64_t j = r % rowsPerSlice, k = firstSlice + r / rowsPerSlice;
                        const Row row{scratch.data(), j, k, coords_[1][j], coords_[2][k]};
                        paintRow(row);
                        finishRow(row, out + r * rowLength);
                      }
                    });
}

// The band-limited phantom: the painted anatomy (with partial volume) plus correlated noise,
// convolved with the separable Gaussian psf_ (edges replicated, so every voxel is a function
// of its index and the seed alone), rounded, then the white noise. Output slices go in chunks:
// each chunk paints the slices its taps reach (int16) once, then blurs one output slice at a
// time along z, y and x in float.
template <typename T>
void HeadPhantom::generateBlurred(int64_t firstSlice, int64_t sliceCount, T* out) const {
  const int64_t nx = dims_[0], ny = dims_[1], nz = dims_[2];
  const int64_t sliceSamples = nx * ny;
  const int radius = static_cast<int>(psf_.size() / 2);
  // Chunks of output slices whose painted slices stay near 128 MB.
  const int64_t chunk = std::clamp<int64_t>((int64_t{1} << 26) / std::max<int64_t>(1, sliceSamples) - 2 * radius,
                                            1, 32);
  std::vector<int16_t> painted;
  for (int64_t c0 = firstSlice; c0 < firstSlice + sliceCount; c0 += chunk) {
    const int64_t c1 = std::min(c0 + chunk, firstSlice + sliceCount);
    const int64_t p0 = std::max<int64_t>(0, c0 - radius), p1 = std::min(nz, c1 + radius);
    painted.resize(static_cast<std::size_t>((p1 - p0) * sliceSamples));
    const int64_t rows = (p1 - p0) * ny;
    const int64_t grain = std::max<int64_t>(1, (int64_t{1} << 15) / nx);
    tbb::parallel_for(tbb::blocked_range<int64_t>(0, rows, grain), [&](const tbb::blocked_range<int64_t>& range) {
      std::vector<int32_t> scratch(static_cast<std::size_t>(nx)), sum(static_cast<std::size_t>(nx));
      for (int64_t r = range.begin(); r < range.end(); ++r) {
        const int64_t j = r % ny, k = p0 + r / ny;
        // Partial volume: the row painted at kSubRows points of its voxels' extent (a Latin
        // hypercube in x, y and z, shifted per row by a hash), averaged. Point sampling at the
        // voxel centres alone quantises every surface to whole voxels along the axis its
        // normal is closest to, and those terraces survive any blur. (The shift does not
        // depend on the seed: seeds change the noise only.)
        const uint32_t key = rowKey(seed_ ^ 0x5bd1e995u, j, k);
        const double shift = (hash32(rowKey(0x68e31da4u, j, k)) >> 8) * (1.0 / 16777216.0);
        std::fill(sum.begin(), sum.end(), 0);
        for (int s = 0; s < kSubRows; ++s) {
          const auto offset = [&](int stratum, int64_t n) {
            return ((stratum + shift) / kSubRows - 0.5) * 2.0 / static_cast<double>(n);
          };
          Row row{scratch.data(), j, k, coords_[1][j] + offset(subRowStratum(1, s), ny),
                  coords_[2][k] + offset(subRowStratum(2, s), nz)};
          row.dx = offset(subRowStratum(0, s), nx);
          paintRow(row);
          for (int64_t i = 0; i < nx; ++i) sum[static_cast<std::size_t>(i)] += scratch[static_cast<std::size_t>(i)];
        }
        int16_t* dst = painted.data() + r * nx;
        for (int64_t i = 0; i < nx; ++i) {
          const uint32_t h = hash32(key ^ (static_cast<uint32_t>(i) * 0x9e3779b9u));
          const int32_t total = sum[static_cast<std::size_t>(i)];
          const int32_t mean = (total + (total >= 0 ? kSubRows / 2 : -kSubRows / 2)) / kSubRows;
          dst[i] = static_cast<int16_t>(std::clamp(mean + correlatedNoiseHu(h), -2048, 4095));
        }
      }
    });
    tbb::parallel_for(c0, c1, [&](int64_t k) {
      std::vector<float> a(static_cast<std::size_t>(sliceSamples)), b(static_cast<std::size_t>(sliceSamples));
      // z: the taps' slices, edges replicated.
      for (int d = -radius; d <= radius; ++d) {
        const int64_t kk = std::clamp<int64_t>(k + d, 0, nz - 1);
        const int16_t* src = painted.data() + (kk - p0) * sliceSamples;
        const float w = psf_[static_cast<std::size_t>(d + radius)];
        for (int64_t n = 0; n < sliceSamples; ++n) a[static_cast<std::size_t>(n)] += w * static_cast<float>(src[n]);
      }
      // y, then x.
      for (int64_t j = 0; j < ny; ++j) {
        float* dst = b.data() + j * nx;
        std::fill(dst, dst + nx, 0.0f);
        for (int d = -radius; d <= radius; ++d) {
          const int64_t jj = std::clamp<int64_t>(j + d, 0, ny - 1);
          const float* src = a.data() + jj * nx;
          const float w = psf_[static_cast<std::size_t>(d + radius)];
          for (int64_t i = 0; i < nx; ++i) dst[i] += w * src[i];
        }
      }
      std::vector<int32_t> hu(static_cast<std::size_t>(nx));
      std::vector<float> padded(static_cast<std::size_t>(nx + 2 * radius)), sum(static_cast<std::size_t>(nx));
      for (int64_t j = 0; j < ny; ++j) {
        const float* src = b.data() + j * nx;
        for (int64_t i = -radius; i < nx + radius; ++i) {
          padded[static_cast<std::size_t>(i + radius)] = src[std::clamp<int64_t>(i, 0, nx - 1)];
        }
        std::fill(sum.begin(), sum.end(), 0.0f);
        for (int d = 0; d <= 2 * radius; ++d) {
          const float w = psf_[static_cast<std::size_t>(d)];
          const float* p = padded.data() + d;
          for (int64_t i = 0; i < nx; ++i) sum[static_cast<std::size_t>(i)] += w * p[i];
        }
        for (int64_t i = 0; i < nx; ++i) {
          hu[static_cast<std::size_t>(i)] = static_cast<int32_t>(std::lround(sum[static_cast<std::size_t>(i)]));
        }
        const Row row{hu.data(), j, k, coords_[1][j], coords_[2][k]};
        finishRow(row, out + ((k - firstSlice) * ny + j) * nx);
      }
    });
  }
}

// ---------------------------------------------------------------------------------------------
// VolumeSource

void checkOptions(const PhantomOptions& options) {
  for (int a = 0; a < 3; ++a) {
    if (options.dims[a] < 1 || options.dims[a] > (int64_t{1} << 20)) {
      throw Error("phantom", fmt::format("size {}x{}x{}: each dimension must be in [1, 1048576]",
                                         options.dims[0], options.dims[1], options.dims[2]));
    }
    const double s = options.spacingMm[a];
    if (!std::isfinite(s) || s <= 0) {
      throw Error("phantom",
                  fmt::format("spacing {},{},{} mm: each must be positive", options.spacingMm.x,
                              options.spacingMm.y, options.spacingMm.z));
    }
  }
  if (!(options.psfSigmaVoxels >= 0 && options.psfSigmaVoxels <= 4)) {
    throw Error("phantom", fmt::format("point-spread function sigma {} voxels: must be in [0, 4]",
                                       options.psfSigmaVoxels));
  }
  const double samples = static_cast<double>(options.dims[0]) *
                         static_cast<double>(options.dims[1]) *
                         static_cast<double>(options.dims[2]);
  if (samples > 0x1p62) throw Error("phantom", "too many samples");
}

VolumeInfo phantomInfo(const PhantomOptions& options) {
  VolumeInfo info;
  info.dims = options.dims;
  const Vec3 s = options.spacingMm;
  // Centre the volume on the patient origin.
  const Vec3 origin{-0.5 * static_cast<double>(options.dims[0] - 1) * s.x,
                    -0.5 * static_cast<double>(options.dims[1] - 1) * s.y,
                    -0.5 * static_cast<double>(options.dims[2] - 1) * s.z};
  info.patientFromIndex = Mat4::fromColumns({s.x, 0, 0}, {0, s.y, 0}, {0, 0, s.z}, origin);
  info.format = "phantom";
  info.sourcePath = "phantom";
  info.modality = "CT";
  info.description = options.psfSigmaVoxels > 0
                         ? fmt::format("octoray phantom seed {}", options.seed)
                         : fmt::format("octoray phantom seed {} (hard edges)", options.seed);
  info.unit = "HU";
  info.integerValues = true;
  info.valueLowerBound = -1024;
  info.valueUpperBound = 3071;
  return info;
}

class PhantomSource final : public VolumeSource {
 public:
  explicit PhantomSource(const PhantomOptions& options)
      : phantom_(options), info_(phantomInfo(options)) {}

  const VolumeInfo& info() const override { return info_; }

  void readSlab(int64_t firstSlice, int64_t sliceCount, std::span<float> out) override {
    checkSlabRequest(info_, firstSlice, sliceCount, out.size());
    phantom_.generate(firstSlice, sliceCount, out.data());
  }

 private:
  HeadPhantom phantom_;
  VolumeInfo info_;
};

}  // namespace

std::unique_ptr<VolumeSource> makePhantom(const PhantomOptions& options) {
  checkOptions(options);
  return std::make_unique<PhantomSource>(options);
}

}  // namespace octoray::volume
