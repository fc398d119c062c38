#include "octoray/transfer/preintegration.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "octoray/core/error.h"

namespace octoray::transfer {

double alphaCorrected(double alpha, double stepMm, double unitDistanceMm) {
  if (!(alpha > 0)) return 0;          // also NaN
  if (!(stepMm > 0)) return 0;         // no path, no absorption (also NaN)
  if (!(unitDistanceMm > 0)) return std::min(alpha, 1.0);
  if (alpha >= 1) return 1;            // log1p(-1) = -inf; handled before it can meet a 0
  // 1 - (1 - a)^r = -expm1(r * log1p(-a)): no cancellation when a or r is tiny.
  return -std::expm1((stepMm / unitDistanceMm) * std::log1p(-alpha));
}

std::array<double, 4> integrateSegment(const TransferFunction& tf, double frontValue,
                                       double backValue, double stepMm,
                                       std::uint32_t subStepCount) {
  std::array<double, 4> rgba{0, 0, 0, 0};
  if (subStepCount == 0) subStepCount = 1;
  const double subStepMm = stepMm / subStepCount;
  double transmittance = 1;  // exp(-tau so far), kept in double
  for (std::uint32_t k = 0; k < subStepCount; ++k) {
    // Midpoint of sub-step k along the linear value profile.
    const double t = (k + 0.5) / subStepCount;
    const double value = frontValue + t * (backValue - frontValue);
    const std::array<float, 4> sample = tf.evaluate(value);
    const double alpha = alphaCorrected(sample[3], subStepMm, tf.unitDistanceMm);
    const double weight = transmittance * alpha;  // front-to-back compositing
    rgba[0] += weight * sample[0];
    rgba[1] += weight * sample[1];
    rgba[2] += weight * sample[2];
    transmittance *= 1 - alpha;
  }
  rgba[3] = 1 - transmittance;
  return rgba;
}

PreintegrationTable::PreintegrationTable(const TransferFunction& tf, double loValue,
                                         double hiValue, std::uint32_t binCount, double stepMm,
                                         std::uint32_t subStepCount)
    : loValue_(loValue), hiValue_(hiValue), binCount_(binCount), stepMm_(stepMm) {
  if (!(std::isfinite(loValue) && std::isfinite(hiValue) && loValue < hiValue) || binCount < 2 ||
      binCount > 4096 || !(std::isfinite(stepMm) && stepMm >= 0)) {
    throw Error("", fmt::format("pre-integration table [{}, {}] x {} bins, step {} mm is not usable",
                                loValue, hiValue, binCount, stepMm));
  }
  rgba_.resize(std::size_t{binCount} * binCount);
  for (std::uint32_t back = 0; back < binCount; ++back) {
    for (std::uint32_t front = 0; front < binCount; ++front) {
      const std::array<double, 4> segment =
          integrateSegment(tf, valueAt(front), valueAt(back), stepMm, subStepCount);
      rgba_[std::size_t{back} * binCount + front] = {
          static_cast<float>(segment[0]), static_cast<float>(segment[1]),
          static_cast<float>(segment[2]), static_cast<float>(segment[3])};
    }
  }
}

double PreintegrationTable::valueAt(std::uint32_t bin) const {
  if (bin + 1 >= binCount_) return hiValue_;
  return loValue_ + (hiValue_ - loValue_) * bin / (binCount_ - 1);
}

std::pair<double, double> opacitySupport(const TransferFunction& tf) {
  constexpr double kInf = std::numeric_limits<double>::infinity();
  const auto& points = tf.opacity;
  std::size_t first = points.size(), last = 0;
  for (std::size_t i = 0; i < points.size(); ++i) {
    if (points[i].alpha > 0) {
      first = std::min(first, i);
      last = i;
    }
  }
  if (first == points.size()) return {kInf, -kInf};
  // Piecewise linear, clamped at the ends: opacity starts after the zero point before the
  // first non-zero one and ends at the zero point after the last.
  const double lo = first == 0 ? -kInf : points[first - 1].value;
  const double hi = last + 1 == points.size() ? kInf : points[last + 1].value;
  return {lo, hi};
}

SegmentExtinctionTable::SegmentExtinctionTable(const TransferFunction& tf, double loValue,
                                               double hiValue, std::uint32_t binCount)
    : loValue_(loValue), hiValue_(hiValue), binCount_(binCount) {
  if (!(std::isfinite(loValue) && std::isfinite(hiValue) && loValue < hiValue) || binCount < 2 ||
      binCount > 4096) {
    throw Error("", fmt::format("pre-integration table [{}, {}] x {} bins is not usable", loValue,
                                hiValue, binCount));
  }
  constexpr std::size_t kFine = 16;
  const std::size_t grid = (std::size_t{binCount} - 1) * kFine + 1;
  const double h = (hiValue - loValue) / static_cast<double>(grid - 1);
  // Running integrals over the value of extinction and of colour x extinction.
  std::vector<std::array<double, 4>> integral(grid);
  std::vector<std::array<double, 4>> point(grid);  // colour x extinction, extinction
  for (std::size_t i = 0; i < grid; ++i) {
    const double v = i + 1 == grid ? hiValue : loValue + h * static_cast<double>(i);
    const std::array<float, 4> c = tf.evaluate(v);
    const double alpha = std::clamp<double>(c[3], 0.0, 1.0);
    const double extinction = alpha < 1.0 ? -std::log1p(-alpha) : 1e4;
    point[i] = {c[0] * extinction, c[1] * extinction, c[2] * extinction, extinction};
    if (i > 0) {
      for (int ch = 0; ch < 4; ++ch) {
        integral[i][ch] = integral[i - 1][ch] + 0.5 * h * (point[i - 1][ch] + point[i][ch]);
      }
    }
  }
  entries_.resize(std::size_t{binCount} * binCount);
  for (std::uint32_t back = 0; back < binCount; ++back) {
    for (std::uint32_t front = 0; front < binCount; ++front) {
      const std::size_t f = front * kFine, b = back * kFine;
      std::array<float, 4>& e = entries_[std::size_t{back} * binCount + front];
      for (int ch = 0; ch < 4; ++ch) {
        const double mean = f == b ? point[f][ch]
                                   : (integral[b][ch] - integral[f][ch]) /
                                         (h * (static_cast<double>(b) - static_cast<double>(f)));
        e[ch] = static_cast<float>(mean);
      }
    }
  }
}

double SegmentExtinctionTable::valueAt(std::uint32_t bin) const {
  if (bin + 1 >= binCount_) return hiValue_;
  return loValue_ + (hiValue_ - loValue_) * bin / (binCount_ - 1);
}

}  // namespace octoray::transfer
