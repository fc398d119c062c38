// Real tilted Philips CT (S21610/S2010, gantry tilt -18.5 degrees: a sheared affine) exported as
// OpenVDB and read back, through our reader and independently through OpenVDB's own API.

#include <gtest/gtest.h>

#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>

#include <cmath>
#include <filesystem>
#include <vector>

#include "format_test_helpers.h"
#include "octoray/core/error.h"
#include "octoray/dicom/formats.h"
#include "octoray/dicom/vdb.h"
#include "test_paths.h"

namespace octoray {
namespace {

namespace fs = std::filesystem;

std::vector<float> readAll(VolumeSource& source) {
  const VolumeInfo& info = source.info();
  std::vector<float> values(static_cast<std::size_t>(info.sampleCount()));
  source.readSlab(0, info.dims[2], values);
  return values;
}

TEST(VdbPhilips, TiltedSeriesRoundTrips) {
  const fs::path folder = test::philipsDir() / "S21610/S2010";
  OCTORAY_REQUIRE_PATH(folder);
  auto source = openVolume(folder.string());
  const VolumeInfo info = source->info();
  ASSERT_GT(std::abs(info.tiltDegrees), 10.0);
  ASSERT_EQ(info.unit, "HU");
  const std::vector<float> original = readAll(*source);
  auto at = [&](int64_t i, int64_t j, int64_t k) {
    return original[static_cast<std::size_t>((k * info.dims[1] + j) * info.dims[0] + i)];
  };

  const fs::path dir = test::freshTempDir("vdb_philips");
  for (double threshold : {-900.0, 300.0}) {
    SCOPED_TRACE(threshold);
    const fs::path file = dir / "tilted.vdb";
    VdbExportOptions options;
    options.thresholdHu = threshold;
    const VdbExportReport report = exportVdb(*source, file.string(), options);
    int64_t expectedActive = 0;
    for (float v : original) expectedActive += v >= threshold;
    EXPECT_EQ(report.activeVoxels, expectedActive);
    EXPECT_GT(expectedActive, 0);
    EXPECT_LT(expectedActive, info.sampleCount());

    // OpenVDB's own reader: as many active voxels as samples >= the threshold, each at such a
    // sample with its exact value (together: the same set), and the affine as the transform.
    openvdb::initialize();
    openvdb::io::File vdb(file.string());
    vdb.open(false);
    const auto grid = openvdb::gridPtrCast<openvdb::FloatGrid>(vdb.readGrid("density"));
    vdb.close();
    ASSERT_TRUE(grid);
    EXPECT_EQ(grid->activeVoxelCount(), static_cast<openvdb::Index64>(expectedActive));
    int64_t wrong = 0;
    for (auto it = grid->cbeginValueOn(); it; ++it) {
      openvdb::CoordBBox box;
      it.getBoundingBox(box);
      for (auto ijk = box.begin(); ijk; ++ijk) {
        const float v = at((*ijk).x(), (*ijk).y(), (*ijk).z());
        wrong += !(v >= threshold) || v != *it;
      }
    }
    EXPECT_EQ(wrong, 0);
    const int last[3] = {int(info.dims[0] - 1), int(info.dims[1] - 1), int(info.dims[2] - 1)};
    for (const openvdb::Coord corner :
         {openvdb::Coord(0, 0, 0), openvdb::Coord(last[0], 0, 0), openvdb::Coord(0, last[1], last[2]),
          openvdb::Coord(last[0], last[1], last[2])}) {
      const openvdb::Vec3d world = grid->indexToWorld(corner);
      const Vec3 expected = info.patientFromIndex.transformPoint(
          {double(corner.x()), double(corner.y()), double(corner.z())});
      for (int a = 0; a < 3; ++a) EXPECT_NEAR(world[a], expected[a], 1e-9);
    }

    // Our reader: the same extent and affine, the samples >= threshold, air elsewhere.
    auto back = openVdb(file.string());
    EXPECT_EQ(back->info().dims, info.dims);
    formats_test::expectAffineNear(back->info().patientFromIndex, info.patientFromIndex, 1e-9);
    EXPECT_EQ(back->info().unit, "HU");
    EXPECT_TRUE(back->info().integerValues);
    const std::vector<float> values = readAll(*back);
    int64_t differing = 0;
    for (std::size_t n = 0; n < values.size(); ++n) {
      differing += values[n] != (original[n] >= threshold ? original[n] : -1000.0f);
    }
    EXPECT_EQ(differing, 0);
  }
}

}  // namespace
}  // namespace octoray
