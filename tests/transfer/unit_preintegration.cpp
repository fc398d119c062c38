// Opacity correction and pre-integration against analytic integrals.

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "octoray/transfer/preintegration.h"

namespace octoray::transfer {
namespace {

TransferFunction constant(float alpha, float r = 0.2f, float g = 0.4f, float b = 0.8f) {
  TransferFunction tf;
  tf.color = {{0, r, g, b}};
  tf.opacity = {{0, alpha}};
  tf.unitDistanceMm = 2.0;
  return tf;
}

TEST(AlphaCorrected, EdgeCasesStayFinite) {
  EXPECT_EQ(alphaCorrected(0, 1, 1), 0);
  EXPECT_EQ(alphaCorrected(1, 0.5, 1), 1);
  EXPECT_EQ(alphaCorrected(1, 1e-12, 1), 1);
  EXPECT_EQ(alphaCorrected(0.5, 0, 1), 0);
  EXPECT_EQ(alphaCorrected(1, 0, 1), 0);  // no path: no NaN from 0 * log(0)
  EXPECT_EQ(alphaCorrected(std::nan(""), 1, 1), 0);
  EXPECT_EQ(alphaCorrected(0.5, std::nan(""), 1), 0);
  EXPECT_DOUBLE_EQ(alphaCorrected(0.5, 1, 1), 0.5);
  EXPECT_DOUBLE_EQ(alphaCorrected(0.5, 2, 1), 0.75);
  // Tiny alpha: 1 - (1 - a)^r ~ r * a, which the naive pow form loses entirely.
  EXPECT_NEAR(alphaCorrected(1e-12, 0.5, 1), 0.5e-12, 1e-24);
  EXPECT_NEAR(alphaCorrected(0.3, 1e-9, 1), -std::log(0.7) * 1e-9, 1e-18);
  EXPECT_FALSE(std::isnan(alphaCorrected(1 - 1e-17, 1e6, 1)));
}

TEST(Preintegration, ConstantTfIsExact) {
  for (const float a : {0.0f, 1e-6f, 0.3f, 0.999f, 1.0f}) {
    const TransferFunction tf = constant(a);
    for (const double step : {0.0, 0.25, 1.0, 7.0}) {
      const auto rgba = integrateSegment(tf, -5, 5, step, 16);
      const double expected = 1 - std::pow(1 - double{a}, step / tf.unitDistanceMm);
      EXPECT_NEAR(rgba[3], expected, 1e-12) << a << " " << step;
      EXPECT_NEAR(rgba[0], 0.2f * expected, 1e-12);  // premultiplied
      EXPECT_NEAR(rgba[2], 0.8f * expected, 1e-12);
    }
  }
}

TEST(Preintegration, LinearAlphaRampMatchesTheIntegral) {
  // alpha(v) = k v on [0, 1]: integral of -ln(1 - k v) dv = ((w ln w - w) from 1 to 1-k) / k.
  const double k = 0.9;
  TransferFunction tf = constant(0);
  tf.unitDistanceMm = 1;
  tf.opacity = {{0, 0}, {1, static_cast<float>(k)}};
  const double kf = static_cast<float>(k);
  auto primitive = [&](double w) { return w * std::log(w) - w; };
  const double meanTau = (primitive(1 - kf) - primitive(1)) / kf;  // over v in [0, 1]
  for (const double step : {0.5, 3.0}) {
    const double expectedAlpha = 1 - std::exp(-step * meanTau);
    const auto rgba = integrateSegment(tf, 0, 1, step, 4096);
    EXPECT_NEAR(rgba[3], expectedAlpha, 1e-6) << step;
    EXPECT_NEAR(rgba[1], 0.4f * expectedAlpha, 1e-6);  // constant colour: C = c * alpha
    const auto reversed = integrateSegment(tf, 1, 0, step, 4096);
    EXPECT_NEAR(reversed[3], expectedAlpha, 1e-6);  // absorption ignores direction
  }
}

TEST(Preintegration, ColourRampIsWeightedTowardsTheFront) {
  // Opaque medium, colour from 0 (front) to 1 (back): most light comes from the front.
  TransferFunction tf = constant(0.9f);
  tf.color = {{0, 0, 0, 0}, {1, 1, 1, 1}};
  tf.unitDistanceMm = 1;
  const double tau = -std::log(1 - double{0.9f});
  const double d = 2;
  // C = integral_0^d (t/d) tau e^{-tau t} dt, closed form.
  const double expected = (1 - std::exp(-tau * d) * (1 + tau * d)) / (tau * d);
  const auto rgba = integrateSegment(tf, 0, 1, d, 4096);
  EXPECT_NEAR(rgba[0], expected, 1e-6);
}

TEST(Preintegration, TableDiagonalIsThePointValueCorrected) {
  TransferFunction tf = constant(0);
  tf.opacity = {{-100, 0}, {100, 0.8f}};
  tf.unitDistanceMm = 1;
  const PreintegrationTable table(tf, -100, 100, 17, 0.5, 8);
  for (std::uint32_t i = 0; i < table.binCount(); ++i) {
    const double alpha = alphaCorrected(tf.opacityAt(table.valueAt(i)), 0.5, 1);
    EXPECT_NEAR(table.at(i, i)[3], alpha, 1e-6) << i;
  }
  EXPECT_EQ(table.valueAt(0), -100);
  EXPECT_EQ(table.valueAt(16), 100);
  EXPECT_EQ(table.data().size(), 17u * 17u);
}


// The thin shell of the accuracy issue: opacity 0 -> 0.9 -> 0 over 680..720 HU, one colour.
TransferFunction thinShell() {
  TransferFunction tf;
  tf.color = {{0, 1.0f, 0.9f, 0.8f}};
  tf.opacity = {{680, 0.0f}, {700, 0.9f}, {720, 0.0f}};
  tf.unitDistanceMm = 1.0;
  return tf;
}

TEST(OpacitySupport, EndsWhereTheOpacityFallsToZero) {
  const auto [lo, hi] = opacitySupport(thinShell());
  EXPECT_EQ(lo, 680);
  EXPECT_EQ(hi, 720);
  const auto open = opacitySupport(constant(0.3f));
  EXPECT_TRUE(std::isinf(open.first) && open.first < 0);
  EXPECT_TRUE(std::isinf(open.second) && open.second > 0);
  const auto none = opacitySupport(constant(0.0f));
  EXPECT_GT(none.first, none.second);
}

// Opacity from the table's mean extinction equals the exact segment integral for every
// length (a property the per-level tables of the paper get by keeping one table per step);
// with one colour, the colour is exact too.
TEST(SegmentExtinctionTable, OpacityIsExactForAnyLength) {
  const TransferFunction tf = thinShell();
  const SegmentExtinctionTable table(tf, 680, 720, 161);  // bins every 0.25 HU
  ASSERT_EQ(table.data().size(), 161u * 161u);
  double worstAlpha = 0, worstColour = 0;
  for (const auto& [f, b] : {std::pair{0u, 160u}, std::pair{160u, 0u}, std::pair{40u, 41u},
                             std::pair{10u, 90u}, std::pair{80u, 80u}, std::pair{0u, 0u},
                             std::pair{100u, 160u}}) {
    for (const double length : {0.05, 0.5, 2.0, 8.0}) {
      const std::array<double, 4> exact =
          integrateSegment(tf, table.valueAt(f), table.valueAt(b), length, 20000);
      const std::array<float, 4>& e = table.at(f, b);
      const double alpha = 1.0 - std::exp(-e[3] * length / tf.unitDistanceMm);
      worstAlpha = std::max(worstAlpha, std::abs(alpha - exact[3]));
      const double colour = e[3] > 0 ? e[0] / e[3] * alpha : 0.0;
      worstColour = std::max(worstColour, std::abs(colour - exact[0]));
    }
  }
  EXPECT_LT(worstAlpha, 2e-4);
  EXPECT_LT(worstColour, 2e-4);
  // Symmetric in front and back, and nothing outside the support.
  EXPECT_FLOAT_EQ(table.at(10, 90)[3], table.at(90, 10)[3]);
  EXPECT_EQ(table.at(0, 0)[3], 0.0f);
  EXPECT_EQ(table.at(160, 160)[3], 0.0f);
}

// With a colour ramp the mean neglects the order inside the segment: the error shrinks as
// the segment's opacity does (short steps), which is where the raycaster uses it.
TEST(SegmentExtinctionTable, ColourOrderErrorShrinksWithTheSegmentOpacity) {
  TransferFunction tf;
  tf.color = {{0, 1, 0, 0}, {100, 0, 0, 1}};
  tf.opacity = {{0, 0.5f}};
  tf.unitDistanceMm = 1.0;
  const SegmentExtinctionTable table(tf, 0, 100, 101);
  double previous = 1;
  for (const double length : {4.0, 1.0, 0.25, 0.0625}) {
    const std::array<double, 4> exact = integrateSegment(tf, 0, 100, length, 20000);
    const std::array<float, 4>& e = table.at(0, 100);
    const double alpha = 1.0 - std::exp(-e[3] * length);
    EXPECT_NEAR(alpha, exact[3], 1e-5);
    const double error = std::abs(e[0] / e[3] * alpha - exact[0]);
    EXPECT_LT(error, previous) << "length " << length;
    previous = error;
  }
  EXPECT_LT(previous, 2e-3);
}

}  // namespace
}  // namespace octoray::transfer
