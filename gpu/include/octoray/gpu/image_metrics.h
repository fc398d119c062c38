#pragma once
// How far apart two images are. Colour measures use the premultiplied RGB channels, i.e. the
// images as seen over black (what a PNG holds, so PNG and EXR compare); alpha is compared
// separately when both images carry it; depth is not compared. The error measures skip
// pixels where either image holds a NaN or an infinity in any channel; those are counted
// instead, since one is always a bug.

#include <cstdint>

#include "octoray/gpu/image.h"

namespace octoray::gpu {

struct ImageMetrics {
  double rmse = 0;             // root mean square error over R, G, B of finite pixels
  double psnrDb = 0;           // 20 log10(1 / rmse) with a peak of 1.0; +inf for equal images
  double ssim = 1;             // mean SSIM of R, G, B (cv::quality::QualitySSIM, on 0..255 after
                               // clamping to [0, 1])
  double maxAbsError = 0;      // largest R, G or B difference over finite pixels
  bool alphaCompared = false;  // both images carry alpha
  double maxAlphaError = 0;    // largest alpha difference (when alphaCompared)
  int64_t nonFiniteA = 0;      // pixels of `a` with a NaN or infinite channel
  int64_t nonFiniteB = 0;
  int64_t pixels = 0;
};

// Throws octoray::Error when the sizes differ.
ImageMetrics compare(const Image& a, const Image& b);

}  // namespace octoray::gpu
