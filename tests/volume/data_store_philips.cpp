// Real CT through the store: every leaf sample of the 140-slice head series and of the tilted
// series reads back exactly (HU), and the store keeps the tilt's shear in its affine.
#include <gtest/gtest.h>

#include "octoray/dicom/dicom_series.h"
#include "octoray/dicom/dicom_volume.h"
#include "octoray/volume/store_builder.h"
#include "octoray/volume/store_reader.h"
#include "store_leaf_check.h"
#include "test_paths.h"

namespace octoray::volume {
namespace {

void roundTrip(const std::filesystem::path& folder, int brickSize) {
  OCTORAY_REQUIRE_PATH(folder);
  const dicom::DicomScan scan = dicom::scanDicom(folder);
  const auto& series = scan.series.at(dicom::defaultSeriesIndex(scan, folder.string()));
  auto source = dicom::openDicomSeries(series);
  const std::string path = (test::freshTempDir("philips") / "head.octoray").string();
  BuildOptions options;
  options.brickSize = brickSize;
  const BuildReport report = buildStore(*source, path, options);
  EXPECT_EQ(report.clampedSamples, 0);
  const StoreReader store(path);
  EXPECT_EQ(store.sampleFormat(), SampleFormat::UInt16);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) {
      EXPECT_EQ(store.patientFromIndex().m[r][c], source->info().patientFromIndex.m[r][c]);
    }
  test::expectStoreValid(path);
  auto again = dicom::openDicomSeries(series);
  EXPECT_EQ(test::expectLeavesEqualSource(*again, store), source->info().sampleCount());
}

TEST(StorePhilips, HeadSeriesLeavesAreExact) { roundTrip(test::philipsDir() / "S21570/S2020", 32); }

TEST(StorePhilips, TiltedSeriesKeepsShearAndValues) {
  roundTrip(test::philipsDir() / "S21610/S2010", 64);
}

}  // namespace
}  // namespace octoray::volume
