// The defaults a tool picks when the user gives none (defaults.h). The transfer functions
// themselves are checked through octoray-render (tests/gpu/unit_render_tools.cpp); here the
// automatic isovalue against an independent implementation, OpenCV's.
#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "octoray/transfer/defaults.h"

namespace octoray::transfer {
namespace {

// The isovalue of a volume without HU: Otsu's threshold of its histogram, checked against
// OpenCV's THRESH_OTSU on an 8-bit image whose pixels are the samples' bin numbers: its
// threshold t puts bins 0..t below, so the isovalue splits the samples into the same two
// classes, at the upper edge of bin t or, where empty bins follow it, in the middle of them.
TEST(TransferDefaults, AutomaticIsoValueIsOtsusThresholdOfTheValues) {
  const double lo = -12.5, hi = 3827.5;  // an MR's range; 256 bins of 15 units
  std::mt19937 rng(2026);
  struct Mix {
    double background, object, spread;  // two normal classes, in bins
    double objectShare;
  };
  for (const Mix mix : {Mix{12, 140, 18, 0.35}, Mix{30, 90, 10, 0.6}, Mix{5, 220, 25, 0.1},
                        Mix{100, 130, 20, 0.5}}) {
    std::normal_distribution<double> background(mix.background, mix.spread), object(mix.object, mix.spread);
    std::bernoulli_distribution isObject(mix.objectShare);
    cv::Mat bins(200, 300, CV_8UC1);
    std::vector<int> histogram(256, 0);
    for (int r = 0; r < bins.rows; ++r) {
      for (int c = 0; c < bins.cols; ++c) {
        const double b = isObject(rng) ? object(rng) : background(rng);
        const int bin = std::clamp(static_cast<int>(std::lround(b)), 0, 255);
        bins.at<uint8_t>(r, c) = static_cast<uint8_t>(bin);
        ++histogram[static_cast<std::size_t>(bin)];
      }
    }
    cv::Mat unused;
    const auto t = static_cast<std::size_t>(cv::threshold(bins, unused, 0, 255, cv::THRESH_BINARY | cv::THRESH_OTSU));
    const double iso = automaticIsoValue(histogram, lo, hi);
    std::size_t gap = t + 1;  // the empty bins after t
    while (gap < 256 && histogram[gap] == 0) ++gap;
    EXPECT_NEAR(iso, lo + (0.5 * static_cast<double>(t + gap - 1) + 1) * (hi - lo) / 256, 1e-9)
        << "classes at bins " << mix.background << " and " << mix.object << ", OpenCV's threshold " << t;
    // Between the two classes' means (well apart for the first three).
    if (mix.object - mix.background > 3 * mix.spread) {
      EXPECT_GT(iso, lo + mix.background * 15);
      EXPECT_LT(iso, lo + mix.object * 15);
    }
  }
  // A 0/1 mask: the middle of the gap between its two values, 0.5, not just above 0.
  std::vector<int> mask(256, 0);
  mask[0] = 9000;
  mask[255] = 1000;
  EXPECT_DOUBLE_EQ(automaticIsoValue(mask, 0, 1), 0.5);
  // Nothing to split: the middle of the range.
  std::vector<int> one(256, 0);
  one[40] = 5000;
  EXPECT_EQ(automaticIsoValue(one, 0, 256), 128);
  EXPECT_EQ(automaticIsoValue(std::vector<int>(256, 0), 0, 256), 128);
  EXPECT_EQ(automaticIsoValue({}, 0, 1), 0.5);
}

}  // namespace
}  // namespace octoray::transfer
