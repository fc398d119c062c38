#include "octoray/gpu/reference/reference_renderer.h"

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <limits>

#include "octoray/core/error.h"
#include "octoray/gpu/image_metrics.h"
#include "octoray/transfer/preintegration.h"

namespace octoray::gpu::reference {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
// Isosurface refinement stops when the bracket is shorter than this, in index units.
constexpr double kIsoToleranceVoxels = 1e-6;

// Piecewise-linear interpolation over sorted control points, in double precision: clamped at
// the ends; where points share a value the later one applies from that value on.
template <typename Points, typename Key, typename Value>
double interpolatePoints(const Points& points, double x, Key key, Value value) {
  const auto next = std::upper_bound(points.begin(), points.end(), x,
                                     [&](double v, const auto& p) { return v < key(p); });
  if (next == points.begin()) return value(points.front());
  if (next == points.end()) return value(points.back());
  const auto& p0 = *(next - 1);
  const auto& p1 = *next;
  const double w = (x - key(p0)) / (key(p1) - key(p0));
  return value(p0) + w * (value(p1) - value(p0));
}

// Everything a ray needs, computed once per frame.
struct Frame {
  const ReferenceVolume* volume = nullptr;
  const transfer::TransferFunction* tf = nullptr;
  RenderOptions options;
  Mat4 indexFromPatient;
  double stepMm = 0;
  bool shade = false;
  bool useGradientOpacity = false;
  bool needGradient = false;
  std::pair<double, double> support;  // the TF's opacity support (pre-integration)
};

struct RayResult {
  double r = 0, g = 0, b = 0, a = 0;
  double depth = kInf;
  double value = kNaN;
  int64_t samples = 0;
  bool hit = false;
};

Vec3 indexPoint(const Vec3& origin, const Vec3& direction, double t) {
  return origin + t * direction;
}

double sampleAt(const ReferenceVolume& v, const Vec3& p) { return v.sample(p.x, p.y, p.z); }

// Gradient of the trilinear interpolant in patient space (value units per mm): central
// differences in index space (ReferenceVolume::gradientIndex: +-1 voxel, or for an LOD cut
// +-h voxels of the leaf's level), then the inverse transpose of the linear part.
Vec3 gradientPatient(const Frame& f, const Vec3& p) {
  const Vec3 g = f.volume->gradientIndex(p);
  const double gi = g.x, gj = g.y, gk = g.z;
  const auto& m = f.indexFromPatient.m;  // linear part = inverse of patientFromIndex's
  return {m[0][0] * gi + m[1][0] * gj + m[2][0] * gk, m[0][1] * gi + m[1][1] * gj + m[2][1] * gk,
          m[0][2] * gi + m[1][2] * gj + m[2][2] * gk};
}

// Phong with a headlight: light and viewer both along -rayDirection, two-sided.
Classification shadePhong(const transfer::Material& material, const Classification& c,
                          const Vec3& gradient, const Vec3& rayDirection) {
  const double magnitude = length(gradient);
  double diffuse = 0, specular = 0;
  if (magnitude > 0 && std::isfinite(magnitude)) {
    const Vec3 n = (1.0 / magnitude) * gradient;
    const double nl = std::abs(dot(n, rayDirection));  // l = v = -rayDirection
    diffuse = nl;
    // Reflection of l about n, against v: 2 (n.l)^2 - 1 when l = v.
    const double rv = 2.0 * nl * nl - 1.0;
    specular = rv > 0 ? std::pow(rv, static_cast<double>(material.specularPower)) : 0.0;
  }
  const double lit = material.ambient + material.diffuse * diffuse;
  const double spec = material.specular * specular;
  return {c.r * lit + spec, c.g * lit + spec, c.b * lit + spec, c.alpha};
}

// The chord cut into n equal steps of delta <= the frame's step (every mode's rule).
struct ChordSteps {
  int64_t n = 0;
  double delta = 0;
};
ChordSteps cutChord(const Frame& f, const Chord& chord) {
  const double chordMm = chord.tFar - chord.tNear;
  const double steps = std::max(1.0, std::ceil(chordMm / f.stepMm));
  return {static_cast<int64_t>(steps), chordMm / steps};
}

// What gradient opacity and boundary enhancement multiply a sample's opacity by.
double opacityFactor(const Frame& f, double gradientMagnitude) {
  double factor = 1.0;
  if (f.useGradientOpacity) factor *= gradientOpacity(*f.tf, gradientMagnitude);
  if (f.options.boundary.enabled) {
    const BoundaryEnhancement& be = f.options.boundary;
    factor *= be.kC + be.kS * std::pow(gradientMagnitude, be.kE);
  }
  return factor;
}

// The lighting of shadePhong as (ka + kd |n.l|, ks spec): colour * first + second.
std::pair<double, double> phongFactors(const transfer::Material& material, const Vec3& gradient,
                                       const Vec3& rayDirection) {
  const Classification lit = shadePhong(material, {1.0, 0.0, 0.0, 1.0}, gradient, rayDirection);
  return {lit.r - lit.g, lit.g};  // r = lit + spec, g = spec
}

// Counts the TF's control points strictly between lo and hi.
std::size_t pointsBetween(const transfer::TransferFunction& tf, double lo, double hi) {
  std::size_t n = 0;
  for (const auto& p : tf.opacity) n += p.value > lo && p.value < hi ? 1 : 0;
  for (const auto& p : tf.color) n += p.value > lo && p.value < hi ? 1 : 0;
  return n;
}

// One pre-integrated segment: premultiplied colour and opacity of a path of lengthMm along
// which the value runs linearly from vf to vb; only its part inside the opacity support has
// material. Sub-steps at their midpoints with exact per-sub-step opacity correction
// (transfer::integrateSegment's rule, in double with the reference's classify).
Classification integrateSegment(const Frame& f, double vf, double vb, double lengthMm) {
  const auto [lo, hi] = f.support;
  if (!(std::max(vf, vb) >= lo && std::min(vf, vb) <= hi)) return {};
  const double fc = std::clamp(vf, lo, hi), bc = std::clamp(vb, lo, hi);
  const double length = vf == vb ? lengthMm : lengthMm * std::abs(bc - fc) / std::abs(vb - vf);
  if (!(length > 0)) return {};
  const std::size_t inside = pointsBetween(*f.tf, std::min(fc, bc), std::max(fc, bc));
  const int subSteps = fc == bc ? 1 : static_cast<int>(std::min<std::size_t>(16 + 16 * inside, 1024));
  const double ratio = length / subSteps / f.tf->unitDistanceMm;
  Classification out;
  double transmittance = 1.0;
  for (int k = 0; k < subSteps; ++k) {
    const double v = fc + (k + 0.5) / subSteps * (bc - fc);
    const Classification c = classify(*f.tf, v);
    const double alpha = correctOpacity(c.alpha, ratio);
    if (!(alpha > 0)) continue;
    const double weight = transmittance * alpha;
    out.r += weight * c.r;
    out.g += weight * c.g;
    out.b += weight * c.b;
    transmittance *= 1.0 - alpha;
  }
  out.alpha = 1.0 - transmittance;
  return out;
}

RayResult marchDvrPreintegrated(const Frame& f, const Vec3& o, const Vec3& d,
                                const Vec3& directionPatient, const Chord& chord) {
  RayResult out;
  const transfer::TransferFunction& tf = *f.tf;
  const auto [n, delta] = cutChord(f, chord);
  const double ratio = delta / tf.unitDistanceMm;
  const double stopAt = f.options.earlyTermination;
  double transmittance = 1.0;
  double front = sampleAt(*f.volume, indexPoint(o, d, chord.tNear));
  ++out.samples;
  for (int64_t s = 0; s < n; ++s) {
    const double tb = s + 1 == n ? chord.tFar : chord.tNear + static_cast<double>(s + 1) * delta;
    const double back = sampleAt(*f.volume, indexPoint(o, d, tb));
    ++out.samples;
    Classification c = integrateSegment(f, front, back, delta);
    front = back;
    if (!(c.alpha > 0)) continue;
    const double t = chord.tNear + (static_cast<double>(s) + 0.5) * delta;
    if (f.needGradient) {
      const Vec3 g = gradientPatient(f, indexPoint(o, d, t));
      out.samples += 6;
      const double factor = opacityFactor(f, length(g));
      if (factor != 1.0) {
        // The segment's opacity per unit distance scaled, then carried back to its length.
        const double unitAlpha = c.alpha >= 1.0 ? 1.0 : correctOpacity(c.alpha, 1.0 / ratio);
        const double scaled = correctOpacity(std::clamp(unitAlpha * factor, 0.0, 1.0), ratio);
        const double k = scaled / c.alpha;
        c = {c.r * k, c.g * k, c.b * k, scaled};
        if (!(c.alpha > 0)) continue;
      }
      if (f.shade) {
        const auto [lit, spec] = phongFactors(tf.material, g, directionPatient);
        c = {c.r * lit + spec * c.alpha, c.g * lit + spec * c.alpha, c.b * lit + spec * c.alpha,
             c.alpha};
      }
    }
    if (out.depth == kInf) out.depth = t;
    out.r += transmittance * c.r;
    out.g += transmittance * c.g;
    out.b += transmittance * c.b;
    transmittance *= 1.0 - c.alpha;
    if (transmittance == 0.0 || (stopAt < 1.0 && 1.0 - transmittance >= stopAt)) break;
  }
  out.a = 1.0 - transmittance;
  return out;
}

RayResult marchDvr(const Frame& f, const Vec3& o, const Vec3& d, const Vec3& directionPatient,
                   const Chord& chord, double jitter) {
  RayResult out;
  const transfer::TransferFunction& tf = *f.tf;
  const auto [n, delta] = cutChord(f, chord);
  const double ratio = delta / tf.unitDistanceMm;
  const double stopAt = f.options.earlyTermination;
  double transmittance = 1.0;
  for (int64_t s = 0; s < n; ++s) {
    const double t = chord.tNear + (static_cast<double>(s) + jitter) * delta;
    const Vec3 p = indexPoint(o, d, t);
    const double value = sampleAt(*f.volume, p);
    ++out.samples;
    Classification c = classify(tf, value);
    if (!(c.alpha > 0)) continue;
    if (f.needGradient) {
      const Vec3 g = gradientPatient(f, p);
      out.samples += 6;
      c.alpha = std::clamp(c.alpha * opacityFactor(f, length(g)), 0.0, 1.0);
      if (f.shade) c = shadePhong(tf.material, c, g, directionPatient);
    }
    const double alpha = correctOpacity(c.alpha, ratio);
    if (!(alpha > 0)) continue;
    if (out.depth == kInf) out.depth = t;
    const double weight = transmittance * alpha;
    out.r += weight * c.r;
    out.g += weight * c.g;
    out.b += weight * c.b;
    transmittance *= 1.0 - alpha;
    if (transmittance == 0.0 || (stopAt < 1.0 && 1.0 - transmittance >= stopAt)) break;
  }
  out.a = 1.0 - transmittance;
  return out;
}

// A surface thinner than the step: three consecutive samples x[0] < x[1] < x[2] whose excesses
// times s are g, all positive, the middle one the smallest, may straddle a dip of the
// interpolant through zero that no sample sees (a ray grazing thin bone). With L the steepest
// slope seen between the points, the Piyavskii-Shubert bound min over [a, b] >=
// (g(a) + g(b) - L' (b - a)) / 2 with L' = kIsoDipSlopeSafety x L (slopes may be steeper than
// any seen) decides whether a dip is possible; the probe goes where the bound with L itself has
// its argmin (exact for a symmetric tent, the shape of the trilinear interpolant along an
// axis), or with L' where that bound stays above zero. A probe replaces one of the three; at
// most kIsoDipProbes. Returns the first probe with g <= 0 (its excess in fHit), or NaN. The
// GPU's isoDip (raycast_iso.glsl) follows the same rule.
constexpr int kIsoDipProbes = 4;
constexpr double kIsoDipSlopeSafety = 2.0;

// The lower of the two halves' bounds with `slope`, and where it is reached.
std::pair<double, double> isoDipArgmin(const std::array<double, 3>& x,
                                       const std::array<double, 3>& g, double slope) {
  const double boundA = 0.5 * (g[0] + g[1] - slope * (x[1] - x[0]));
  const double boundB = 0.5 * (g[1] + g[2] - slope * (x[2] - x[1]));
  return boundA <= boundB
             ? std::pair{0.5 * (x[0] + x[1]) + (g[0] - g[1]) / (2.0 * slope), boundA}
             : std::pair{0.5 * (x[1] + x[2]) + (g[1] - g[2]) / (2.0 * slope), boundB};
}

template <typename Excess>
double isoDip(const Excess& excess, double s, std::array<double, 3> x, std::array<double, 3> g,
              double& fHit) {
  double slope = 0.0;
  for (int probe = 0; probe < kIsoDipProbes; ++probe) {
    slope = std::max(slope, std::max((g[0] - g[1]) / (x[1] - x[0]), (g[2] - g[1]) / (x[2] - x[1])));
    if (!(slope > 0.0)) return kNaN;
    const auto [xSafe, safeBound] = isoDipArgmin(x, g, kIsoDipSlopeSafety * slope);
    if (safeBound > 0.0) return kNaN;
    const auto [xFit, bound] = isoDipArgmin(x, g, slope);
    const double xv = bound > 0.0 ? xSafe : xFit;
    if (xv <= x[0] || xv >= x[2] || xv == x[1]) return kNaN;
    const double f = excess(xv);
    const double gv = s * f;
    if (gv <= 0.0) {
      fHit = f;
      return xv;
    }
    if (xv < x[1]) {
      if (gv < g[1]) {
        x = {x[0], xv, x[1]};
        g = {g[0], gv, g[1]};
      } else {
        x[0] = xv;
        g[0] = gv;
      }
    } else if (gv < g[1]) {
      x = {x[1], xv, x[2]};
      g = {g[1], gv, g[2]};
    } else {
      x[2] = xv;
      g[2] = gv;
    }
  }
  return kNaN;
}

RayResult marchIso(const Frame& f, const Vec3& o, const Vec3& d, const Vec3& directionPatient,
                   const Chord& chord) {
  RayResult out;
  const double iso = f.options.isoValue;
  const double voxelsPerMm = length(d);
  const auto [n, delta] = cutChord(f, chord);
  auto excess = [&](double t) {
    ++out.samples;
    return sampleAt(*f.volume, indexPoint(o, d, t)) - iso;
  };
  // The crossing inside [lo, hi], whose excesses differ in sign: bisection keeps a bracket
  // with a sign change; the last step is the linear root.
  auto root = [&](double lo, double hi, double flo, double fhi) {
    while ((hi - lo) * voxelsPerMm > kIsoToleranceVoxels) {
      const double mid = 0.5 * (lo + hi);
      if (mid <= lo || mid >= hi) break;
      const double fm = excess(mid);
      if (fm == 0.0) return mid;
      if ((fm < 0) == (flo < 0)) {
        lo = mid;
        flo = fm;
      } else {
        hi = mid;
        fhi = fm;
      }
    }
    return lo + (hi - lo) * (flo / (flo - fhi));
  };
  double ta = chord.tNear;
  double fa = excess(ta);
  double tBefore = kNaN, fBefore = 0.0;  // the sample before ta
  double hit = fa == 0.0 ? ta : kNaN;
  for (int64_t s = 1; s <= n && std::isnan(hit); ++s) {
    const double tb = s == n ? chord.tFar : chord.tNear + static_cast<double>(s) * delta;
    const double fb = excess(tb);
    if (fb == 0.0) {
      hit = tb;
    } else if ((fa < 0) != (fb < 0)) {
      hit = root(ta, tb, fa, fb);
    } else if (!std::isnan(tBefore) && (fBefore < 0) == (fa < 0)) {
      const double sign = fa < 0 ? -1.0 : 1.0;
      const std::array<double, 3> g{sign * fBefore, sign * fa, sign * fb};
      if (g[1] < g[0] && g[1] <= g[2]) {
        double fHit = 0.0;
        const double xv = isoDip(excess, sign, {tBefore, ta, tb}, g, fHit);
        if (!std::isnan(xv)) hit = fHit == 0.0 ? xv : root(tBefore, xv, fBefore, fHit);
      }
    }
    tBefore = ta;
    fBefore = fa;
    ta = tb;
    fa = fb;
  }
  if (std::isnan(hit)) return out;
  const Vec3 p = indexPoint(o, d, hit);
  Classification c = classify(*f.tf, iso);
  c.alpha = 1.0;
  if (f.shade) {
    c = shadePhong(f.tf->material, c, gradientPatient(f, p), directionPatient);
    out.samples += 6;
  }
  out.r = c.r;
  out.g = c.g;
  out.b = c.b;
  out.a = 1.0;
  out.depth = hit;
  out.value = iso;
  return out;
}

// Where the chord crosses the voxel-centre planes of one axis, within (tNear, tFar).
void planeCrossings(double origin, double direction, int64_t dim, const Chord& chord,
                    std::vector<double>& out) {
  if (direction == 0.0 || dim < 2) return;
  const double a = origin + chord.tNear * direction;
  const double b = origin + chord.tFar * direction;
  const double lo = std::max(0.0, std::ceil(std::min(a, b)));
  const double hi = std::min(static_cast<double>(dim - 1), std::floor(std::max(a, b)));
  for (double plane = lo; plane <= hi; plane += 1.0) {
    const double t = (plane - origin) / direction;
    if (t > chord.tNear && t < chord.tFar) out.push_back(t);
  }
}

RayResult marchMip(const Frame& f, const Vec3& o, const Vec3& d, const Chord& chord) {
  RayResult out;
  std::vector<double> cuts{chord.tNear, chord.tFar};
  const auto& dims = f.volume->dims();
  planeCrossings(o.x, d.x, dims[0], chord, cuts);
  planeCrossings(o.y, d.y, dims[1], chord, cuts);
  planeCrossings(o.z, d.z, dims[2], chord, cuts);
  std::sort(cuts.begin(), cuts.end());
  double best = -kInf, bestT = chord.tNear;
  auto consider = [&](double t) {
    const double v = sampleAt(*f.volume, indexPoint(o, d, t));
    ++out.samples;
    if (v > best) {
      best = v;
      bestT = t;
    }
    return v;
  };
  consider(cuts.front());
  for (std::size_t i = 1; i < cuts.size(); ++i) {
    const double ta = cuts[i - 1], tb = cuts[i];
    const double h = tb - ta;
    if (!(h > 0)) continue;
    // The interpolant is a cubic in u = 3 (t - ta) / h on [0, 3]; from its values at u = 0..3
    // (Newton forward differences) its derivative's roots are the interior candidates.
    const double v0 = sampleAt(*f.volume, indexPoint(o, d, ta));
    const double v1 = sampleAt(*f.volume, indexPoint(o, d, ta + h / 3.0));
    const double v2 = sampleAt(*f.volume, indexPoint(o, d, ta + 2.0 * h / 3.0));
    out.samples += 3;
    const double v3 = sampleAt(*f.volume, indexPoint(o, d, tb));
    const double d1 = v1 - v0, d2 = v2 - 2 * v1 + v0, d3 = v3 - 3 * v2 + 3 * v1 - v0;
    const double qa = 0.5 * d3, qb = d2 - d3, qc = d1 - 0.5 * d2 + d3 / 3.0;
    double roots[2];
    int count = 0;
    const double scale = std::abs(qa) + std::abs(qb) + std::abs(qc);
    if (std::abs(qa) > 1e-12 * scale) {
      const double disc = qb * qb - 4 * qa * qc;
      if (disc >= 0) {
        // Numerically stable pair of roots.
        const double q = -0.5 * (qb + std::copysign(std::sqrt(disc), qb));
        roots[count++] = q / qa;
        if (q != 0) roots[count++] = qc / q;
      }
    } else if (std::abs(qb) > 1e-12 * scale) {
      roots[count++] = -qc / qb;
    }
    for (int r = 0; r < count; ++r) {
      if (roots[r] > 0 && roots[r] < 3) consider(ta + roots[r] * h / 3.0);
    }
    consider(tb);  // after the interior candidates: the first t of the maximum is kept
  }
  const Classification c = classify(*f.tf, best);
  out.r = c.r * c.alpha;
  out.g = c.g * c.alpha;
  out.b = c.b * c.alpha;
  out.a = c.alpha;
  out.depth = bestT;
  out.value = best;
  return out;
}

void checkOptions(const RenderOptions& o, const transfer::TransferFunction& tf) {
  if (!(o.stepMm >= 0 && std::isfinite(o.stepMm))) {
    throw Error("", fmt::format("step {} mm must be positive (or 0 for the default)", o.stepMm));
  }
  if (!(o.earlyTermination > 0 && o.earlyTermination <= 1)) {
    throw Error("", fmt::format("early termination {} must be in (0, 1]", o.earlyTermination));
  }
  if (o.mode == RenderMode::Iso && !std::isfinite(o.isoValue)) {
    throw Error("", "the isovalue must be finite");
  }
  if (o.boundary.enabled && !(std::isfinite(o.boundary.kC) && std::isfinite(o.boundary.kS) &&
                              std::isfinite(o.boundary.kE) && o.boundary.kE >= 0)) {
    throw Error("", "boundary enhancement: kC, kS must be finite and kE finite and >= 0");
  }
  if (o.preintegration && o.jitter) {
    throw Error("", "pre-integration and jitter are alternatives: choose one");
  }
  if (!(tf.unitDistanceMm > 0 && std::isfinite(tf.unitDistanceMm))) {
    throw Error("",
                fmt::format("transfer function \"{}\": unit distance must be positive", tf.name));
  }
}

}  // namespace

float rayJitter(uint32_t x, uint32_t y) {
  // lowbias32 (Chris Wellons' integer hash) of the pixel's two coordinates.
  uint32_t h = x * 0x8da6b343u ^ y * 0xd8163841u;
  h ^= h >> 16;
  h *= 0x7feb352du;
  h ^= h >> 15;
  h *= 0x846ca68bu;
  h ^= h >> 16;
  return static_cast<float>(h >> 8) * (1.0f / 16777216.0f);
}

Classification classify(const transfer::TransferFunction& tf, double value) {
  Classification c;
  if (std::isnan(value)) return c;
  if (!tf.color.empty()) {
    auto key = [](const transfer::ColorPoint& p) { return p.value; };
    c.r = interpolatePoints(tf.color, value, key, [](const auto& p) { return double{p.r}; });
    c.g = interpolatePoints(tf.color, value, key, [](const auto& p) { return double{p.g}; });
    c.b = interpolatePoints(tf.color, value, key, [](const auto& p) { return double{p.b}; });
  }
  if (!tf.opacity.empty()) {
    c.alpha = interpolatePoints(
        tf.opacity, value, [](const transfer::OpacityPoint& p) { return p.value; },
        [](const auto& p) { return double{p.alpha}; });
  }
  return c;
}

double gradientOpacity(const transfer::TransferFunction& tf, double magnitudePerMm) {
  if (tf.gradientOpacity.empty()) return 1.0;
  if (std::isnan(magnitudePerMm)) return 0.0;
  return interpolatePoints(
      tf.gradientOpacity, magnitudePerMm,
      [](const transfer::GradientOpacityPoint& p) { return p.magnitude; },
      [](const auto& p) { return double{p.alpha}; });
}

double correctOpacity(double alpha, double ratio) {
  if (!(alpha > 0) || !(ratio > 0)) return 0.0;  // no material, or no path through it
  if (alpha >= 1.0) return 1.0;
  return -std::expm1(ratio * std::log1p(-alpha));
}

Chord clipToDomain(const Vec3& o, const Vec3& d, const std::array<int64_t, 3>& dims, double tMin) {
  Chord c{tMin, kInf};
  for (int axis = 0; axis < 3; ++axis) {
    const double lo = -0.5, hi = static_cast<double>(dims[static_cast<std::size_t>(axis)]) - 0.5;
    const double origin = o[axis], direction = d[axis];
    if (direction == 0.0) {
      // Parallel to this slab: inside (faces included) for every t, or nowhere.
      if (origin < lo || origin > hi) return {0, -1};
      continue;
    }
    // Divisions, not a reciprocal: a tiny component gives huge finite or infinite t, never NaN.
    double t0 = (lo - origin) / direction, t1 = (hi - origin) / direction;
    if (t0 > t1) std::swap(t0, t1);
    c.tNear = std::max(c.tNear, t0);
    c.tFar = std::min(c.tFar, t1);
    if (c.empty()) return {0, -1};
  }
  return c;
}

RenderResult ReferenceRenderer::render(const Camera& camera, const transfer::TransferFunction& tf,
                                       const RenderOptions& options) const {
  camera.validate();
  checkOptions(options, tf);
  if (volume_.hasCoarseLeaves() && options.mode == RenderMode::Mip) {
    // The exact maximum splits chords at the leaf level's voxel-centre planes; a coarse leaf's
    // interpolant has other planes.
    throw Error("", "the reference renders DVR and isosurfaces over an LOD cut with coarse "
                    "leaves, not MIP");
  }
  Frame f;
  f.volume = &volume_;
  f.tf = &tf;
  f.options = options;
  f.indexFromPatient = volume_.patientFromIndex().inverseAffine();
  const Mat4& m = volume_.patientFromIndex();
  const double smallestSpacing =
      std::min({length(m.column(0)), length(m.column(1)), length(m.column(2))});
  f.stepMm = options.stepMm > 0 ? options.stepMm : 0.25 * smallestSpacing;
  // The longest chord is the domain's diagonal; bound the steps per ray so counts stay exact.
  const double diagonalMm = 2.0 * VolumeDomain{volume_.dims(), m}.boundingRadiusMm();
  if (diagonalMm / f.stepMm > 1e9) {
    throw Error("",
                fmt::format("step {} mm is too small: over 1e9 steps across the volume", f.stepMm));
  }
  f.shade = options.shading == RenderOptions::Shading::On ||
            (options.shading == RenderOptions::Shading::FromTransferFunction && tf.material.shade);
  f.useGradientOpacity = options.gradientOpacity && !tf.gradientOpacity.empty();
  f.needGradient = f.shade || f.useGradientOpacity || options.boundary.enabled;
  f.support = transfer::opacitySupport(tf);

  RenderResult result;
  result.image = Image(camera.width, camera.height);
  if (options.mode == RenderMode::Mip) {
    result.value.assign(result.image.pixelCount(), kNaN);
  }
  result.stats.stepMm = f.stepMm;
  std::atomic<int64_t> samples{0}, raysHit{0};
  tbb::parallel_for(
      tbb::blocked_range<int>(0, camera.height), [&](const tbb::blocked_range<int>& rows) {
        int64_t rowSamples = 0, rowHits = 0;
        for (int y = rows.begin(); y < rows.end(); ++y) {
          for (int x = 0; x < camera.width; ++x) {
            const Ray ray = camera.ray(x, y);
            const Vec3 o = f.indexFromPatient.transformPoint(ray.origin);
            const Vec3 d = f.indexFromPatient.transformVector(ray.direction);
            const Chord chord = clipToDomain(o, d, volume_.dims(), 0.0);
            if (chord.empty()) continue;
            ++rowHits;
            RayResult r;
            switch (options.mode) {
              case RenderMode::Dvr:
                if (options.preintegration) {
                  r = marchDvrPreintegrated(f, o, d, ray.direction, chord);
                } else {
                  const double j = options.jitter ? rayJitter(static_cast<uint32_t>(x), static_cast<uint32_t>(y)) : 0.5;
                  r = marchDvr(f, o, d, ray.direction, chord, j);
                }
                break;
              case RenderMode::Iso:
                r = marchIso(f, o, d, ray.direction, chord);
                break;
              case RenderMode::Mip:
                r = marchMip(f, o, d, chord);
                break;
            }
            rowSamples += r.samples;
            float* p = result.image.pixel(x, y);
            p[0] = static_cast<float>(r.r);
            p[1] = static_cast<float>(r.g);
            p[2] = static_cast<float>(r.b);
            p[3] = static_cast<float>(r.a);
            result.image.depth[result.image.index(x, y)] = static_cast<float>(r.depth);
            if (!result.value.empty()) result.value[result.image.index(x, y)] = r.value;
          }
        }
        samples += rowSamples;
        raysHit += rowHits;
      });
  result.stats.samples = samples.load();
  result.stats.raysHit = raysHit.load();
  return result;
}

ReferenceRenderer::ConvergedResult ReferenceRenderer::renderConverged(
    const Camera& camera, const transfer::TransferFunction& tf, const RenderOptions& options,
    const ConvergenceRule& rule) const {
  ConvergedResult out;
  RenderOptions o = options;
  RenderResult previous = render(camera, tf, o);
  out.stepsMm.push_back(previous.stats.stepMm);
  for (int halving = 0; halving < rule.maxHalvings; ++halving) {
    o.stepMm = 0.5 * out.stepsMm.back();
    RenderResult next = render(camera, tf, o);
    out.stepsMm.push_back(next.stats.stepMm);
    double maxChange = 0;
    for (std::size_t i = 0; i < next.image.rgba.size(); ++i) {
      maxChange = std::max(maxChange, std::abs(static_cast<double>(next.image.rgba[i]) - previous.image.rgba[i]));
    }
    const ImageMetrics m = compare(previous.image, next.image);
    out.changeMax.push_back(maxChange);
    out.changePsnrDb.push_back(m.psnrDb);
    previous = std::move(next);
    if (maxChange <= rule.maxChange && m.psnrDb >= rule.minPsnrDb) {
      out.converged = true;
      break;
    }
  }
  out.estimatedMaxError = out.changeMax.empty() ? 0.0 : out.changeMax.back() / 3.0;
  out.result = std::move(previous);
  return out;
}

}  // namespace octoray::gpu::reference
