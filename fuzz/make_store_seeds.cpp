// Writes a few small valid octree stores into OUT_DIR: the seed corpus of fuzz_store_reader.
// Generated at fuzz time, so no binary file lives in the repository. Together the seeds cover
// every codec, both sample formats, both borders, gradients, constant and varying bricks.
//
//   make_store_seeds OUT_DIR

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include "octoray/core/error.h"
#include "octoray/dicom/volume_source.h"
#include "octoray/volume/store_builder.h"

namespace {

// A small smooth volume with an empty (constant) corner, in memory.
class SeedVolume final : public octoray::VolumeSource {
 public:
  SeedVolume(std::array<int64_t, 3> dims, bool hu) {
    info_.dims = dims;
    info_.format = "memory";
    info_.sourcePath = "seed";
    info_.unit = hu ? "HU" : "";
    info_.integerValues = hu;
    info_.patientFromIndex =
        octoray::Mat4::fromColumns({0.7, 0, 0}, {0, 0.7, 0}, {0, 0.2, 1.5}, {-12, 4, 90});
  }
  const octoray::VolumeInfo& info() const override { return info_; }
  void readSlab(int64_t first, int64_t count, std::span<float> out) override {
    octoray::checkSlabRequest(info_, first, count, out.size());
    std::size_t n = 0;
    for (int64_t k = first; k < first + count; ++k)
      for (int64_t j = 0; j < info_.dims[1]; ++j)
        for (int64_t i = 0; i < info_.dims[0]; ++i) {
          const bool air = i < info_.dims[0] / 2 && j < info_.dims[1] / 2;
          const double v = air ? -1000.0 : 40.0 * std::sin(0.3 * double(i + 2 * j)) + 7.0 * double(k);
          out[n++] = static_cast<float>(info_.integerValues ? std::round(v) : v * 0.01);
        }
  }

 private:
  octoray::VolumeInfo info_;
};

struct Seed {
  const char* name;
  std::array<int64_t, 3> dims;
  bool hu;
  int border;
  bool gradients;
  octoray::volume::Codec codec;
};

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: make_store_seeds OUT_DIR\n");
    return 2;
  }
  using octoray::volume::Codec;
  const std::vector<Seed> seeds = {
      {"u16-lz4", {20, 18, 9}, true, 1, false, Codec::Lz4},
      {"u16-zstd-gradients", {17, 9, 40}, true, 2, true, Codec::Zstd},
      {"u16-none", {9, 8, 7}, true, 1, false, Codec::None},
      {"f32-lz4", {18, 5, 6}, false, 1, false, Codec::Lz4},
      {"f32-zstd-gradients", {6, 17, 21}, false, 2, true, Codec::Zstd},
  };
  try {
    std::filesystem::create_directories(argv[1]);
    for (const Seed& s : seeds) {
      SeedVolume volume(s.dims, s.hu);
      octoray::volume::BuildOptions options;
      options.brickSize = 16;
      options.border = s.border;
      options.gradients = s.gradients;
      options.codec = s.codec;
      options.provenanceJson = R"({"seed":")" + std::string(s.name) + R"("})";
      const auto path = std::filesystem::path(argv[1]) / (std::string(s.name) + ".octoray");
      const auto report = octoray::volume::buildStore(volume, path.string(), options);
      std::printf("%s: %llu bytes, %lld nodes\n", path.c_str(),
                  static_cast<unsigned long long>(report.bytesOnDisk),
                  static_cast<long long>(report.nodes));
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "make_store_seeds: %s\n", e.what());
    return 1;
  }
  return 0;
}
