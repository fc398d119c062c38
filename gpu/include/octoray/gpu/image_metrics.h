#pragma once
// How far apart two images are, over the RGBA channels (depth is not compared). The error
// measures skip pixels where either image holds a NaN or an infinity in any channel; those
// are counted instead, since one is always a bug.

#include <cstdint>

#include "octoray/gpu/image.h"

namespace octoray::gpu {

struct ImageMetrics {
  double rmse = 0;          // root mean square error over channels of finite pixels
  double psnrDb = 0;        // 20 log10(1 / rmse) with a peak of 1.0; +inf for equal images
  double ssim = 1;          // mean SSIM of R, G, B, A (cv::quality::QualitySSIM, 8-bit range)
  double maxAbsError = 0;   // largest channel difference over finite pixels
  int64_t nonFiniteA = 0;   // pixels of `a` with a NaN or infinite channel
  int64_t nonFiniteB = 0;
  int64_t pixels = 0;
};

// Throws octoray::Error when the sizes differ.
ImageMetrics compare(const Image& a, const Image& b);

}  // namespace octoray::gpu
