// TransferFunction evaluation, exact transparentOver, validation and window/level.

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

#include "octoray/core/error.h"
#include "octoray/transfer/transfer_function.h"

namespace octoray::transfer {
namespace {

TransferFunction ramp() {
  TransferFunction tf;
  tf.name = "ramp";
  tf.color = {{0, 0, 0, 0}, {100, 1, 0.5f, 0.25f}};
  tf.opacity = {{0, 0}, {100, 0}, {200, 1}, {300, 1}};
  return tf;
}

TEST(TransferFunction, InterpolatesLinearlyAndClampsEnds) {
  const TransferFunction tf = ramp();
  EXPECT_FLOAT_EQ(tf.opacityAt(150), 0.5f);
  EXPECT_FLOAT_EQ(tf.opacityAt(-1e9), 0.0f);
  EXPECT_FLOAT_EQ(tf.opacityAt(1e9), 1.0f);
  const auto rgba = tf.evaluate(50);
  EXPECT_FLOAT_EQ(rgba[0], 0.5f);
  EXPECT_FLOAT_EQ(rgba[1], 0.25f);
  EXPECT_FLOAT_EQ(rgba[2], 0.125f);
  EXPECT_FLOAT_EQ(rgba[3], 0.0f);
  EXPECT_EQ(tf.evaluate(std::nan(""))[3], 0.0f);
  EXPECT_FLOAT_EQ(tf.gradientOpacityAt(5), 1.0f);  // empty: 1 everywhere
}

TEST(TransferFunction, StepTakesTheLaterPoint) {
  TransferFunction tf = ramp();
  tf.opacity = {{10, 0}, {10, 0.5f}, {20, 0.5f}, {20, 1}};
  EXPECT_FLOAT_EQ(tf.opacityAt(9.999), 0.0f);
  EXPECT_FLOAT_EQ(tf.opacityAt(10), 0.5f);
  EXPECT_FLOAT_EQ(tf.opacityAt(15), 0.5f);
  EXPECT_FLOAT_EQ(tf.opacityAt(20), 1.0f);
}

TEST(TransferFunction, TransparentOverIsExact) {
  const TransferFunction tf = ramp();
  EXPECT_TRUE(tf.transparentOver(-1e9, 100));
  EXPECT_FALSE(tf.transparentOver(-1e9, std::nextafter(100.0, 200.0)));
  EXPECT_TRUE(tf.transparentOver(100, 100));
  EXPECT_FALSE(tf.transparentOver(150, 150));
  EXPECT_FALSE(tf.transparentOver(250, 1e9));
  EXPECT_TRUE(tf.transparentOver(100, 50));  // either order
  EXPECT_FALSE(tf.transparentOver(std::nan(""), 0));

  // A tiny opacity at one end of a long zero run is still seen.
  TransferFunction tiny = ramp();
  tiny.opacity = {{0, 0}, {1000, 0}, {1000.5, 1e-7f}, {2000, 0}};
  EXPECT_TRUE(tiny.transparentOver(0, 1000));
  EXPECT_FALSE(tiny.transparentOver(0, 1000.0001));
  EXPECT_FALSE(tiny.transparentOver(1999.9, 5000));
  EXPECT_TRUE(tiny.transparentOver(2000, 5000));
}

TEST(TransferFunction, TransparentOverAgreesWithDenseSampling) {
  std::mt19937 random(7);
  std::uniform_real_distribution<double> valueIn(-100, 100);
  for (int trial = 0; trial < 200; ++trial) {
    TransferFunction tf = ramp();
    tf.opacity.clear();
    double value = -80;
    for (int i = 0; i < 6; ++i) {
      value += std::uniform_real_distribution<double>(0, 30)(random);
      tf.opacity.push_back({std::round(value), random() % 3 == 0 ? 0.3f : 0.0f});
    }
    const double a = std::round(valueIn(random)), b = std::round(valueIn(random));
    bool anyOpaque = false;  // sampling at 1/8 steps hits every control point (integers)
    for (double v = std::min(a, b); v <= std::max(a, b); v += 0.125) anyOpaque |= tf.opacityAt(v) > 0;
    EXPECT_EQ(tf.transparentOver(a, b), !anyOpaque) << "trial " << trial;
  }
}

TEST(TransferFunction, ValidateRefusesMoreThanTheMaximumOfPoints) {
  TransferFunction tf = ramp();
  tf.opacity.assign(kMaxControlPoints, {0.0, 0.5f});
  EXPECT_NO_THROW(validate(tf, "big.json"));
  tf.opacity.push_back({0.0, 0.5f});
  try {
    validate(tf, "big.json");
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.path(), "big.json");
    EXPECT_NE(e.reason().find("more than the 1000000 allowed"), std::string::npos) << e.what();
  }
}

TEST(TransferFunction, ValidateNamesTheField) {
  TransferFunction tf = ramp();
  EXPECT_NO_THROW(validate(tf, "x.json"));
  tf.opacity[2].alpha = 1.5f;
  try {
    validate(tf, "x.json");
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.path(), "x.json");
    EXPECT_NE(e.reason().find("opacity[2]"), std::string::npos) << e.what();
    EXPECT_NE(e.reason().find("outside [0, 1]"), std::string::npos) << e.what();
  }
  tf = ramp();
  std::swap(tf.opacity[0], tf.opacity[3]);
  EXPECT_THROW(validate(tf), Error);
  tf = ramp();
  tf.color[1].value = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(validate(tf), Error);
  tf = ramp();
  tf.unitDistanceMm = 0;
  EXPECT_THROW(validate(tf), Error);
  tf = ramp();
  tf.opacity.clear();
  EXPECT_THROW(validate(tf), Error);
}

TEST(TransferFunction, WindowLevelMapsTheRampRange) {
  const TransferFunction tf = ramp();
  const ValueRange range = opacityRampRange(tf);
  EXPECT_EQ(range.lo, 100);
  EXPECT_EQ(range.hi, 200);
  const TransferFunction windowed = withWindowLevel(tf, 50, 1000);
  const ValueRange moved = opacityRampRange(windowed);
  EXPECT_DOUBLE_EQ(moved.lo, 975);
  EXPECT_DOUBLE_EQ(moved.hi, 1025);
  EXPECT_FLOAT_EQ(windowed.opacityAt(1000), 0.5f);
  EXPECT_DOUBLE_EQ(windowed.color[1].value, 1000 + (100 - 150) * 0.5);  // colour follows
  EXPECT_NO_THROW(validate(windowed));
  EXPECT_THROW(withWindowLevel(tf, 0, 0), Error);
  EXPECT_THROW(withWindowLevel(tf, 10, std::nan("")), Error);
}

}  // namespace
}  // namespace octoray::transfer
