// The opacity summed-area table never calls a visible interval empty, and is exact: it agrees
// with brute force over stored values and with TransferFunction::transparentOver.

#include <gtest/gtest.h>

#include <chrono>
#include <random>

#include "octoray/transfer/opacity_table.h"

namespace octoray::transfer {
namespace {

TransferFunction withOpacity(std::vector<OpacityPoint> points) {
  TransferFunction tf;
  tf.color = {{0, 1, 1, 1}};
  tf.opacity = std::move(points);
  return tf;
}

// Brute force over stored values: any stored value in [lo, hi] with non-zero opacity.
bool anyStoredOpaque(const TransferFunction& tf, double offset, double scale, int lo, int hi) {
  for (int s = lo; s <= hi; ++s) {
    if (tf.opacityAt(offset + scale * s) > 0) return true;
  }
  return false;
}

TEST(OpacityTable, TinyOpacitiesNextToLongZeroRunsAtBothEnds) {
  // Stored 0 and 65535 (physical -1024 and 64511) carry 1e-7; everything else is zero.
  const TransferFunction tf = withOpacity(
      {{-1024, 1e-7f}, {-1023, 0}, {64510, 0}, {64511, 1e-7f}});
  const OpacitySummedAreaTable table(tf, -1024, 1);
  EXPECT_FALSE(table.transparent(0, 0));
  EXPECT_FALSE(table.transparent(0, 1));
  EXPECT_TRUE(table.transparent(1, 1));
  EXPECT_TRUE(table.transparent(1, 65534));
  EXPECT_FALSE(table.transparent(65534, 65535));
  EXPECT_FALSE(table.transparent(65535, 65535));
  EXPECT_FALSE(table.transparent(0, 65535));
  EXPECT_FALSE(table.transparent(65535, 0));
}

TEST(OpacityTable, SpikeBetweenStoredValuesIsSeen) {
  // Non-zero only strictly between stored 100 and 101: interpolation can reach it.
  const TransferFunction tf = withOpacity({{100.25, 0}, {100.5, 1e-7f}, {100.75, 0}});
  const OpacitySummedAreaTable table(tf, 0, 1);
  EXPECT_TRUE(table.transparent(100, 100));
  EXPECT_TRUE(table.transparent(101, 101));
  EXPECT_FALSE(table.transparent(100, 101));
  EXPECT_TRUE(table.transparent(0, 100));
  EXPECT_TRUE(table.transparent(101, 65535));
}

TEST(OpacityTable, RandomTfsAgainstBruteForce) {
  std::mt19937 random(42);
  for (int trial = 0; trial < 8; ++trial) {
    const double scale = trial % 2 == 0 ? 1.0 : -0.5;
    const double offset = trial % 2 == 0 ? -1024.0 : 30000.0;
    std::vector<OpacityPoint> points;
    double value = -2000;
    std::uniform_real_distribution<double> gap(0, 9000);
    while (value < 66000) {
      value += gap(random);
      const float alpha = random() % 4 == 0 ? (random() % 2 ? 1e-7f : 0.5f) : 0.0f;
      points.push_back({std::round(value), alpha});
    }
    const TransferFunction tf = withOpacity(points);
    const OpacitySummedAreaTable table(tf, offset, scale);
    std::uniform_int_distribution<int> stored(0, 65535);
    for (int q = 0; q < 300; ++q) {
      int lo = stored(random), hi = stored(random);
      if (q % 3 == 0) hi = lo;
      if (q % 7 == 0) hi = std::min(65535, lo + static_cast<int>(random() % 5));
      if (lo > hi) std::swap(lo, hi);
      const bool empty = table.transparent(static_cast<uint16_t>(lo), static_cast<uint16_t>(hi));
      // Never a false "empty"; and exact against the continuous TF.
      if (anyStoredOpaque(tf, offset, scale, lo, hi)) {
        EXPECT_FALSE(empty) << trial << " [" << lo << ", " << hi << "]";
      }
      EXPECT_EQ(empty, tf.transparentOver(offset + scale * lo, offset + scale * hi))
          << trial << " [" << lo << ", " << hi << "]";
    }
    EXPECT_EQ(table.transparent(0, 65535), !anyStoredOpaque(tf, offset, scale, 0, 65535) &&
                                               tf.transparentOver(offset + scale * 65535, offset));
  }
}

// Many close points with steps (equal values) and zero runs: the table's O(log n) rule agrees
// with TransferFunction::transparentOver everywhere.
TEST(OpacityTable, DenseStepsAgainstTransparentOver) {
  std::mt19937 random(7);
  std::vector<OpacityPoint> points;
  double value = -1100;
  while (value < 3000) {
    value += static_cast<double>(random() % 6);  // 0: a step
    points.push_back({value, random() % 5 == 0 ? 0.25f : 0.0f});
  }
  const TransferFunction tf = withOpacity(points);
  const OpacitySummedAreaTable table(tf, -1024.0, 1.0);
  std::uniform_int_distribution<int> stored(0, 4500);
  for (int q = 0; q < 3000; ++q) {
    int lo = stored(random), hi = q % 2 ? lo + static_cast<int>(random() % 8) : stored(random);
    if (lo > hi) std::swap(lo, hi);
    EXPECT_EQ(table.transparent(static_cast<uint16_t>(lo), static_cast<uint16_t>(hi)),
              tf.transparentOver(lo - 1024.0, hi - 1024.0))
        << "[" << lo << ", " << hi << "]";
  }
}

// 10^6 control points (the documented maximum): the tables build in time linear in them (the
// old rule asked the whole function 2 x 65536 times; 10^5 points took 8.7 s on the GPU path).
TEST(OpacityTable, AMillionPointsBuildInLinearTime) {
  std::vector<OpacityPoint> points(1'000'000);
  for (std::size_t i = 0; i < points.size(); ++i) {
    points[i] = {-1024.0 + 0.065 * static_cast<double>(i), i % 3 == 0 ? 0.5f : 0.0f};
  }
  const TransferFunction tf = withOpacity(points);
  const auto start = std::chrono::steady_clock::now();
  const OpacitySummedAreaTable stored(tf, -1024.0, 1.0);
  const auto floats = OpacitySummedAreaTable::overRange(tf, -1024.0, 64000.0, 65536);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  EXPECT_LT(seconds, 10.0) << "a hang guard, not a benchmark";
  EXPECT_FALSE(stored.transparent(0, 65535));
  EXPECT_FALSE(floats.transparentValues(0, 10));
}

TEST(OpacityTable, FloatRangeIsSound) {
  const TransferFunction tf = withOpacity({{0.0, 0}, {0.3, 0}, {0.31, 1e-7f}, {0.32, 0}});
  const auto table = OpacitySummedAreaTable::overRange(tf, -1, 1, 256);
  EXPECT_TRUE(table.transparentValues(-1, 0.25));
  EXPECT_FALSE(table.transparentValues(0.305, 0.306));  // inside one bin
  EXPECT_FALSE(table.transparentValues(-5, 5));
  EXPECT_TRUE(table.transparentValues(0.5, 5));
  EXPECT_TRUE(table.transparentValues(-5, -2));  // clamped end, transparent
  std::mt19937 random(3);
  std::uniform_real_distribution<double> valueIn(-1.5, 1.5);
  for (int q = 0; q < 2000; ++q) {
    const double a = valueIn(random), b = valueIn(random);
    if (!tf.transparentOver(a, b)) {
      EXPECT_FALSE(table.transparentValues(a, b)) << a << " " << b;
    }
  }
}

}  // namespace
}  // namespace octoray::transfer
