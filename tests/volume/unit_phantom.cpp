// The phantom is a pure function of (index, seed): slabs in any order and size agree, seeds
// change only the noise, values are integer HU in range, the anatomy has plausible tissue
// fractions, and the NRRD it writes reads back exactly through openVolume.
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <vector>

#include "octoray/core/error.h"
#include "octoray/dicom/formats.h"
#include "octoray/volume/phantom.h"
#include "test_paths.h"

namespace octoray::volume {
namespace {

PhantomOptions optionsFor(std::array<int64_t, 3> dims, uint64_t seed = 1, double psfSigmaVoxels = 1.0) {
  PhantomOptions options;
  options.dims = dims;
  options.seed = seed;
  options.psfSigmaVoxels = psfSigmaVoxels;
  return options;
}

std::vector<float> readAll(VolumeSource& source) {
  std::vector<float> values(static_cast<std::size_t>(source.info().sampleCount()));
  source.readSlab(0, source.info().dims[2], values);
  return values;
}

// Reads the volume in slabs of `slabSlices`, last slab first.
std::vector<float> readBackwards(VolumeSource& source, int64_t slabSlices) {
  const VolumeInfo& info = source.info();
  std::vector<float> values(static_cast<std::size_t>(info.sampleCount()));
  const int64_t slabs = (info.dims[2] + slabSlices - 1) / slabSlices;
  for (int64_t s = slabs - 1; s >= 0; --s) {
    const int64_t first = s * slabSlices, count = std::min(slabSlices, info.dims[2] - first);
    source.readSlab(
        first, count,
        std::span<float>(values).subspan(static_cast<std::size_t>(first * info.sliceSamples()),
                                         static_cast<std::size_t>(count * info.sliceSamples())));
  }
  return values;
}

TEST(Phantom, DescribesItselfAsCenteredCtInHu) {
  PhantomOptions options = optionsFor({33, 17, 5}, 42);
  options.spacingMm = {0.7, 0.8, 1.25};
  const auto source = makePhantom(options);
  const VolumeInfo& info = source->info();
  EXPECT_EQ(info.dims, (std::array<int64_t, 3>{33, 17, 5}));
  EXPECT_EQ(info.format, "phantom");
  EXPECT_EQ(info.modality, "CT");
  EXPECT_EQ(info.unit, "HU");
  EXPECT_TRUE(info.integerValues);
  EXPECT_EQ(info.description, "octoray phantom seed 42");
  const Vec3 spacing = info.spacingMm();
  EXPECT_DOUBLE_EQ(spacing.x, 0.7);
  EXPECT_DOUBLE_EQ(spacing.y, 0.8);
  EXPECT_DOUBLE_EQ(spacing.z, 1.25);
  // The centre of the index grid maps to the patient origin.
  const Vec3 centre = info.patientFromIndex.transformPoint({16, 8, 2});
  EXPECT_NEAR(centre.x, 0, 1e-12);
  EXPECT_NEAR(centre.y, 0, 1e-12);
  EXPECT_NEAR(centre.z, 0, 1e-12);
}

TEST(Phantom, SameSeedSameValuesOtherSeedOtherNoiseOnly) {
  const std::array<int64_t, 3> dims{48, 40, 36};
  for (const double psf : {0.0, 1.0}) {
    const auto first = readAll(*makePhantom(optionsFor(dims, 7, psf)));
    const auto again = readAll(*makePhantom(optionsFor(dims, 7, psf)));
    const auto other = readAll(*makePhantom(optionsFor(dims, 8, psf)));
    EXPECT_EQ(first, again);
    std::size_t differing = 0;
    float largest = 0;
    for (std::size_t n = 0; n < first.size(); ++n) {
      differing += first[n] != other[n] ? 1 : 0;
      largest = std::max(largest, std::abs(first[n] - other[n]));
    }
    // The white noise is within +-11 HU, the correlated noise (a weighted mean of values in
    // +-64 HU) within +-64, and rounding adds 1: seeds move values by at most 22 (hard edges)
    // or 22 + 128 + 1, and move most of them.
    EXPECT_LE(largest, psf > 0 ? 151.0f : 22.0f) << "psf " << psf;
    EXPECT_GT(static_cast<double>(differing), 0.8 * static_cast<double>(first.size())) << "psf " << psf;
  }
}

// The point-spread function band-limits the anatomy: boundaries become ramps a few voxels
// wide (no value jumps as a hard edge's), the mean is kept, and the hard variant is still there.
TEST(Phantom, PointSpreadFunctionTurnsEdgesIntoRamps) {
  const std::array<int64_t, 3> dims{96, 96, 96};
  const auto hard = readAll(*makePhantom(optionsFor(dims, 1, 0.0)));
  const auto soft = readAll(*makePhantom(optionsFor(dims, 1, 1.0)));
  const auto at = [&](const std::vector<float>& v, int64_t i, int64_t j, int64_t k) {
    return v[static_cast<std::size_t>(i + dims[0] * (j + dims[1] * k))];
  };
  // The largest jump between x neighbours: a hard edge jumps by the full contrast.
  const auto largestJump = [&](const std::vector<float>& v) {
    float jump = 0;
    for (int64_t k = 0; k < dims[2]; ++k)
      for (int64_t j = 0; j < dims[1]; ++j)
        for (int64_t i = 1; i < dims[0]; ++i) jump = std::max(jump, std::abs(at(v, i, j, k) - at(v, i - 1, j, k)));
    return jump;
  };
  const float hardJump = largestJump(hard), softJump = largestJump(soft);
  EXPECT_GT(hardJump, 1500.0f);
  EXPECT_LT(softJump, 0.6f * hardJump) << "hard " << hardJump << ", band-limited " << softJump;
  double hardMean = 0, softMean = 0;
  for (std::size_t n = 0; n < hard.size(); ++n) {
    hardMean += hard[n];
    softMean += soft[n];
  }
  hardMean /= static_cast<double>(hard.size());
  softMean /= static_cast<double>(soft.size());
  EXPECT_NEAR(softMean, hardMean, 2.0);
  // Down the column from the vertex: hard, air jumps to scalp in one voxel; band-limited, at
  // least two voxels lie between air and soft tissue.
  const auto between = [&](const std::vector<float>& v) {
    int count = 0;
    for (int64_t k = dims[2] - 1; k >= 0; --k) {
      const float x = at(v, 48, 50, k);
      if (x > -100) break;
      count += x > -900 ? 1 : 0;
    }
    return count;
  };
  EXPECT_LE(between(hard), 1);
  EXPECT_GE(between(soft), 2);
  EXPECT_THROW(makePhantom(optionsFor(dims, 1, -1.0)), Error);
  EXPECT_THROW(makePhantom(optionsFor(dims, 1, 5.0)), Error);
}

TEST(Phantom, SlabsInAnyOrderSizeAndThreadCountAgree) {
  const std::array<int64_t, 3> dims{70, 50, 29};
  const auto whole = readAll(*makePhantom(optionsFor(dims)));
  for (const int64_t slabSlices : {1, 3, 7, 29}) {
    const auto source = makePhantom(optionsFor(dims));
    EXPECT_EQ(readBackwards(*source, slabSlices), whole) << "slabs of " << slabSlices;
  }
  const tbb::global_control oneThread(tbb::global_control::max_allowed_parallelism, 1);
  EXPECT_EQ(readAll(*makePhantom(optionsFor(dims))), whole);
}

TEST(Phantom, ValuesAreIntegerHuInRange) {
  for (const auto& dims :
       {std::array<int64_t, 3>{64, 64, 64}, std::array<int64_t, 3>{96, 80, 40}}) {
    for (const float v : readAll(*makePhantom(optionsFor(dims, 3)))) {
      ASSERT_EQ(v, std::round(v));
      ASSERT_GE(v, -1024.0f);
      ASSERT_LE(v, 3071.0f);
    }
  }
}

TEST(Phantom, TinyAndDegenerateSizesWork) {
  for (const auto& dims : {std::array<int64_t, 3>{1, 1, 1}, std::array<int64_t, 3>{33, 17, 5},
                           std::array<int64_t, 3>{1, 1, 200}, std::array<int64_t, 3>{200, 1, 1},
                           std::array<int64_t, 3>{2, 3, 1}}) {
    const auto source = makePhantom(optionsFor(dims));
    const auto values = readAll(*source);
    EXPECT_EQ(readBackwards(*source, 2), values);
    for (const float v : values) {
      EXPECT_GE(v, -1024.0f);
      EXPECT_LE(v, 3071.0f);
    }
  }
  // A single voxel lies at the centre of the head: brain-like soft tissue when point-sampled
  // (band-limited, it is the mean of the whole head and its surroundings).
  const auto single = readAll(*makePhantom(optionsFor({1, 1, 1}, 1, 0.0)));
  EXPECT_GE(single[0], -20.0f);
  EXPECT_LE(single[0], 70.0f);
}

TEST(Phantom, RejectsBadOptionsAndSlabs) {
  EXPECT_THROW(makePhantom(optionsFor({0, 4, 4})), Error);
  EXPECT_THROW(makePhantom(optionsFor({4, -1, 4})), Error);
  PhantomOptions badSpacing = optionsFor({4, 4, 4});
  badSpacing.spacingMm = {0.5, 0, 0.5};
  EXPECT_THROW(makePhantom(badSpacing), Error);
  badSpacing.spacingMm = {0.5, NAN, 0.5};
  EXPECT_THROW(makePhantom(badSpacing), Error);

  const auto source = makePhantom(optionsFor({8, 8, 8}));
  std::vector<float> slab(64 * 2);
  EXPECT_THROW(source->readSlab(7, 2, slab), Error);
  EXPECT_THROW(source->readSlab(-1, 2, slab), Error);
  EXPECT_THROW(source->readSlab(0, 1, slab), Error);  // buffer of the wrong size
  EXPECT_NO_THROW(source->readSlab(6, 2, slab));
}

// The painted anatomy (hard edges: at 128^3 the 1-voxel point-spread function averages the
// one-voxel cortical tables below the dense-bone threshold, as a scanner of that resolution
// would).
TEST(Phantom, HasPlausibleHeadAnatomyAt128) {
  const std::array<int64_t, 3> dims{128, 128, 128};
  const auto values = readAll(*makePhantom(optionsFor(dims, 1, 0.0)));
  const auto at = [&](int64_t i, int64_t j, int64_t k) {
    return values[static_cast<std::size_t>(i + dims[0] * (j + dims[1] * k))];
  };
  std::size_t air = 0, fat = 0, soft = 0, csf = 0, brain = 0, contrast = 0, bone = 0, dense = 0;
  for (const float v : values) {
    air += v < -850 ? 1 : 0;
    fat += v >= -120 && v <= -60 ? 1 : 0;
    soft += v >= -20 && v <= 70 ? 1 : 0;
    csf += v >= -6 && v <= 16 ? 1 : 0;
    brain += v >= 18 && v <= 52 ? 1 : 0;
    contrast += v >= 180 && v <= 360 ? 1 : 0;
    bone += v >= 400 ? 1 : 0;
    dense += v >= 1200 ? 1 : 0;
  }
  const auto fraction = [&](std::size_t count) {
    return static_cast<double>(count) / static_cast<double>(values.size());
  };
  // Measured at 128^3: air 0.59, soft 0.33, brain 0.29, CSF 0.030, fat 0.024, contrast 0.007,
  // bone 0.044, dense bone 0.024. The bounds leave room for changes to the anatomy.
  EXPECT_GT(fraction(air), 0.40);  // air around the head
  EXPECT_LT(fraction(air), 0.70);
  EXPECT_GT(fraction(soft), 0.25);  // skin, muscle, brain
  EXPECT_GT(fraction(brain), 0.15);
  EXPECT_GT(fraction(csf), 0.01);  // ventricles, sulci, subarachnoid space
  EXPECT_GT(fraction(fat), 0.01);
  EXPECT_GT(fraction(contrast), 0.002);  // vessels (and some trabecular bone)
  EXPECT_GT(fraction(bone), 0.02);
  EXPECT_LT(fraction(bone), 0.15);
  EXPECT_GT(fraction(dense), 0.01);  // cortical tables

  // Corners are air; the centre is brain; a column down from the vertex meets air, scalp,
  // the skull, then brain.
  EXPECT_LT(at(0, 0, 0), -980.0f);
  EXPECT_LT(at(127, 127, 127), -980.0f);
  EXPECT_GE(at(64, 64, 64), -20.0f);
  EXPECT_LE(at(64, 64, 64), 70.0f);
  int stage = 0;  // 0 air, 1 scalp, 2 skull, 3 brain
  for (int64_t k = dims[2] - 1; k >= 0 && stage < 3; --k) {
    const float v = at(64, 67, k);
    if (stage == 0 && v > -200) stage = 1;
    if (stage == 1 && v > 1000) stage = 2;
    if (stage == 2 && v >= 18 && v <= 52) stage = 3;
  }
  EXPECT_EQ(stage, 3);
}

TEST(PhantomNrrd, RoundTripsExactlyThroughOpenVolume) {
  const auto dir = test::freshTempDir("phantom_nrrd_round_trip");
  PhantomOptions options = optionsFor({40, 36, 24}, 5);
  options.spacingMm = {0.7, 0.8, 1.25};
  const std::string path = (dir / "head.nhdr").string();
  std::vector<int64_t> progress;
  writePhantomNrrd(options, path, [&](int64_t done, int64_t total) {
    EXPECT_EQ(total, 24);
    progress.push_back(done);
  });
  ASSERT_FALSE(progress.empty());
  EXPECT_TRUE(std::is_sorted(progress.begin(), progress.end()));
  EXPECT_EQ(progress.back(), 24);
  EXPECT_EQ(std::filesystem::file_size(dir / "head.raw"), 40u * 36 * 24 * 2);
  // Nothing but the header and the data is left behind.
  EXPECT_EQ(std::distance(std::filesystem::directory_iterator(dir), {}), 2);

  const auto phantom = makePhantom(options);
  const auto read = openVolume(path);
  const VolumeInfo& expected = phantom->info();
  const VolumeInfo& got = read->info();
  EXPECT_EQ(got.dims, expected.dims);
  EXPECT_EQ(got.unit, "HU");  // 'sample units': a store built from the file is CT, in any format
  EXPECT_EQ(got.unit, expected.unit);
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 4; ++c) {
      EXPECT_NEAR(got.patientFromIndex.m[r][c], expected.patientFromIndex.m[r][c], 1e-9)
          << "patientFromIndex[" << r << "][" << c << "]";
    }
  }
  EXPECT_EQ(readAll(*read), readAll(*phantom));
}

TEST(PhantomNrrd, StreamsSeveralSlabs) {
  // 2048 x 2048 slices: the writer uses slabs of two slices, so three slices take two slabs.
  const auto dir = test::freshTempDir("phantom_nrrd_slabs");
  const PhantomOptions options = optionsFor({2048, 2048, 3}, 9);
  const std::string path = (dir / "wide.nrrd").string();
  std::vector<int64_t> progress;
  writePhantomNrrd(options, path, [&](int64_t done, int64_t) { progress.push_back(done); });
  EXPECT_EQ(progress, (std::vector<int64_t>{2, 3}));
  const auto read = openVolume(path);
  EXPECT_EQ(readAll(*read), readAll(*makePhantom(options)));
}

TEST(PhantomNrrd, FailuresNameTheFileAndLeaveNothing) {
  const auto dir = test::freshTempDir("phantom_nrrd_failures");
  const PhantomOptions options = optionsFor({16, 16, 4});
  try {
    writePhantomNrrd(options, (dir / "head.mhd").string());
    FAIL() << "a header name without .nhdr/.nrrd was accepted";
  } catch (const Error& e) {
    EXPECT_EQ(e.path(), (dir / "head.mhd").string());
  }
  const std::string missing = (dir / "no_such_folder" / "head.nhdr").string();
  try {
    writePhantomNrrd(options, missing);
    FAIL() << "writing into a missing folder succeeded";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("head.raw"), std::string::npos) << e.what();
  }
  // More data than any test machine's disk: refused by name before anything is written.
  try {
    writePhantomNrrd(optionsFor({1048576, 1048576, 1024}), (dir / "huge.nhdr").string());
    FAIL() << "a phantom of 2 PiB was started";
  } catch (const Error& e) {
    EXPECT_EQ(e.path(), (dir / "huge.raw").string());
    EXPECT_NE(e.reason().find("the 1048576x1048576x1024 phantom needs 2097152.0 GiB, but this "
                              "file system has "),
              std::string::npos)
        << e.what();
  }
  EXPECT_FALSE(std::filesystem::exists(dir / "huge.raw.partial"));
  // A header name that is a folder: the data is written, the header rename fails, and both
  // the temporary files and the renamed data are removed.
  std::filesystem::create_directory(dir / "taken.nhdr");
  std::filesystem::create_directory(dir / "taken.nhdr" / "inside");
  EXPECT_THROW(writePhantomNrrd(options, (dir / "taken.nhdr").string()), Error);
  EXPECT_FALSE(std::filesystem::exists(dir / "taken.raw"));
  EXPECT_FALSE(std::filesystem::exists(dir / "taken.raw.partial"));
  EXPECT_FALSE(std::filesystem::exists(dir / "taken.nhdr.partial"));
}

}  // namespace
}  // namespace octoray::volume
