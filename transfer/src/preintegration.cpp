#include "octoray/transfer/preintegration.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

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

}  // namespace octoray::transfer
