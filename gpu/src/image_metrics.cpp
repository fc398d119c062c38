#include "octoray/gpu/image_metrics.h"

#include <fmt/format.h>
#include <opencv2/core.hpp>
#include <opencv2/quality.hpp>

#include <algorithm>
#include <cmath>
#include <limits>

#include "octoray/core/error.h"

namespace octoray::gpu {
namespace {

bool finitePixel(const float* p) {
  return std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]) && std::isfinite(p[3]);
}

// The image on SSIM's 8-bit scale (its constants assume a range of 255); non-finite pixels
// of either image become 0 in both, so they do not count twice.
cv::Mat ssimInput(const Image& image, const std::vector<uint8_t>& valid) {
  cv::Mat m(image.height, image.width, CV_32FC3);
  for (int y = 0; y < image.height; ++y) {
    for (int x = 0; x < image.width; ++x) {
      const float* p = image.pixel(x, y);
      cv::Vec3f& out = m.at<cv::Vec3f>(y, x);
      for (int c = 0; c < 3; ++c) {
        out[c] = valid[image.index(x, y)] ? std::clamp(p[c], 0.0f, 1.0f) * 255.0f : 0.0f;
      }
    }
  }
  return m;
}

}  // namespace

ImageMetrics compare(const Image& a, const Image& b) {
  if (a.width != b.width || a.height != b.height) {
    throw Error("", fmt::format("images differ in size: {}x{} and {}x{}", a.width, a.height,
                                b.width, b.height));
  }
  ImageMetrics m;
  m.pixels = static_cast<int64_t>(a.pixelCount());
  if (m.pixels == 0) return m;
  m.alphaCompared = a.hasAlpha && b.hasAlpha;
  std::vector<uint8_t> valid(a.pixelCount(), 0);
  double sumSquares = 0;
  int64_t channels = 0;
  for (int y = 0; y < a.height; ++y) {
    for (int x = 0; x < a.width; ++x) {
      const float* pa = a.pixel(x, y);
      const float* pb = b.pixel(x, y);
      const bool fa = finitePixel(pa), fb = finitePixel(pb);
      m.nonFiniteA += fa ? 0 : 1;
      m.nonFiniteB += fb ? 0 : 1;
      if (!fa || !fb) continue;
      valid[a.index(x, y)] = 1;
      for (int c = 0; c < 3; ++c) {
        const double d = static_cast<double>(pa[c]) - static_cast<double>(pb[c]);
        sumSquares += d * d;
        m.maxAbsError = std::max(m.maxAbsError, std::abs(d));
      }
      channels += 3;
      if (m.alphaCompared) {
        m.maxAlphaError = std::max(
            m.maxAlphaError, std::abs(static_cast<double>(pa[3]) - static_cast<double>(pb[3])));
      }
    }
  }
  m.rmse = channels > 0 ? std::sqrt(sumSquares / static_cast<double>(channels)) : 0.0;
  m.psnrDb = m.rmse > 0 ? 20.0 * std::log10(1.0 / m.rmse) : std::numeric_limits<double>::infinity();
  const cv::Scalar ssim =
      cv::quality::QualitySSIM::compute(ssimInput(a, valid), ssimInput(b, valid), cv::noArray());
  m.ssim = (ssim[0] + ssim[1] + ssim[2]) / 3.0;
  return m;
}

}  // namespace octoray::gpu
