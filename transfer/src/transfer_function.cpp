#include "octoray/transfer/transfer_function.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "octoray/core/error.h"

namespace octoray::transfer {
namespace {

// Index of the first control point whose value is greater than `value` (points sorted).
template <typename Point>
std::size_t upperIndex(const std::vector<Point>& points, double value, double Point::*key) {
  const auto it = std::upper_bound(points.begin(), points.end(), value,
                                   [key](double v, const Point& p) { return v < p.*key; });
  return static_cast<std::size_t>(it - points.begin());
}

// Piecewise-linear interpolation of one channel, clamped at both ends. Requires a non-empty
// list and a non-NaN value. Interpolates in double so tiny opacities do not round to zero
// before the final narrowing.
template <typename Point, typename Channel>
double interpolate(const std::vector<Point>& points, double value, double Point::*key,
                   Channel channel) {
  if (value < points.front().*key) return channel(points.front());
  if (value >= points.back().*key) return channel(points.back());
  const std::size_t upper = upperIndex(points, value, key);  // in [1, size - 1] here
  const Point& a = points[upper - 1];
  const Point& b = points[upper];
  const double t = (value - a.*key) / (b.*key - a.*key);  // b > value >= a, so no 0/0
  return channel(a) + t * (channel(b) - channel(a));
}

void require(bool condition, const std::string& path, const std::string& field,
             const std::string& what) {
  if (!condition) throw Error(path, fmt::format("{}: {}", field, what));
}

bool finite(double v) { return std::isfinite(v); }
bool unitInterval(double v) { return v >= 0.0 && v <= 1.0; }  // false for NaN

}  // namespace

std::array<float, 4> TransferFunction::evaluate(double value) const {
  std::array<float, 4> rgba{0, 0, 0, 0};
  if (std::isnan(value)) return rgba;
  if (!color.empty()) {
    rgba[0] = static_cast<float>(
        interpolate(color, value, &ColorPoint::value, [](const ColorPoint& p) { return p.r; }));
    rgba[1] = static_cast<float>(
        interpolate(color, value, &ColorPoint::value, [](const ColorPoint& p) { return p.g; }));
    rgba[2] = static_cast<float>(
        interpolate(color, value, &ColorPoint::value, [](const ColorPoint& p) { return p.b; }));
  }
  rgba[3] = opacityAt(value);
  return rgba;
}

float TransferFunction::opacityAt(double value) const {
  if (opacity.empty() || std::isnan(value)) return 0.0f;
  return static_cast<float>(interpolate(opacity, value, &OpacityPoint::value,
                                        [](const OpacityPoint& p) { return p.alpha; }));
}

float TransferFunction::gradientOpacityAt(double magnitude) const {
  if (gradientOpacity.empty()) return 1.0f;
  if (std::isnan(magnitude)) return 0.0f;
  return static_cast<float>(interpolate(gradientOpacity, magnitude,
                                        &GradientOpacityPoint::magnitude,
                                        [](const GradientOpacityPoint& p) { return p.alpha; }));
}

bool TransferFunction::transparentOver(double lo, double hi) const {
  if (opacity.empty()) return true;
  if (std::isnan(lo) || std::isnan(hi)) return false;  // unknown range: never call it empty
  if (lo > hi) std::swap(lo, hi);
  // Decided from the control points alone, with no arithmetic: a linear segment whose open
  // interior meets [lo, hi] is zero there only if both its ends are zero, and alphas are never
  // negative, so zero cannot occur strictly inside a segment with a non-zero end.
  if (lo < opacity.front().value && opacity.front().alpha != 0.0f) return false;
  if (hi > opacity.back().value && opacity.back().alpha != 0.0f) return false;
  for (std::size_t i = 0; i < opacity.size(); ++i) {
    const OpacityPoint& p = opacity[i];
    if (p.value >= lo && p.value <= hi && p.alpha != 0.0f) return false;
    if (i + 1 < opacity.size()) {
      const OpacityPoint& q = opacity[i + 1];
      const bool interiorMeets = p.value < q.value && lo < q.value && hi > p.value;
      if (interiorMeets && (p.alpha != 0.0f || q.alpha != 0.0f)) return false;
    }
  }
  return true;
}

void validate(const TransferFunction& tf, const std::string& path) {
  const std::string prefix = tf.name.empty() ? std::string() : fmt::format("'{}' ", tf.name);
  auto field = [&](const char* name, std::size_t i) {
    return fmt::format("{}{}[{}]", prefix, name, i);
  };
  require(!tf.color.empty(), path, prefix + "color", "needs at least one control point");
  require(!tf.opacity.empty(), path, prefix + "opacity", "needs at least one control point");
  for (const auto& [name, count] : {std::pair{"color", tf.color.size()}, std::pair{"opacity", tf.opacity.size()},
                                    std::pair{"gradientOpacity", tf.gradientOpacity.size()}}) {
    require(count <= kMaxControlPoints, path, prefix + name,
            fmt::format("{} control points, more than the {} allowed", count, kMaxControlPoints));
  }
  for (std::size_t i = 0; i < tf.color.size(); ++i) {
    const ColorPoint& p = tf.color[i];
    require(finite(p.value), path, field("color", i), "value is not a finite number");
    // The message names the previous point, so it is only built when there is one.
    if (i > 0) {
      require(p.value >= tf.color[i - 1].value, path, field("color", i),
              fmt::format("value {} is below the previous point's {} (points must be sorted)",
                          p.value, tf.color[i - 1].value));
    }
    require(unitInterval(p.r) && unitInterval(p.g) && unitInterval(p.b), path, field("color", i),
            fmt::format("colour ({}, {}, {}) is outside [0, 1]", p.r, p.g, p.b));
  }
  for (std::size_t i = 0; i < tf.opacity.size(); ++i) {
    const OpacityPoint& p = tf.opacity[i];
    require(finite(p.value), path, field("opacity", i), "value is not a finite number");
    // The message names the previous point, so it is only built when there is one.
    if (i > 0) {
      require(p.value >= tf.opacity[i - 1].value, path, field("opacity", i),
              fmt::format("value {} is below the previous point's {} (points must be sorted)",
                          p.value, tf.opacity[i - 1].value));
    }
    require(unitInterval(p.alpha), path, field("opacity", i),
            fmt::format("alpha {} is outside [0, 1]", p.alpha));
  }
  for (std::size_t i = 0; i < tf.gradientOpacity.size(); ++i) {
    const GradientOpacityPoint& p = tf.gradientOpacity[i];
    // Negative magnitudes never occur, but real Slicer presets place points there to shape
    // the function near 0, so they are accepted.
    require(finite(p.magnitude), path, field("gradientOpacity", i),
            fmt::format("magnitude {} is not a finite number", p.magnitude));
    // The message names the previous point, so it is only built when there is one.
    if (i > 0) {
      require(p.magnitude >= tf.gradientOpacity[i - 1].magnitude, path, field("gradientOpacity", i),
              fmt::format("magnitude {} is below the previous point's {} (points must be sorted)",
                          p.magnitude, tf.gradientOpacity[i - 1].magnitude));
    }
    require(unitInterval(p.alpha), path, field("gradientOpacity", i),
            fmt::format("alpha {} is outside [0, 1]", p.alpha));
  }
  const Material& m = tf.material;
  require(unitInterval(m.ambient), path, prefix + "material.ambient",
          fmt::format("{} is outside [0, 1]", m.ambient));
  require(unitInterval(m.diffuse), path, prefix + "material.diffuse",
          fmt::format("{} is outside [0, 1]", m.diffuse));
  require(unitInterval(m.specular), path, prefix + "material.specular",
          fmt::format("{} is outside [0, 1]", m.specular));
  require(finite(m.specularPower) && m.specularPower >= 0, path, prefix + "material.specularPower",
          fmt::format("{} is not a finite non-negative number", m.specularPower));
  require(finite(tf.unitDistanceMm) && tf.unitDistanceMm > 0, path, prefix + "unitDistanceMm",
          fmt::format("{} is not a finite positive number", tf.unitDistanceMm));
}

ValueRange opacityRampRange(const TransferFunction& tf) {
  const auto& points = tf.opacity;
  if (points.empty()) return {};
  std::size_t first = 0;
  while (first + 1 < points.size() && points[first + 1].alpha == points.front().alpha) ++first;
  std::size_t last = points.size() - 1;
  while (last > 0 && points[last - 1].alpha == points.back().alpha) --last;
  if (first >= last) return {points.front().value, points.back().value};  // constant opacity
  return {points[first].value, points[last].value};
}

TransferFunction withWindowLevel(const TransferFunction& tf, double window, double level) {
  if (!(finite(window) && window > 0)) {
    throw Error("", fmt::format("window {} is not a finite positive number", window));
  }
  if (!finite(level)) throw Error("", fmt::format("level {} is not a finite number", level));
  const ValueRange ramp = opacityRampRange(tf);
  const double centre = 0.5 * (ramp.lo + ramp.hi);
  const double width = ramp.hi - ramp.lo;
  const double scale = width > 0 ? window / width : 1.0;
  // windowedFromPreset: value' = level + (value - centre) * scale; order is kept (scale > 0).
  auto windowedFromPreset = [&](double value) { return level + (value - centre) * scale; };
  TransferFunction windowed = tf;
  for (ColorPoint& p : windowed.color) p.value = windowedFromPreset(p.value);
  for (OpacityPoint& p : windowed.opacity) p.value = windowedFromPreset(p.value);
  return windowed;
}

}  // namespace octoray::transfer
