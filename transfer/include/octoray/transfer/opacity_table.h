#pragma once
// Summed-area table of "is the opacity non-zero" over the stored value domain, for the
// working set's emptiness test (paper §4, DESIGN "Working set"): a brick whose stored
// [min, max] is transparent is skipped. The test must never call a visible brick empty, so the
// table counts, in integers, the gaps between consecutive stored values over which the TF has
// any non-zero opacity (TransferFunction::transparentOver, exact from the control points).
// Because the renderer interpolates between samples, a gap counts even when the non-zero
// opacity lies strictly between two stored values.

#include <cstdint>
#include <vector>

#include "octoray/transfer/transfer_function.h"

namespace octoray::transfer {

class OpacitySummedAreaTable {
 public:
  // Over all 65536 16-bit stored values s, with physical = valueOffset + valueScale * s
  // (CT stores: offset -1024, scale 1). valueScale must be finite and non-zero.
  OpacitySummedAreaTable(const TransferFunction& tf, double valueOffset, double valueScale);

  // Over float data: [loValue, hiValue] cut into binCount equal bins (binCount >= 1,
  // loValue < hiValue); values outside the range are covered by two extra flags.
  static OpacitySummedAreaTable overRange(const TransferFunction& tf, double loValue,
                                          double hiValue, std::uint32_t binCount);

  // True only when the TF is exactly zero for every value between stored lo and hi
  // (inclusive, either order), interpolated values included.
  bool transparent(std::uint16_t lo, std::uint16_t hi) const;
  // Float data (overRange tables): sound, possibly conservative at bin granularity.
  bool transparentValues(double lo, double hi) const;

  // Number of opaque gaps among [lo, hi) of stored values; for tests and diagnostics.
  std::uint32_t opaqueGapCount(std::uint32_t lo, std::uint32_t hi) const {
    return gapPrefix_[hi] - gapPrefix_[lo];
  }

 private:
  OpacitySummedAreaTable() = default;

  // Stored/bin positions: gap i spans positions i..i+1; gapPrefix_[i] = opaque gaps below i.
  std::vector<std::uint32_t> gapPrefix_;
  std::vector<std::uint8_t> pointOpaque_;  // per position: opacity non-zero at that value
  // Float tables only: position p has value rangeLo_ + p * binWidth_.
  double rangeLo_ = 0, binWidth_ = 1;
  bool belowOpaque_ = true, aboveOpaque_ = true;
};

}  // namespace octoray::transfer
