// Cameras (orbit conventions, rays, JSON), image files (PNG, EXR) and image metrics.

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cmath>
#include <fstream>
#include <limits>

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
