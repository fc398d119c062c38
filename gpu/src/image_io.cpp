#include "octoray/gpu/image_io.h"

#include <ImfChannelList.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfInputFile.h>
#include <ImfOutputFile.h>
#include <fmt/format.h>
#include <unistd.h>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "octoray/core/error.h"

namespace octoray::gpu {
namespace {

void checkImage(const Image& image, const std::filesystem::path& path) {
  if (image.width < 1 || image.height < 1 || image.rgba.size() != image.pixelCount() * 4 ||
      (!image.depth.empty() && image.depth.size() != image.pixelCount())) {
    throw Error(path.string(), "cannot write an empty or inconsistent image");
  }
}

uint8_t encode8(float value, PngEncoding encoding) {
  double v = std::isnan(value) ? 0.0 : std::clamp(static_cast<double>(value), 0.0, 1.0);
  if (encoding == PngEncoding::Srgb) {
    v = v <= 0.0031308 ? 12.92 * v : 1.055 * std::pow(v, 1.0 / 2.4) - 0.055;
  }
  return static_cast<uint8_t>(std::lround(v * 255.0));
}

// Writes through a temporary name renamed on success, so no partial file is ever left.
void replaceWith(const std::filesystem::path& temporary, const std::filesystem::path& path) {
  std::error_code ec;
  std::filesystem::rename(temporary, path, ec);
  if (ec) {
    std::filesystem::remove(temporary, ec);
    throw Error(path.string(), "cannot rename the finished file into place");
  }
}

// A hidden temporary beside the target, named as the store's: .NAME.partial-PID.
std::filesystem::path temporaryName(const std::filesystem::path& path) {
  return path.parent_path() /
         fmt::format(".{}.partial-{}", path.filename().string(), static_cast<long>(::getpid()));
}

Image readPng(const std::filesystem::path& path) {
  const cv::Mat m = cv::imread(path.string(), cv::IMREAD_UNCHANGED);
  if (m.empty()) throw Error(path.string(), "cannot decode the PNG file");
  const double scale = m.depth() == CV_16U ? 1.0 / 65535.0 : 1.0 / 255.0;
  if (m.depth() != CV_8U && m.depth() != CV_16U) {
    throw Error(path.string(), "PNG of an unsupported sample depth");
  }
  Image image(m.cols, m.rows);
  image.depth.clear();
  const int channels = m.channels();
  image.hasAlpha = channels == 2 || channels == 4;
  for (int y = 0; y < m.rows; ++y) {
    for (int x = 0; x < m.cols; ++x) {
      std::array<double, 4> stored{0, 0, 0, 1 / scale};
      for (int c = 0; c < channels; ++c) {
        stored[static_cast<std::size_t>(c)] = m.depth() == CV_8U
                                                  ? m.ptr<uint8_t>(y)[x * channels + c]
                                                  : m.ptr<uint16_t>(y)[x * channels + c];
      }
      float* p = image.pixel(x, y);
      if (channels <= 2) {  // grey (+ alpha)
        const double a = channels == 2 ? stored[1] : 1 / scale;
        p[0] = p[1] = p[2] = static_cast<float>(stored[0] * scale);
        p[3] = static_cast<float>(a * scale);
      } else {  // OpenCV keeps BGR(A)
        p[0] = static_cast<float>(stored[2] * scale);
        p[1] = static_cast<float>(stored[1] * scale);
        p[2] = static_cast<float>(stored[0] * scale);
        p[3] = static_cast<float>(stored[3] * scale);
      }
    }
  }
  return image;
}

Image readExr(const std::filesystem::path& path) {
  Imf::InputFile file(path.c_str());
  const Imath::Box2i window = file.header().dataWindow();
  const int64_t w = int64_t{window.max.x} - window.min.x + 1;
  const int64_t h = int64_t{window.max.y} - window.min.y + 1;
  if (w < 1 || h < 1 || w > 65536 || h > 65536) {
    throw Error(path.string(), fmt::format("EXR data window {}x{} out of range", w, h));
  }
  Image image(static_cast<int>(w), static_cast<int>(h));
  const bool hasDepth = file.header().channels().findChannel("Z") != nullptr;
  // OpenEXR addresses pixels by absolute coordinates: shift the base to the data window.
  const std::ptrdiff_t shift =
      -(static_cast<std::ptrdiff_t>(window.min.x) + static_cast<std::ptrdiff_t>(window.min.y) * w);
  Imf::FrameBuffer frame;
  const std::array<const char*, 4> names{"R", "G", "B", "A"};
  for (std::size_t c = 0; c < 4; ++c) {
    char* base = reinterpret_cast<char*>(image.rgba.data() + c) + shift * 4 * sizeof(float);
    frame.insert(names[c], Imf::Slice(Imf::FLOAT, base, 4 * sizeof(float), 4 * sizeof(float) * w, 1,
                                      1, c == 3 ? 1.0 : 0.0));
  }
  if (hasDepth) {
    char* base = reinterpret_cast<char*>(image.depth.data()) + shift * sizeof(float);
    frame.insert("Z", Imf::Slice(Imf::FLOAT, base, sizeof(float), sizeof(float) * w));
  } else {
    image.depth.clear();
  }
  file.setFrameBuffer(frame);
  file.readPixels(window.min.y, window.max.y);
  return image;
}

}  // namespace

namespace {

// Writes the PNG of `image` to `temporary` (messages name `path`).
void writePngTo(const Image& image, const std::filesystem::path& path,
                const std::filesystem::path& temporary, PngEncoding encoding) {
  checkImage(image, path);
  cv::Mat bgr(image.height, image.width, CV_8UC3);
  for (int y = 0; y < image.height; ++y) {
    for (int x = 0; x < image.width; ++x) {
      const float* p = image.pixel(x, y);
      cv::Vec3b& out = bgr.at<cv::Vec3b>(y, x);
      out[0] = encode8(p[2], encoding);
      out[1] = encode8(p[1], encoding);
      out[2] = encode8(p[0], encoding);
    }
  }
  std::vector<uint8_t> bytes;
  if (!cv::imencode(".png", bgr, bytes)) throw Error(path.string(), "PNG encoding failed");
  std::ofstream out(temporary, std::ios::binary);
  out.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
  out.close();
  if (!out) {
    std::error_code ec;
    std::filesystem::remove(temporary, ec);
    throw Error(path.string(), "cannot write the PNG file (missing folder, no permission or disk full?)");
  }
}

// Writes the EXR of `image` to `temporary` (messages name `path`).
void writeExrTo(const Image& image, const std::filesystem::path& path,
                const std::filesystem::path& temporary) {
  checkImage(image, path);
  try {
    Imf::Header header(image.width, image.height);
    header.compression() = Imf::ZIP_COMPRESSION;
    Imf::FrameBuffer frame;
    const std::array<const char*, 4> names{"R", "G", "B", "A"};
    for (std::size_t c = 0; c < 4; ++c) {
      header.channels().insert(names[c], Imf::Channel(Imf::FLOAT));
      frame.insert(
          names[c],
          Imf::Slice(Imf::FLOAT,
                     const_cast<char*>(reinterpret_cast<const char*>(image.rgba.data() + c)),
                     4 * sizeof(float), 4 * sizeof(float) * image.width));
    }
    std::vector<float> depth = image.depth;
    if (depth.empty()) depth.assign(image.pixelCount(), std::numeric_limits<float>::infinity());
    header.channels().insert("Z", Imf::Channel(Imf::FLOAT));
    frame.insert("Z", Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(depth.data()), sizeof(float),
                                 sizeof(float) * image.width));
    Imf::OutputFile file(temporary.c_str(), header);
    file.setFrameBuffer(frame);
    file.writePixels(image.height);
  } catch (const std::exception& e) {
    std::error_code ec;
    std::filesystem::remove(temporary, ec);
    throw Error(path.string(), fmt::format("cannot write the EXR file: {}", e.what()));
  }
}

}  // namespace

void writePng(const Image& image, const std::filesystem::path& path, PngEncoding encoding) {
  const std::filesystem::path temporary = temporaryName(path);
  writePngTo(image, path, temporary, encoding);
  replaceWith(temporary, path);
}

void writeExr(const Image& image, const std::filesystem::path& path) {
  const std::filesystem::path temporary = temporaryName(path);
  writeExrTo(image, path, temporary);
  replaceWith(temporary, path);
}

void writeImageOutputs(const Image& image, const ImageOutputs& outputs) {
  const std::filesystem::path pngTemporary = temporaryName(outputs.png);
  const std::filesystem::path exrTemporary =
      outputs.exr.empty() ? std::filesystem::path() : temporaryName(outputs.exr);
  auto removeTemporaries = [&] {
    std::error_code ec;
    std::filesystem::remove(pngTemporary, ec);
    if (!exrTemporary.empty()) std::filesystem::remove(exrTemporary, ec);
  };
  try {
    writePngTo(image, outputs.png, pngTemporary, outputs.encoding);
    if (!outputs.exr.empty()) writeExrTo(image, outputs.exr, exrTemporary);
  } catch (...) {
    removeTemporaries();
    throw;
  }
  // Both complete: into place. Should the second rename fail, the first output is taken
  // back, so the command leaves both or neither.
  std::error_code ec;
  std::filesystem::rename(pngTemporary, outputs.png, ec);
  if (ec) {
    removeTemporaries();
    throw Error(outputs.png.string(), "cannot rename the finished file into place: " + ec.message());
  }
  if (!exrTemporary.empty()) {
    std::filesystem::rename(exrTemporary, outputs.exr, ec);
    if (ec) {
      removeTemporaries();
      std::error_code ignored;
      std::filesystem::remove(outputs.png, ignored);
      throw Error(outputs.exr.string(), "cannot rename the finished file into place: " + ec.message());
    }
  }
}

Image readImage(const std::filesystem::path& path) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) throw Error(path.string(), "is a folder, not an image file");
  std::array<unsigned char, 8> magic{};
  {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw Error(path.string(), "cannot open the image file");
    in.read(reinterpret_cast<char*>(magic.data()), magic.size());
    if (in.gcount() < 4) throw Error(path.string(), "too short to be an image file");
  }
  if (magic[0] == 0x89 && magic[1] == 'P' && magic[2] == 'N' && magic[3] == 'G') {
    return readPng(path);
  }
  if (magic[0] == 0x76 && magic[1] == 0x2f && magic[2] == 0x31 && magic[3] == 0x01) {
    try {
      return readExr(path);
    } catch (const Error&) {
      throw;
    } catch (const std::exception& e) {
      throw Error(path.string(), fmt::format("cannot read the EXR file: {}", e.what()));
    }
  }
  throw Error(path.string(), "not a PNG or OpenEXR file");
}

}  // namespace octoray::gpu
