#pragma once
// Image files. PNG (8-bit, through OpenCV) for looking at and for documents; OpenEXR (float
// R G B A Z, through OpenEXR) for exact comparison. Both write to a hidden temporary name
// (.NAME.partial-PID) and rename it when complete. Read errors throw octoray::Error naming the file.
//
// PNG: the premultiplied colour is the colour over a black background, so it is written as
// RGB (no alpha channel). Encoding: by default each channel is clamped to [0, 1] and scaled
// to 0..255 with rounding, as VTK, Slicer and an 8-bit GL framebuffer do with transfer
// function colours (presets are tuned as display values); PngEncoding::Srgb applies the sRGB
// transfer curve first, for colours meant as linear light.
// EXR: channels R G B A (premultiplied, the EXR convention) and Z (the depth, +inf where
// nothing was hit), all 32-bit float, ZIP compressed.

#include <filesystem>

#include "octoray/gpu/image.h"

namespace octoray::gpu {

enum class PngEncoding { Clamp, Srgb };

void writePng(const Image& image, const std::filesystem::path& path,
              PngEncoding encoding = PngEncoding::Clamp);
void writeExr(const Image& image, const std::filesystem::path& path);

// A command's image outputs: the PNG and, when named, the EXR of the same picture.
struct ImageOutputs {
  std::filesystem::path png;
  PngEncoding encoding = PngEncoding::Clamp;
  std::filesystem::path exr;  // empty: none
};
// Writes both to hidden temporaries beside their targets (.NAME.partial-PID) and renames them
// only when both are complete: a failure (a missing folder, a full disk) leaves neither.
void writeImageOutputs(const Image& image, const ImageOutputs& outputs);

// Reads a PNG (8 or 16 bit; grey, RGB or RGBA) as float in [0, 1] with the values as stored (no
// decoding of sRGB), alpha 1 where the file has none, and no depth; or an EXR's R G B A
// (missing channels: colour 0, alpha 1) and Z when present. The format comes from the
// file's first bytes.
Image readImage(const std::filesystem::path& path);

}  // namespace octoray::gpu
