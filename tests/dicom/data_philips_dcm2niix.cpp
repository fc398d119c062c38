// Real Philips CT (dcm_qa_ct), a second, independent opinion: where dcm2niix is installed, its
// NIfTI of each axial series is read here in a few lines and compared with our volume at the
// same patient positions. Where dcm2niix disagrees with the files' own attributes (its tilt
// correction on one series), the attributes decide; data_philips.cpp checks our volume against
// them pixel by pixel.

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "philips_data.h"
#include "test_paths.h"

namespace octoray {
namespace {

using namespace philips_test;

// A NIfTI-1 file read here in a few lines (not through our reader or VTK, whose qfac
// handling would be one more thing to trust): dims, sform and scaled values.
struct Nifti {
  std::array<int64_t, 3> dims{};
  double srow[3][4]{};
  std::vector<double> values;
  double at(int64_t i, int64_t j, int64_t k) const {
    return values[static_cast<std::size_t>((k * dims[1] + j) * dims[0] + i)];
  }
};

std::optional<Nifti> readNifti(const fs::path& path, std::string& why) {
  std::ifstream in(path, std::ios::binary);
  char header[348];
  if (!in.read(header, sizeof header)) {
    why = "short header";
    return std::nullopt;
  }
  auto get = [&](auto& value, std::size_t offset) {
    std::memcpy(&value, header + offset, sizeof value);
  };
  int32_t size;
  get(size, 0);
  int16_t dim[8], datatype, sformCode;
  float voxOffset, slope, inter, srow[12];
  get(dim, 40);
  get(datatype, 70);
  get(voxOffset, 108);
  get(slope, 112);
  get(inter, 116);
  get(sformCode, 254);
  get(srow, 280);
  if (size != 348 || dim[0] < 3 || (dim[0] > 3 && dim[4] > 1)) {
    why = "not a little-endian 3D NIfTI-1";
    return std::nullopt;
  }
  if (sformCode <= 0) {
    why = "no sform";
    return std::nullopt;
  }
  Nifti n;
  n.dims = {dim[1], dim[2], dim[3]};
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 4; ++c) n.srow[r][c] = srow[4 * r + c];
  }
  const std::size_t count = static_cast<std::size_t>(n.dims[0] * n.dims[1] * n.dims[2]);
  const double scale = slope == 0 ? 1.0 : slope;
  const double offset = slope == 0 ? 0.0 : inter;
  in.seekg(static_cast<std::streamoff>(voxOffset));
  auto readAll = [&](auto sample) {
    std::vector<decltype(sample)> raw(count);
    if (!in.read(reinterpret_cast<char*>(raw.data()),
                 static_cast<std::streamsize>(count * sizeof sample))) {
      return false;
    }
    n.values.resize(count);
    for (std::size_t i = 0; i < count; ++i) n.values[i] = scale * raw[i] + offset;
    return true;
  };
  bool ok = false;
  switch (datatype) {
    case 2: ok = readAll(uint8_t{}); break;
    case 4: ok = readAll(int16_t{}); break;
    case 8: ok = readAll(int32_t{}); break;
    case 16: ok = readAll(float{}); break;
    case 512: ok = readAll(uint16_t{}); break;
    default: why = fmt::format("datatype {} not handled by the test", datatype); return std::nullopt;
  }
  if (!ok) {
    why = "truncated voxel data";
    return std::nullopt;
  }
  return n;
}

TEST_P(PhilipsAxial, AgreesWithDcm2niixWhereDcm2niixAgreesWithTheAttributes) {
  const AxialCase& c = GetParam();
  if (std::system("dcm2niix -h > /dev/null 2>&1") != 0) {
    GTEST_SKIP() << "skipped: dcm2niix is not installed (Debian package dcm2niix)";
  }
  const fs::path out = test::freshTempDir("dcm2niix");
  const std::string command = fmt::format("dcm2niix -z n -f %s -o '{}' '{}' > '{}' 2>&1",
                                          out.string(), (test::philipsDir() / c.folder).string(),
                                          (out / "dcm2niix.log").string());
  ASSERT_EQ(std::system(command.c_str()), 0) << command;
  const LoadedVolume& volume = PhilipsData::volume(c.folder);

  int filesCompared = 0;
  bool exactFileFound = false;
  for (const auto& entry : fs::directory_iterator(out)) {
    if (entry.path().extension() != ".nii") continue;
    std::string why;
    const auto nifti = readNifti(entry.path(), why);
    if (!nifti) {
      ADD_FAILURE() << entry.path().string() << ": " << why;
      continue;
    }
    ++filesCompared;
    // Random voxel centres of dcm2niix's grid, RAS -> LPS, into our index space.
    std::mt19937 rng(7);
    std::uniform_int_distribution<int64_t> di(0, nifti->dims[0] - 1), dj(0, nifti->dims[1] - 1),
        dk(0, nifti->dims[2] - 1);
    int inside = 0, onOurGrid = 0, equal = 0, withinOne = 0;
    double maxDifference = 0;
    const int samples = 20000;
    for (int s = 0; s < samples; ++s) {
      const int64_t i = di(rng), j = dj(rng), k = dk(rng);
      double ras[3];
      for (int r = 0; r < 3; ++r) {
        ras[r] = nifti->srow[r][0] * i + nifti->srow[r][1] * j + nifti->srow[r][2] * k +
                 nifti->srow[r][3];
      }
      const Vec3 index = volume.indexFromPatient.transformPoint({-ras[0], -ras[1], ras[2]});
      if (!volume.inside(index)) continue;
      ++inside;
      // sform is float32: positions carry ~1e-5 relative error, so allow 2e-3 voxel.
      const bool integral = std::abs(index.x - std::round(index.x)) < 2e-3 &&
                            std::abs(index.y - std::round(index.y)) < 2e-3 &&
                            std::abs(index.z - std::round(index.z)) < 2e-3;
      const double ours = integral ? volume.at(std::llround(index.x), std::llround(index.y),
                                               std::llround(index.z))
                                   : volume.sample(index);
      const double difference = std::abs(ours - nifti->at(i, j, k));
      onOurGrid += integral;
      equal += difference == 0;
      withinOne += difference <= 1.0;
      maxDifference = std::max(maxDifference, difference);
    }
    const double agreement = inside ? static_cast<double>(withinOne) / inside : 0;
    std::cout << fmt::format("[{}] dcm2niix {}: {} of {} samples inside our grid, {} on our "
                             "voxel centres, {} equal, {:.2f}% within 1 HU, max difference {} "
                             "HU\n", c.folder, entry.path().filename().string(), inside,
                             samples, onOurGrid, equal, 100 * agreement, maxDifference);
    if (!c.tilted) {
      // Untilted, evenly spaced: same grid (up to axis flips), same values, exactly.
      EXPECT_EQ(inside, samples) << entry.path().filename();
      EXPECT_EQ(onOurGrid, inside) << entry.path().filename();
      EXPECT_EQ(equal, inside) << entry.path().filename() << ": max difference "
                               << maxDifference << " HU";
      exactFileFound = true;
    } else if (agreement < 0.99) {
      // Our volume was checked against the DICOM attributes pixel by pixel above; where
      // dcm2niix puts different values at the same patient positions, the attributes decide.
      std::cout << fmt::format("[{}] dcm2niix {} disagrees with the DICOM attributes (its "
                               "geometry or tilt correction differs from ImagePositionPatient/"
                               "ImageOrientationPatient); the attributes decide, and our "
                               "volume agrees with them\n",
                               c.folder, entry.path().filename().string());
    }
  }
  // dcm2niix's own account of the tilt. Debian's v1.0.20220720 logs opposite signs for
  // 0018,1120 and its estimate from the slice positions on both tilted series; its corrected
  // S21610/S2010 agrees with the attributes, its S21610/S3010 outputs do not.
  std::ifstream log(out / "dcm2niix.log");
  for (std::string line; std::getline(log, line);) {
    if (line.find("Tilt") != std::string::npos || line.find("tilt") != std::string::npos) {
      std::cout << "[" << c.folder << "] dcm2niix says: " << line << "\n";
    }
  }
  EXPECT_GT(filesCompared, 0) << "dcm2niix wrote no NIfTI; see " << (out / "dcm2niix.log");
  if (!c.tilted) {
    EXPECT_TRUE(exactFileFound);
  }
}

}  // namespace
}  // namespace octoray
