#include "octoray/gpu/image_io.h"

#include <ImfChannelList.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfInputFile.h>
#include <ImfOutputFile.h>
#include <fmt/format.h>
#include <png.h>
#include <unistd.h>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <csetjmp>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iterator>
#include <memory>
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

// libpng reports an error by calling onPngError, which must not return: the message is kept
// for ours and png_longjmp leaves the read. Warnings are not printed either; the first is kept,
// since it may say why an error follows ("Image width exceeds user limit in IHDR", then
// "Invalid IHDR data").
struct PngMessages {
  char error[256] = "";
  char warning[256] = "";
};
void onPngError(png_structp png, png_const_charp message) {
  auto* kept = static_cast<PngMessages*>(png_get_error_ptr(png));
  std::snprintf(kept->error, sizeof kept->error, "%s", message);
  png_longjmp(png, 1);
}
void onPngWarning(png_structp png, png_const_charp message) {
  auto* kept = static_cast<PngMessages*>(png_get_error_ptr(png));
  if (kept->warning[0] == '\0') std::snprintf(kept->warning, sizeof kept->warning, "%s", message);
}
// libpng's own file reader says only "Read Error" when the file ends.
void readPngBytes(png_structp png, png_bytep data, png_size_t length) {
  auto* file = static_cast<std::FILE*>(png_get_io_ptr(png));
  if (std::fread(data, 1, length, file) != length) {
    png_error(png, std::ferror(file) != 0 ? "the file cannot be read" : "the file ends early");
  }
}

// What a PNG holds once libpng's transforms (below) are set.
struct PngLayout {
  uint32_t width = 0, height = 0;
  int channels = 0, bitDepth = 0;
  std::size_t rowBytes = 0;
};

// The two steps that may longjmp out of libpng. Between setjmp and a longjmp they own nothing
// with a destructor, which a longjmp would skip.
bool readPngHeader(png_structp png, png_infop info, std::FILE* file, PngLayout& layout) {
  if (setjmp(png_jmpbuf(png))) return false;
  png_set_read_fn(png, file, readPngBytes);
  png_set_user_limits(png, 65536, 65536);  // as the EXR reader's data-window limit
  png_read_info(png, info);
  png_set_expand(png);  // palette to RGB, grey below 8 bits to 8, tRNS to an alpha channel
  if constexpr (std::endian::native == std::endian::little) {
    if (png_get_bit_depth(png, info) == 16) png_set_swap(png);  // PNG stores big-endian
  }
  png_set_interlace_handling(png);
  png_read_update_info(png, info);
  layout.width = png_get_image_width(png, info);
  layout.height = png_get_image_height(png, info);
  layout.channels = png_get_channels(png, info);
  layout.bitDepth = png_get_bit_depth(png, info);
  layout.rowBytes = png_get_rowbytes(png, info);
  return true;
}
bool readPngRows(png_structp png, png_infop info, png_bytepp rows) {
  if (setjmp(png_jmpbuf(png))) return false;
  png_read_image(png, rows);
  png_read_end(png, info);  // to IEND: a file cut after its pixels is refused too
  return true;
}

Image readPng(const std::filesystem::path& path) {
  const std::unique_ptr<std::FILE, int (*)(std::FILE*)> file(std::fopen(path.c_str(), "rb"),
                                                             std::fclose);
  if (!file) throw Error(path.string(), "cannot open the image file");
  PngMessages messages;
  struct ReadStruct {
    png_structp png = nullptr;
    png_infop info = nullptr;
    ~ReadStruct() {
      if (png != nullptr) png_destroy_read_struct(&png, &info, nullptr);
    }
  } read;
  read.png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &messages, onPngError, onPngWarning);
  if (read.png != nullptr) read.info = png_create_info_struct(read.png);
  if (read.info == nullptr) throw Error(path.string(), "out of memory reading it");
  png_structp png = read.png;
  png_infop info = read.info;
  const auto failed = [&] {
    return Error(path.string(),
                 fmt::format("cannot decode the PNG file: {}{}", messages.error,
                             messages.warning[0] == '\0' ? std::string()
                                                         : fmt::format(" ({})", messages.warning)));
  };
  PngLayout layout;
  if (!readPngHeader(png, info, file.get(), layout)) throw failed();
  // Before the rows are allocated: a few hundred bytes may declare any size up to the limits.
  if (uint64_t{layout.width} * layout.height > (uint64_t{1} << 30)) {
    throw Error(path.string(), fmt::format("is {}x{} pixels, more than the {} read here",
                                           layout.width, layout.height, uint64_t{1} << 30));
  }
  if (layout.bitDepth != 8 && layout.bitDepth != 16) {
    throw Error(path.string(), "PNG of an unsupported sample depth");
  }
  std::vector<uint8_t> pixels(layout.rowBytes * layout.height);
  std::vector<png_bytep> rows(layout.height);
  for (uint32_t y = 0; y < layout.height; ++y) rows[y] = pixels.data() + y * layout.rowBytes;
  if (!readPngRows(png, info, rows.data())) throw failed();

  const int channels = layout.channels;
  const double scale = layout.bitDepth == 16 ? 1.0 / 65535.0 : 1.0 / 255.0;
  Image image(static_cast<int>(layout.width), static_cast<int>(layout.height));
  image.depth.clear();
  image.hasAlpha = channels == 2 || channels == 4;
  for (uint32_t y = 0; y < layout.height; ++y) {
    for (uint32_t x = 0; x < layout.width; ++x) {
      std::array<double, 4> stored{0, 0, 0, 1 / scale};
      for (int c = 0; c < channels; ++c) {
        const std::size_t at = (std::size_t{x} * channels + c) * (layout.bitDepth / 8);
        if (layout.bitDepth == 8) {
          stored[static_cast<std::size_t>(c)] = rows[y][at];
        } else {
          uint16_t value;
          std::memcpy(&value, rows[y] + at, sizeof value);
          stored[static_cast<std::size_t>(c)] = value;
        }
      }
      float* p = image.pixel(static_cast<int>(x), static_cast<int>(y));
      if (channels <= 2) {  // grey (+ alpha)
        const double a = channels == 2 ? stored[1] : 1 / scale;
        p[0] = p[1] = p[2] = static_cast<float>(stored[0] * scale);
        p[3] = static_cast<float>(a * scale);
      } else {  // RGB(A)
        for (std::size_t c = 0; c < 4; ++c) p[c] = static_cast<float>(stored[c] * scale);
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
