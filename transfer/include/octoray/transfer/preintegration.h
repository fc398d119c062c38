#pragma once
// Opacity correction and pre-integrated classification for the emission-absorption model.
//
// A TF alpha is the opacity of unitDistanceMm of material, so the extinction coefficient is
// tau(v) = -ln(1 - alpha(v)) / unitDistanceMm and emission is colour(v) * tau(v). A ray
// segment of length stepMm along which the value runs linearly from `front` to `back` has
//   alpha = 1 - exp(-integral of tau),  colour = integral of c * tau * exp(-tau so far)
// (colour premultiplied by alpha). Gradient opacity is not part of the table: it depends on
// the gradient, not the value, and is applied by the renderer as a multiplier.

#include <array>
#include <cstdint>
#include <vector>

#include "octoray/transfer/transfer_function.h"

namespace octoray::transfer {

// 1 - (1 - alpha)^(stepMm / unitDistanceMm), accurate for tiny alpha (log1p/expm1) and never
// NaN: alpha <= 0 or NaN gives 0, alpha >= 1 gives 1 for any positive step, a step <= 0
// gives 0. A non-positive or NaN unit distance returns alpha unchanged (validate() rejects
// such TFs).
double alphaCorrected(double alpha, double stepMm, double unitDistanceMm);

// Premultiplied RGBA of one segment (see above), integrated in double precision by the
// midpoint rule on subStepCount sub-steps, each composited with exact per-sub-step opacity
// correction. Exact for a constant TF at any subStepCount; front == back gives the point
// TF value corrected for stepMm.
std::array<double, 4> integrateSegment(const TransferFunction& tf, double frontValue,
                                       double backValue, double stepMm,
                                       std::uint32_t subStepCount = 256);

// Table of integrateSegment over (front, back) pairs for one step length: entry (f, b) holds
// the segment from value(f) to value(b), value(i) = loValue + i * (hiValue - loValue) /
// (binCount - 1), so bins sit on texel centres when uploaded as a binCount^2 texture.
class PreintegrationTable {
 public:
  PreintegrationTable(const TransferFunction& tf, double loValue, double hiValue,
                      std::uint32_t binCount, double stepMm, std::uint32_t subStepCount = 64);

  std::uint32_t binCount() const { return binCount_; }
  double stepMm() const { return stepMm_; }
  double valueAt(std::uint32_t bin) const;
  // Premultiplied RGBA for front bin f and back bin b.
  const std::array<float, 4>& at(std::uint32_t front, std::uint32_t back) const {
    return rgba_[std::size_t{back} * binCount_ + front];
  }
  // Row-major (back-major) RGBA, binCount^2 entries: ready for a 2D RGBA32F upload.
  const std::vector<std::array<float, 4>>& data() const { return rgba_; }

 private:
  double loValue_, hiValue_;
  std::uint32_t binCount_;
  double stepMm_;
  std::vector<std::array<float, 4>> rgba_;
};

}  // namespace octoray::transfer
