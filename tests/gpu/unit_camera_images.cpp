// Cameras (orbit conventions, rays, JSON), image files (PNG, EXR) and image metrics.

#include <gtest/gtest.h>
#include <zlib.h>
#include <nlohmann/json.hpp>

#include <array>
#include <cmath>
#include <fstream>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "octoray/core/error.h"
#include "octoray/gpu/camera.h"
#include "octoray/gpu/image_io.h"
#include "octoray/gpu/image_metrics.h"
#include "test_paths.h"

namespace octoray::test {
namespace {

using namespace octoray::gpu;

void expectVec(Vec3 a, Vec3 b, double tolerance = 1e-9) {
  EXPECT_NEAR(a.x, b.x, tolerance);
  EXPECT_NEAR(a.y, b.y, tolerance);
  EXPECT_NEAR(a.z, b.z, tolerance);
}

VolumeDomain cube() {
  return {{11, 11, 11}, Mat4::fromColumns({1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {-5, -5, -5})};
}

TEST(Camera, OrbitConventions) {
  OrbitParameters orbit;
  orbit.width = 101;
  orbit.height = 101;
  // Azimuth 0: from anterior (-Y), superior up, patient's left (+X) on the image's right.
  Camera c = orbitCamera(cube(), orbit);
  expectVec(c.target, {0, 0, 0});
  EXPECT_LT(c.eye.y, 0);
  EXPECT_NEAR(c.eye.x, 0, 1e-9);
  expectVec(c.ray(50, 50).direction, {0, 1, 0});
  EXPECT_GT(c.ray(100, 50).direction.x, 0);  // right column looks towards +X
  EXPECT_GT(c.ray(50, 0).direction.z, 0);    // top row looks towards superior
  // Azimuth 90: from the patient's left.
  orbit.azimuthDegrees = 90;
  c = orbitCamera(cube(), orbit);
  expectVec(normalize(c.eye - c.target), {1, 0, 0});
  // Elevation 90: from above, image up = posterior.
  orbit.azimuthDegrees = 0;
  orbit.elevationDegrees = 90;
  c = orbitCamera(cube(), orbit);
  expectVec(normalize(c.eye - c.target), {0, 0, 1});
  EXPECT_GT(c.ray(50, 0).direction.y, 0);
  // Zoom 1 frames the bounding sphere; zoom 2 halves the visible height.
  orbit.elevationDegrees = 0;
  const double radius = cube().boundingRadiusMm();
  EXPECT_NEAR(radius, 5.5 * std::sqrt(3.0), 1e-9);
  c = orbitCamera(cube(), orbit);
  EXPECT_NEAR(length(c.eye - c.target) * std::sin(c.fovYDegrees / 2 * M_PI / 180), radius, 1e-9);
  orbit.projection = Projection::Orthographic;
  orbit.zoom = 2;
  c = orbitCamera(cube(), orbit);
  EXPECT_NEAR(c.orthoHeightMm, radius, 1e-9);
  EXPECT_THROW(orbitCamera(cube(), {0, 0, 0}), Error);
}

TEST(Camera, RaysAreUnitAndOrthographicRaysParallel) {
  Camera c;
  c.projection = Projection::Orthographic;
  c.width = 4;
  c.height = 2;
  c.orthoHeightMm = 10;
  const Ray a = c.ray(0, 0), b = c.ray(3, 1);
  expectVec(a.direction, b.direction);
  EXPECT_NEAR(length(a.direction), 1.0, 1e-12);
  EXPECT_NEAR(length(a.origin - b.origin), std::hypot(15.0, 5.0), 1e-9);  // pixel = 5 mm
}

TEST(Camera, JsonRoundTripAndErrors) {
  Camera c = orbitCamera(cube(), {20, 30, 1.5, Projection::Perspective, 40, 64, 48});
  const auto dir = freshTempDir("camera");
  saveCamera(c, dir / "camera.json");
  const Camera back = loadCamera(dir / "camera.json");
  expectVec(back.eye, c.eye, 0);
  expectVec(back.target, c.target, 0);
  expectVec(back.up, c.up, 0);
  EXPECT_EQ(back.fovYDegrees, c.fovYDegrees);
  EXPECT_EQ(back.width, 64);
  EXPECT_EQ(back.height, 48);
  nlohmann::json j = cameraToJson(c);
  j["up"] = {0, 0, 0};
  EXPECT_THROW(cameraFromJson(j, "x.json"), Error);
  j = cameraToJson(c);
  j.erase("eye");
  try {
    cameraFromJson(j, "x.json");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("eye"), std::string::npos);
  }
  std::ofstream(dir / "bad.json") << "{ not json";
  EXPECT_THROW(loadCamera(dir / "bad.json"), Error);
}

Image gradientImage(int w, int h) {
  Image image(w, h);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      float* p = image.pixel(x, y);
      p[0] = static_cast<float>(x) / static_cast<float>(w);
      p[1] = static_cast<float>(y) / static_cast<float>(h);
      p[2] = 0.25f;
      p[3] = 0.75f;
      image.depth[image.index(x, y)] = x == 0 ? std::numeric_limits<float>::infinity() : 3.5f * y;
    }
  }
  return image;
}

TEST(ImageIo, ExrRoundTripIsExact) {
  const Image image = gradientImage(17, 9);
  const auto dir = freshTempDir("exr");
  writeExr(image, dir / "a.exr");
  const Image back = readImage(dir / "a.exr");
  EXPECT_EQ(back.width, 17);
  EXPECT_EQ(back.height, 9);
  EXPECT_EQ(back.rgba, image.rgba);
  EXPECT_EQ(back.depth, image.depth);
}

TEST(ImageIo, PngRoundTripWithinOneLevel) {
  const Image image = gradientImage(17, 9);
  const auto dir = freshTempDir("png");
  writePng(image, dir / "a.png");
  const Image back = readImage(dir / "a.png");
  for (std::size_t i = 0; i < image.rgba.size(); ++i) {
    if (i % 4 == 3) {
      EXPECT_EQ(back.rgba[i], 1.0f);  // written as colour over black, no alpha
      EXPECT_FALSE(back.hasAlpha);
    } else {
      EXPECT_NEAR(back.rgba[i], image.rgba[i], 0.5 / 255 + 1e-6);
    }
  }
  writePng(image, dir / "s.png", PngEncoding::Srgb);
  const Image srgb = readImage(dir / "s.png");
  EXPECT_NEAR(srgb.pixel(0, 0)[2], 0.537, 0.003);  // sRGB(0.25)
  std::ofstream(dir / "junk.png") << "not an image at all";
  EXPECT_THROW(readImage(dir / "junk.png"), Error);
  EXPECT_THROW(readImage(dir / "missing.exr"), Error);
  try {
    readImage(dir);
    ADD_FAILURE() << "a folder was read as an image";
  } catch (const Error& e) {
    EXPECT_EQ(std::string(e.what()), dir.string() + ": is a folder, not an image file");
  }
}

// A PNG made by hand (zlib for the pixels and the CRCs): no PNG library writes what libpng
// reads. `rows` are the image rows, each written with filter byte 0; `before` are chunks
// (type, data) between IHDR and IDAT.
std::string pngChunk(const std::string& type, const std::string& data) {
  std::string out;
  const auto put32 = [&](uint32_t v) {
    for (int shift = 24; shift >= 0; shift -= 8) out += static_cast<char>((v >> shift) & 0xFF);
  };
  put32(static_cast<uint32_t>(data.size()));
  const std::string typed = type + data;
  out += typed;
  put32(static_cast<uint32_t>(
      crc32(0, reinterpret_cast<const Bytef*>(typed.data()), static_cast<uInt>(typed.size()))));
  return out;
}

std::string handPng(uint32_t width, const std::vector<std::string>& rows, int bitDepth,
                    int colourType,
                    const std::vector<std::pair<std::string, std::string>>& before = {}) {
  std::string header;
  for (const uint32_t v : {width, static_cast<uint32_t>(rows.size())}) {
    for (int shift = 24; shift >= 0; shift -= 8) header += static_cast<char>((v >> shift) & 0xFF);
  }
  header += {static_cast<char>(bitDepth), static_cast<char>(colourType), 0, 0, 0};
  std::string raw;
  for (const auto& row : rows) raw += '\0' + row;
  uLongf size = compressBound(raw.size());
  std::string packed(size, '\0');
  EXPECT_EQ(compress2(reinterpret_cast<Bytef*>(packed.data()), &size,
                      reinterpret_cast<const Bytef*>(raw.data()), raw.size(), 6),
            Z_OK);
  packed.resize(size);
  std::string png = "\x89PNG\r\n\x1a\n" + pngChunk("IHDR", header);
  for (const auto& [type, data] : before) png += pngChunk(type, data);
  return png + pngChunk("IDAT", packed) + pngChunk("IEND", "");
}

void writeBytes(const std::filesystem::path& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary) << bytes;
}

// Every kind of PNG reads as stored, scaled to [0, 1]: 8- and 16-bit grey, grey + alpha, RGB
// and RGBA (16-bit samples are big-endian in the file), a palette with transparency, and
// 1-bit grey (expanded to 0 and 1).
TEST(ImageIo, PngOfEveryKindReadsAsStored) {
  const auto dir = freshTempDir("png_kinds");
  const auto expectPixel = [](const Image& image, int x, int y, std::array<float, 4> rgba) {
    for (std::size_t c = 0; c < 4; ++c) {
      EXPECT_FLOAT_EQ(image.pixel(x, y)[c], rgba[c])
          << "pixel " << x << "," << y << " channel " << c;
    }
  };
  writeBytes(dir / "grey8.png", handPng(2, {"\x10\xF0"}, 8, 0));
  const Image grey8 = readImage(dir / "grey8.png");
  EXPECT_FALSE(grey8.hasAlpha);
  expectPixel(grey8, 1, 0, {240 / 255.f, 240 / 255.f, 240 / 255.f, 1});

  writeBytes(dir / "grey16.png",
             handPng(1, {std::string("\x12\x34", 2), std::string("\xFF\x00", 2)}, 16, 0));
  const Image grey16 = readImage(dir / "grey16.png");
  expectPixel(grey16, 0, 0, {0x1234 / 65535.f, 0x1234 / 65535.f, 0x1234 / 65535.f, 1});
  expectPixel(grey16, 0, 1, {0xFF00 / 65535.f, 0xFF00 / 65535.f, 0xFF00 / 65535.f, 1});

  writeBytes(dir / "greyalpha.png", handPng(1, {"\x40\x80"}, 8, 4));
  const Image greyAlpha = readImage(dir / "greyalpha.png");
  EXPECT_TRUE(greyAlpha.hasAlpha);
  expectPixel(greyAlpha, 0, 0, {64 / 255.f, 64 / 255.f, 64 / 255.f, 128 / 255.f});

  writeBytes(dir / "rgb8.png", handPng(1, {"\x01\x02\x03"}, 8, 2));
  expectPixel(readImage(dir / "rgb8.png"), 0, 0, {1 / 255.f, 2 / 255.f, 3 / 255.f, 1});

  writeBytes(dir / "rgba16.png",
             handPng(1, {std::string("\x00\x01\x01\x00\x80\x00\xFF\xFF", 8)}, 16, 6));
  const Image rgba16 = readImage(dir / "rgba16.png");
  EXPECT_TRUE(rgba16.hasAlpha);
  expectPixel(rgba16, 0, 0, {1 / 65535.f, 256 / 65535.f, 0x8000 / 65535.f, 1});

  // Palette: entry 0 red and half transparent, entry 1 blue and opaque.
  writeBytes(dir / "palette.png",
             handPng(2, {std::string("\x00\x01", 2)}, 8, 3,
                     {{"PLTE", std::string("\xFF\x00\x00\x00\x00\xFF", 6)}, {"tRNS", "\x80"}}));
  const Image palette = readImage(dir / "palette.png");
  EXPECT_TRUE(palette.hasAlpha);
  expectPixel(palette, 0, 0, {1, 0, 0, 128 / 255.f});
  expectPixel(palette, 1, 0, {0, 0, 1, 1});

  writeBytes(dir / "bits1.png", handPng(8, {"\xA0"}, 1, 0));  // 1010 0000
  const Image bits1 = readImage(dir / "bits1.png");
  expectPixel(bits1, 0, 0, {1, 1, 1, 1});
  expectPixel(bits1, 1, 0, {0, 0, 0, 1});
  expectPixel(bits1, 2, 0, {1, 1, 1, 1});
}

// A damaged PNG ends in one octoray::Error naming the file and libpng's reason; libpng prints
// nothing (through OpenCV it printed "libpng error: ..." on stderr first).
TEST(ImageIo, DamagedPngEndsInOneMessage) {
  const auto dir = freshTempDir("png_damaged");
  const std::string good = handPng(4, {"\x01\x02\x03\x04", "\x05\x06\x07\x08"}, 8, 0);
  const auto expectRefused = [&](const std::string& name, const std::string& bytes,
                                 const std::string& reason) {
    writeBytes(dir / name, bytes);
    testing::internal::CaptureStderr();
    try {
      readImage(dir / name);
      ADD_FAILURE() << name << " was read";
    } catch (const Error& e) {
      EXPECT_EQ(std::string(e.what()),
                (dir / name).string() + ": cannot decode the PNG file: " + reason);
    }
    EXPECT_EQ(testing::internal::GetCapturedStderr(), "") << name;
  };
  expectRefused("cut.png", good.substr(0, good.size() - 20), "the file ends early");
  std::string crc = good;
  crc[8 + 8 + 13] ^= 0x01;  // IHDR's CRC
  expectRefused("crc.png", crc, "IHDR: CRC error");
  // Filter type 7 does not exist.
  expectRefused(
      "filter.png",
      "\x89PNG\r\n\x1a\n" + pngChunk("IHDR", std::string("\0\0\0\1\0\0\0\1\x08\0\0\0\0", 13)) +
          [] {
            const std::string row("\x07\x10", 2);
            uLongf size = compressBound(row.size());
            std::string packed(size, '\0');
            compress2(reinterpret_cast<Bytef*>(packed.data()), &size,
                      reinterpret_cast<const Bytef*>(row.data()), row.size(), 6);
            packed.resize(size);
            return pngChunk("IDAT", packed);
          }() +
          pngChunk("IEND", ""),
      "bad adaptive filter value");
  // 60,000 x 60,000 in a few bytes: refused before its rows are allocated.
  writeBytes(dir / "vast.png",
             "\x89PNG\r\n\x1a\n" +
                 pngChunk("IHDR", std::string("\0\0\xEA\x60\0\0\xEA\x60\x08\0\0\0\0", 13)) +
                 pngChunk("IDAT", "x") + pngChunk("IEND", ""));
  try {
    readImage(dir / "vast.png");
    ADD_FAILURE() << "vast.png was read";
  } catch (const Error& e) {
    EXPECT_EQ(std::string(e.what()),
              (dir / "vast.png").string() +
                  ": is 60000x60000 pixels, more than the 1073741824 read here");
  }
  // 70,000 pixels wide: above the 65,536 limit, refused before any row is allocated.
  expectRefused("wide.png", handPng(70000, {"\x01"}, 8, 0),
                "Invalid IHDR data (Image width exceeds user limit in IHDR)");
}

// The PNG and the EXR of a command are written together or not at all; temporaries are
// hidden (.NAME.partial-PID) and never left behind.
TEST(ImageIo, OutputsAreWrittenTogetherOrNotAtAll) {
  const Image image = gradientImage(17, 9);
  const auto dir = freshTempDir("outputs");
  writeImageOutputs(image, {dir / "a.png", PngEncoding::Clamp, dir / "a.exr"});
  EXPECT_EQ(readImage(dir / "a.exr").rgba, image.rgba);
  EXPECT_TRUE(std::filesystem::exists(dir / "a.png"));
  // The EXR's folder is a file: the EXR cannot be made, so the PNG is not left either.
  std::ofstream(dir / "not-a-folder") << "x";
  EXPECT_THROW(writeImageOutputs(image, {dir / "b.png", PngEncoding::Clamp, dir / "not-a-folder" / "b.exr"}),
               Error);
  EXPECT_FALSE(std::filesystem::exists(dir / "b.png"));
  // The EXR's name is a folder: the rename fails after both were written; neither stays.
  std::filesystem::create_directory(dir / "c.exr");
  EXPECT_THROW(writeImageOutputs(image, {dir / "c.png", PngEncoding::Clamp, dir / "c.exr"}), Error);
  EXPECT_FALSE(std::filesystem::exists(dir / "c.png"));
  for (const auto& e : std::filesystem::directory_iterator(dir)) {
    EXPECT_EQ(e.path().filename().string().find("partial"), std::string::npos) << e.path();
  }
}

TEST(ImageMetrics, CompareCountsAndMeasures) {
  const Image a = gradientImage(32, 24);
  ImageMetrics same = compare(a, a);
  EXPECT_EQ(same.rmse, 0);
  EXPECT_TRUE(std::isinf(same.psnrDb));
  EXPECT_NEAR(same.ssim, 1.0, 1e-9);
  Image b = a;
  b.pixel(3, 4)[0] += 0.5f;
  b.pixel(5, 5)[1] = std::numeric_limits<float>::quiet_NaN();
  const ImageMetrics m = compare(a, b);
  EXPECT_EQ(m.nonFiniteA, 0);
  EXPECT_EQ(m.nonFiniteB, 1);
  EXPECT_NEAR(m.maxAbsError, 0.5, 1e-6);
  EXPECT_NEAR(m.rmse, std::sqrt(0.25 / ((32.0 * 24 - 1) * 3)), 1e-6);
  EXPECT_LT(m.ssim, 1.0);
  EXPECT_TRUE(m.alphaCompared);
  EXPECT_EQ(m.maxAlphaError, 0.0);
  b = a;
  b.pixel(1, 1)[3] = 0.0f;
  EXPECT_EQ(compare(a, b).maxAbsError, 0.0);
  EXPECT_NEAR(compare(a, b).maxAlphaError, 0.75, 1e-7);
  b.hasAlpha = false;  // e.g. read from our PNG: alpha is not compared
  EXPECT_FALSE(compare(a, b).alphaCompared);
  EXPECT_THROW(compare(a, gradientImage(8, 8)), Error);
}

}  // namespace
}  // namespace octoray::test

namespace octoray::gpu {
namespace {

// --orbit for cameras from a file: a quarter turn about the up vector (+z) through the centre
// takes an eye in front (−y) to the side (+x), keeps distances, target offsets and the up
// vector, and a full turn comes back.
TEST(TurnAboutCentre, QuarterAndFullTurns) {
  Camera camera;
  camera.eye = {10, -90, 5};
  camera.target = {10, 0, 5};
  camera.up = {0, 0, 1};
  const Vec3 centre{10, 0, 0};
  const Camera quarter = turnAboutCentre(camera, centre, 90);
  EXPECT_NEAR(quarter.eye.x, 100, 1e-9);
  EXPECT_NEAR(quarter.eye.y, 0, 1e-9);
  EXPECT_NEAR(quarter.eye.z, 5, 1e-9);
  EXPECT_NEAR(quarter.target.x, 10, 1e-9);
  EXPECT_NEAR(quarter.target.y, 0, 1e-9);
  EXPECT_EQ(quarter.up.z, 1);
  const Camera full = turnAboutCentre(camera, centre, 360);
  EXPECT_NEAR(full.eye.x, camera.eye.x, 1e-9);
  EXPECT_NEAR(full.eye.y, camera.eye.y, 1e-9);
  EXPECT_NEAR(full.eye.z, camera.eye.z, 1e-9);
}

}  // namespace
}  // namespace octoray::gpu
