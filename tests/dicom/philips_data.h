#pragma once
// What tests/dicom/data_philips.cpp and data_philips_dcm2niix.cpp share: the four axial series
// of ../shared/data/Philips as test parameters, and one scan of the folder with the volumes
// opened from it, read whole (through our scanner and reader, for random access in checks).

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <ostream>
#include <span>
#include <string>
#include <vector>

#include "octoray/core/error.h"
#include "octoray/dicom/dicom_series.h"
#include "octoray/dicom/dicom_volume.h"
#include "test_paths.h"

namespace octoray::philips_test {

namespace fs = std::filesystem;
using dicom::DicomScan;

// The axial series of both sessions (data/README.md).
struct AxialCase {
  const char* folder;
  int images;
  bool tilted;
};
// Names the case in test listings (ctest shows GetParam() through this).
inline void PrintTo(const AxialCase& c, std::ostream* os) { *os << c.folder; }

inline constexpr AxialCase kAxialCases[] = {
    {"S21570/S2010", 28, false},
    {"S21570/S2020", 140, false},
    {"S21610/S2010", 54, true},
    {"S21610/S3010", 58, true},
};

// The image files of one series folder (everything but Philips' DIRFILE), sorted by name.
inline std::vector<fs::path> imageFiles(const fs::path& folder) {
  std::vector<fs::path> files;
  for (const auto& entry : fs::directory_iterator(folder)) {
    if (entry.is_regular_file() && entry.path().filename() != "DIRFILE") {
      files.push_back(entry.path());
    }
  }
  std::sort(files.begin(), files.end());
  return files;
}

inline bool isUnder(const fs::path& file, const fs::path& folder) {
  const auto f = fs::weakly_canonical(file).string();
  const auto d = fs::weakly_canonical(folder).string() + "/";
  return f.compare(0, d.size(), d) == 0;
}

// Indices of the series with frames in `folder`.
inline std::vector<std::size_t> seriesTouching(const DicomScan& scan, const fs::path& folder) {
  std::vector<std::size_t> found;
  for (std::size_t s = 0; s < scan.series.size(); ++s) {
    const auto& frames = scan.series[s].frames;
    if (std::any_of(frames.begin(), frames.end(),
                    [&](const auto& f) { return isUnder(f.path, folder); })) {
      found.push_back(s);
    }
  }
  return found;
}

// Index of the one series that holds exactly the frames of `folder`; fails the test otherwise.
inline std::optional<std::size_t> seriesIn(const DicomScan& scan, const fs::path& folder) {
  const auto found = seriesTouching(scan, folder);
  EXPECT_EQ(found.size(), 1u) << found.size() << " series hold files of " << folder.string();
  if (found.size() != 1) return std::nullopt;
  const auto& frames = scan.series[found.front()].frames;
  EXPECT_TRUE(std::all_of(frames.begin(), frames.end(),
                          [&](const auto& f) { return isUnder(f.path, folder); }))
      << "the series of " << folder.string() << " also holds files from elsewhere";
  return found.front();
}

// A whole volume read through readSlab, for random access in checks.
struct LoadedVolume {
  VolumeInfo info;
  Mat4 indexFromPatient;
  std::vector<float> values;

  float at(int64_t i, int64_t j, int64_t k) const {
    return values[static_cast<std::size_t>((k * info.dims[1] + j) * info.dims[0] + i)];
  }
  // Inside the grid, up to `marginVoxels` (positions from DS strings and float32 sforms are
  // not exact).
  bool inside(Vec3 index, double marginVoxels = 2e-3) const {
    for (int a = 0; a < 3; ++a) {
      if (index[a] < -marginVoxels ||
          index[a] > static_cast<double>(info.dims[a] - 1) + marginVoxels) {
        return false;
      }
    }
    return true;
  }
  // Trilinear interpolation at a continuous index inside the grid.
  double sample(Vec3 index) const {
    int64_t base[3];
    double frac[3];
    for (int a = 0; a < 3; ++a) {
      const double x = std::clamp(index[a], 0.0, static_cast<double>(info.dims[a] - 1));
      base[a] = std::min<int64_t>(static_cast<int64_t>(std::floor(x)), info.dims[a] - 1);
      frac[a] = x - static_cast<double>(base[a]);
      if (base[a] == info.dims[a] - 1) frac[a] = 0;
    }
    double sum = 0;
    for (int corner = 0; corner < 8; ++corner) {
      double w = 1;
      int64_t c[3];
      for (int a = 0; a < 3; ++a) {
        const bool high = (corner >> a) & 1;
        w *= high ? frac[a] : 1 - frac[a];
        c[a] = base[a] + (high ? 1 : 0);
      }
      if (w > 0) sum += w * at(c[0], c[1], c[2]);
    }
    return sum;
  }
};

inline LoadedVolume loadVolume(VolumeSource& source) {
  LoadedVolume v;
  v.info = source.info();
  v.indexFromPatient = v.info.patientFromIndex.inverseAffine();
  v.values.resize(static_cast<std::size_t>(v.info.sampleCount()));
  const int64_t slab = 16;
  for (int64_t k = 0; k < v.info.dims[2]; k += slab) {
    const int64_t count = std::min(slab, v.info.dims[2] - k);
    source.readSlab(k, count,
                    std::span<float>(v.values.data() + k * v.info.sliceSamples(),
                                     static_cast<std::size_t>(count * v.info.sliceSamples())));
  }
  return v;
}

// The scan of Philips/ and the volumes opened from it, shared by the tests of this file.
class PhilipsData : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    if (fs::exists(test::philipsDir())) {
      scan_ = std::make_unique<DicomScan>(dicom::scanDicom(test::philipsDir()));
    }
  }
  static void TearDownTestSuite() {
    scan_.reset();
    volumes_.clear();
  }
  void SetUp() override { OCTORAY_REQUIRE_PATH(test::philipsDir()); }

  static const DicomScan& scan() { return *scan_; }

  static const LoadedVolume& volume(const std::string& folder) {
    auto it = volumes_.find(folder);
    if (it == volumes_.end()) {
      const auto index = seriesIn(*scan_, test::philipsDir() / folder);
      if (!index) throw Error(folder, "test: no series found");
      auto source = dicom::openDicomSeries(scan_->series[*index]);
      it = volumes_.emplace(folder, loadVolume(*source)).first;
    }
    return it->second;
  }

 private:
  static inline std::unique_ptr<DicomScan> scan_;
  static inline std::map<std::string, LoadedVolume> volumes_;
};

// The four axial series, each a test parameter (instantiated in data_philips.cpp).
class PhilipsAxial : public PhilipsData, public ::testing::WithParamInterface<AxialCase> {};

}  // namespace octoray::philips_test
