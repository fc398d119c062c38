#pragma once
// A rendered image: premultiplied linear RGBA as float, and per pixel the distance along the
// ray in mm of what the renderer chose to report (+inf where the ray met nothing). Row 0 is
// the top row; pixels are stored row by row, x fastest.

#include <cstddef>
#include <limits>
#include <vector>

namespace octoray::gpu {

struct Image {
  int width = 0;
  int height = 0;
  std::vector<float> rgba;   // 4 per pixel, premultiplied
  std::vector<float> depth;  // 1 per pixel, mm along the ray; +inf: nothing; may be empty
  bool hasAlpha = true;      // false for images read from files without alpha (alpha = 1)

  Image() = default;
  Image(int w, int h)
      : width(w),
        height(h),
        rgba(pixelCount() * 4, 0.0f),
        depth(pixelCount(), std::numeric_limits<float>::infinity()) {}

  std::size_t pixelCount() const {
    return static_cast<std::size_t>(width) * static_cast<std::size_t>(height);
  }
  std::size_t index(int x, int y) const {
    return static_cast<std::size_t>(y) * static_cast<std::size_t>(width) +
           static_cast<std::size_t>(x);
  }
  float* pixel(int x, int y) { return rgba.data() + 4 * index(x, y); }
  const float* pixel(int x, int y) const { return rgba.data() + 4 * index(x, y); }
};

}  // namespace octoray::gpu
