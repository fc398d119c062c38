#include "octoray/transfer/opacity_table.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "octoray/core/error.h"

namespace octoray::transfer {
namespace {

// TransferFunction::transparentOver in O(log n) per question after O(n) set-up: the same rule
// (a control point in [lo, hi] with opacity, or a segment whose open interior meets [lo, hi]
// with an end that has opacity, or a clamped end with opacity outside the points), answered
// from prefix counts over the sorted points. The tables ask 2 x 65536 questions; with the
// O(n) rule a function of 10^5 points took seconds.
class TransparencyQuery {
 public:
  explicit TransparencyQuery(const TransferFunction& tf) : points_(tf.opacity) {
    const std::size_t n = points_.size();
    opaquePoints_.assign(n + 1, 0);
    opaqueSegments_.assign(n + 1, 0);
    for (std::size_t i = 0; i < n; ++i) {
      opaquePoints_[i + 1] = opaquePoints_[i] + (points_[i].alpha != 0.0f ? 1 : 0);
      const bool segment = i + 1 < n && points_[i].value < points_[i + 1].value &&
                           (points_[i].alpha != 0.0f || points_[i + 1].alpha != 0.0f);
      opaqueSegments_[i + 1] = opaqueSegments_[i] + (segment ? 1 : 0);
    }
  }

  bool transparentOver(double lo, double hi) const {
    if (points_.empty()) return true;
    if (std::isnan(lo) || std::isnan(hi)) return false;
    if (lo > hi) std::swap(lo, hi);
    if (lo < points_.front().value && points_.front().alpha != 0.0f) return false;
    if (hi > points_.back().value && points_.back().alpha != 0.0f) return false;
    auto below = [](const OpacityPoint& p, double v) { return p.value < v; };
    auto above = [](double v, const OpacityPoint& p) { return v < p.value; };
    // Points with value in [lo, hi].
    const auto first = static_cast<std::size_t>(std::lower_bound(points_.begin(), points_.end(), lo, below) - points_.begin());
    const auto last = static_cast<std::size_t>(std::upper_bound(points_.begin(), points_.end(), hi, above) - points_.begin());
    if (last > first && opaquePoints_[last] != opaquePoints_[first]) return false;
    // Segments j (points j, j+1) with lo < value[j+1] and value[j] < hi.
    const std::size_t afterLo = static_cast<std::size_t>(std::upper_bound(points_.begin(), points_.end(), lo, above) - points_.begin());
    const std::size_t segmentBegin = afterLo == 0 ? 0 : afterLo - 1;
    const std::size_t beforeHi = static_cast<std::size_t>(std::lower_bound(points_.begin(), points_.end(), hi, below) - points_.begin());
    const std::size_t segmentEnd = std::min(beforeHi, points_.size() - 1);
    if (segmentEnd > segmentBegin && opaqueSegments_[segmentEnd] != opaqueSegments_[segmentBegin]) return false;
    return true;
  }

 private:
  const std::vector<OpacityPoint>& points_;
  std::vector<std::uint32_t> opaquePoints_;    // [i]: points below i with opacity
  std::vector<std::uint32_t> opaqueSegments_;  // [i]: segments below i with an opaque end
};

// Fills the flags and prefix counts for positions 0..count-1 with value(p).
template <typename ValueAt>
void fillTable(const TransferFunction& tf, std::size_t count, ValueAt valueAt,
               std::vector<std::uint32_t>& gapPrefix, std::vector<std::uint8_t>& pointOpaque) {
  const TransparencyQuery query(tf);
  pointOpaque.resize(count);
  gapPrefix.assign(count, 0);  // gaps 0..count-2, prefix has count entries
  double previous = valueAt(0);
  pointOpaque[0] = query.transparentOver(previous, previous) ? 0 : 1;
  for (std::size_t p = 1; p < count; ++p) {
    const double value = valueAt(p);
    pointOpaque[p] = query.transparentOver(value, value) ? 0 : 1;
    const bool gapOpaque = !query.transparentOver(previous, value);
    gapPrefix[p] = gapPrefix[p - 1] + (gapOpaque ? 1u : 0u);
    previous = value;
  }
}

}  // namespace

OpacitySummedAreaTable::OpacitySummedAreaTable(const TransferFunction& tf, double valueOffset,
                                               double valueScale) {
  if (!std::isfinite(valueOffset) || !std::isfinite(valueScale) || valueScale == 0) {
    throw Error("", fmt::format("stored-to-physical mapping offset {} scale {} is not usable",
                                valueOffset, valueScale));
  }
  fillTable(
      tf, 65536, [&](std::size_t s) { return valueOffset + valueScale * static_cast<double>(s); },
      gapPrefix_, pointOpaque_);
}

OpacitySummedAreaTable OpacitySummedAreaTable::overRange(const TransferFunction& tf,
                                                         double loValue, double hiValue,
                                                         std::uint32_t binCount) {
  if (!(std::isfinite(loValue) && std::isfinite(hiValue) && loValue < hiValue) || binCount == 0 ||
      binCount == std::numeric_limits<std::uint32_t>::max()) {
    throw Error("", fmt::format("opacity table range [{}, {}] with {} bins is not usable", loValue,
                                hiValue, binCount));
  }
  OpacitySummedAreaTable table;
  table.rangeLo_ = loValue;
  table.binWidth_ = (hiValue - loValue) / binCount;
  // The last position is hiValue itself, not lo + n * width, so no rounding gap is left.
  auto valueAt = [&](std::size_t p) {
    return p == binCount ? hiValue : loValue + table.binWidth_ * static_cast<double>(p);
  };
  fillTable(tf, std::size_t{binCount} + 1, valueAt, table.gapPrefix_, table.pointOpaque_);
  const double inf = std::numeric_limits<double>::infinity();
  table.belowOpaque_ = !tf.transparentOver(-inf, loValue);
  table.aboveOpaque_ = !tf.transparentOver(hiValue, inf);
  return table;
}

bool OpacitySummedAreaTable::transparent(std::uint16_t lo, std::uint16_t hi) const {
  if (lo > hi) std::swap(lo, hi);
  if (hi >= pointOpaque_.size()) return false;  // a float table asked about stored values
  if (lo == hi) return pointOpaque_[lo] == 0;
  return gapPrefix_[hi] == gapPrefix_[lo];
}

bool OpacitySummedAreaTable::transparentValues(double lo, double hi) const {
  if (std::isnan(lo) || std::isnan(hi)) return false;
  if (lo > hi) std::swap(lo, hi);
  const std::size_t lastPosition = pointOpaque_.size() - 1;
  const double hiValue = rangeLo_ + binWidth_ * static_cast<double>(lastPosition);
  if (lo < rangeLo_ && belowOpaque_) return false;
  if (hi > hiValue && aboveOpaque_) return false;
  if (hi < rangeLo_ || lo > hiValue) return true;  // wholly in a transparent clamped end
  // Positions bracketing [lo, hi], widened by one each way so that rounding in the division
  // can only make the answer more conservative.
  auto clampPosition = [&](double position) {
    return static_cast<std::size_t>(std::clamp(position, 0.0, static_cast<double>(lastPosition)));
  };
  const std::size_t first = clampPosition(std::floor((lo - rangeLo_) / binWidth_) - 1);
  const std::size_t last = clampPosition(std::ceil((hi - rangeLo_) / binWidth_) + 1);
  return gapPrefix_[last] == gapPrefix_[first];
}

}  // namespace octoray::transfer
