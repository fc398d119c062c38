#include "octoray/viewer/measure.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <numbers>

#include "octoray/core/error.h"

namespace octoray::viewer {
namespace {

// The ROI's bounding box in its plane: the first corner, and the signed extents along the
// kept right and down axes.
struct Box {
  Vec3 corner;
  double w = 0, h = 0;  // >= 0, along right and down from `corner`
};

Box roiBox(const Measurement& m) {
  if (m.points.size() != 2) throw Error("", "an ROI needs two corner points");
  const Vec3 d = m.points[1] - m.points[0];
  const double du = dot(d, m.right), dv = dot(d, m.down);
  Box b;
  b.corner = m.points[0] + std::min(0.0, du) * m.right + std::min(0.0, dv) * m.down;
  b.w = std::abs(du);
  b.h = std::abs(dv);
  return b;
}

}  // namespace

double distanceMm(const Measurement& m) {
  if (m.points.size() != 2) throw Error("", "a distance needs two points");
  return length(m.points[1] - m.points[0]);
}

double angleDegrees(const Measurement& m) {
  if (m.points.size() != 3) throw Error("", "an angle needs three points");
  const Vec3 a = m.points[0] - m.points[1], b = m.points[2] - m.points[1];
  const double la = length(a), lb = length(b);
  if (la == 0 || lb == 0) return 0;
  const double c = std::clamp(dot(a, b) / (la * lb), -1.0, 1.0);
  return std::acos(c) * 180.0 / std::numbers::pi;
}

std::vector<Vec3> roiSamplePositions(const Measurement& m, double stepMm) {
  const Box b = roiBox(m);
  std::vector<Vec3> out;
  if (stepMm <= 0 || b.w <= 0 || b.h <= 0) return out;
  const int64_t nu = std::max<int64_t>(1, static_cast<int64_t>(std::floor(b.w / stepMm)));
  const int64_t nv = std::max<int64_t>(1, static_cast<int64_t>(std::floor(b.h / stepMm)));
  // Centre the grid in the box so it is symmetric about the shape's centre.
  const double u0 = 0.5 * (b.w - static_cast<double>(nu - 1) * stepMm);
  const double v0 = 0.5 * (b.h - static_cast<double>(nv - 1) * stepMm);
  const double a = 0.5 * b.w, c = 0.5 * b.h;
  for (int64_t j = 0; j < nv; ++j) {
    for (int64_t i = 0; i < nu; ++i) {
      const double u = u0 + static_cast<double>(i) * stepMm;
      const double v = v0 + static_cast<double>(j) * stepMm;
      if (m.kind == MeasureKind::Ellipse) {
        const double x = (u - a) / a, y = (v - c) / c;
        if (x * x + y * y > 1.0) continue;
      }
      out.push_back(b.corner + u * m.right + v * m.down);
    }
  }
  return out;
}

RoiStats roiStats(const Measurement& m, const std::vector<double>& values) {
  const Box b = roiBox(m);
  RoiStats s;
  s.areaMm2 = m.kind == MeasureKind::Ellipse ? std::numbers::pi * 0.25 * b.w * b.h : b.w * b.h;
  double sum = 0;
  s.min = std::numeric_limits<double>::infinity();
  s.max = -s.min;
  for (double v : values) {
    if (std::isnan(v)) continue;
    ++s.samples;
    sum += v;
    s.min = std::min(s.min, v);
    s.max = std::max(s.max, v);
  }
  if (s.samples == 0) {
    s.min = s.max = s.mean = s.sd = std::numeric_limits<double>::quiet_NaN();
    return s;
  }
  s.mean = sum / static_cast<double>(s.samples);
  double sq = 0;
  for (double v : values) {
    if (!std::isnan(v)) sq += (v - s.mean) * (v - s.mean);
  }
  s.sd = std::sqrt(sq / static_cast<double>(s.samples));
  return s;
}

std::string unitSuffix(const std::string& valueUnit) {
  return valueUnit.empty() ? "" : " " + valueUnit;
}

std::string describe(const Measurement& m, const RoiStats* stats, const std::string& valueUnit, int decimals) {
  switch (m.kind) {
    case MeasureKind::Distance: return fmt::format("{:.2f} mm", distanceMm(m));
    case MeasureKind::Angle: return fmt::format("{:.1f}\u00b0", angleDegrees(m));
    case MeasureKind::Ellipse:
    case MeasureKind::Rectangle:
      if (!stats) return "ROI";
      if (stats->samples == 0) return fmt::format("outside the volume, {:.1f} mm\u00b2", stats->areaMm2);
      return fmt::format("mean {:.{}f} SD {:.{}f}{}, min {:.{}f} max {:.{}f}, {:.1f} mm\u00b2", stats->mean,
                         decimals + 1, stats->sd, decimals + 1, unitSuffix(valueUnit), stats->min, decimals,
                         stats->max, decimals, stats->areaMm2);
  }
  return {};
}

}  // namespace octoray::viewer
