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
#include <utility>
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

// The value interval [lo, hi] outside which `tf` has no opacity: alpha is 0 for every value
// below lo and above hi. -inf (+inf) where the opacity does not fall to 0 below the first
// (above the last) point; lo > hi when the TF has no opacity anywhere.
std::pair<double, double> opacitySupport(const TransferFunction& tf);

// Pre-integration for segments of any length: what the GPU raycaster samples (paper 003
// §5.3, with the segment length taken out of the table). Entry (f, b) holds, for a segment
// along which the value runs linearly from value(f) to value(b):
//   a   = the mean extinction -ln(1 - alpha(v)) over [value(f), value(b)] (per unitDistanceMm)
//   rgb = the mean of colour(v) * extinction(v) over the same values
// so a segment of length L has opacity 1 - exp(-a L / unitDistanceMm), exact for every L
// (one table serves every octree level's step; the paper keeps one per level because its
// entries hold opacities), and colour rgb / a times that opacity, exact where the colour is
// constant across the segment (the order of colours inside one segment is neglected;
// integrateSegment keeps it, and the two agree as the step shrinks). Both channels are
// averages of extinction-weighted quantities, so bilinear filtering between entries is
// consistent. The means come from running integrals over a grid 16 times finer than the
// bins (trapezoid rule, double precision); alpha >= 1 counts as extinction 1e4 (the GPU's
// 1D table's convention).
class SegmentExtinctionTable {
 public:
  SegmentExtinctionTable(const TransferFunction& tf, double loValue, double hiValue,
                         std::uint32_t binCount = 256);

  std::uint32_t binCount() const { return binCount_; }
  double loValue() const { return loValue_; }
  double hiValue() const { return hiValue_; }
  double valueAt(std::uint32_t bin) const;
  const std::array<float, 4>& at(std::uint32_t front, std::uint32_t back) const {
    return entries_[std::size_t{back} * binCount_ + front];
  }
  // Back-major RGBA, binCount^2 entries: ready for a 2D RGBA32F upload (front along x).
  const std::vector<std::array<float, 4>>& data() const { return entries_; }

 private:
  double loValue_, hiValue_;
  std::uint32_t binCount_;
  std::vector<std::array<float, 4>> entries_;
};

}  // namespace octoray::transfer
