// vdb-sample-check: checks an exported .vdb against the volume it came from, at random voxels,
// through OpenVDB's own reader with delayed loading (only the leaves it touches are read), so
// that an export too large to read back whole can still be checked. The volume is streamed a
// slab at a time through octoray's readers; in each slab, SAMPLES / slabs voxels drawn with a
// fixed seed must be active with the volume's value where it is >= THRESHOLD, and inactive with
// the background (-1000) elsewhere. Exits 1 on any mismatch.
//
// Usage: vdb-sample-check EXPORT.vdb VOLUME [--samples N] [--threshold HU]

#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>

#include <algorithm>
#include <cstdint>
#include <iostream>
#include <random>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <CLI/CLI.hpp>

#include "cli_checks.h"
#include "octoray/core/error.h"
#include "octoray/dicom/formats.h"
#include "octoray/dicom/vdb.h"

int main(int argc, char** argv) {
  CLI::App app{"Checks an exported .vdb against its volume at random voxels."};
  std::string vdbPath, volumePath;
  int64_t samples = 2'000'000;
  double threshold = -900;
  app.add_option("vdb", vdbPath, "the export")->required();
  app.add_option("volume", volumePath, "the volume it was exported from")->required();
  app.add_option("--samples", samples, "voxels to check")->check(octoray::cli::kPositive);
  app.add_option("--threshold", threshold, "the export's --vdb-threshold (HU)");
  CLI11_PARSE(app, argc, argv);
  try {
    openvdb::initialize();
    openvdb::io::File file(vdbPath);
    file.open(/*delayLoad=*/true);
    const auto grid =
        openvdb::gridPtrCast<openvdb::FloatGrid>(file.readGrid(octoray::kVdbGridName));
    if (!grid) throw octoray::Error(vdbPath, "no float grid named density");
    const auto accessor = grid->getConstAccessor();

    const auto source = octoray::openVolume(volumePath);
    const auto& dims = source->info().dims;
    const int64_t slabSlices = 8, slabs = (dims[2] + slabSlices - 1) / slabSlices;
    const int64_t perSlab = std::max<int64_t>(1, samples / slabs);
    std::mt19937_64 random(20261206);
    std::vector<float> slab(static_cast<std::size_t>(dims[0] * dims[1] * slabSlices));
    int64_t checked = 0, active = 0, wrong = 0;
    for (int64_t z0 = 0; z0 < dims[2]; z0 += slabSlices) {
      const int64_t count = std::min(slabSlices, dims[2] - z0);
      source->readSlab(z0, count,
                       {slab.data(), static_cast<std::size_t>(dims[0] * dims[1] * count)});
      for (int64_t s = 0; s < perSlab; ++s) {
        const auto i = static_cast<int64_t>(random() % static_cast<uint64_t>(dims[0]));
        const auto j = static_cast<int64_t>(random() % static_cast<uint64_t>(dims[1]));
        const auto k = static_cast<int64_t>(random() % static_cast<uint64_t>(count));
        const float v = slab[static_cast<std::size_t>((k * dims[1] + j) * dims[0] + i)];
        const bool on = static_cast<double>(v) >= threshold;
        const openvdb::Coord ijk(static_cast<int>(i), static_cast<int>(j),
                                 static_cast<int>(z0 + k));
        if (accessor.isValueOn(ijk) != on ||
            accessor.getValue(ijk) != (on ? v : octoray::kVdbBackground)) {
          if (++wrong <= 5) {
            std::cerr << fmt::format("voxel ({}, {}, {}): volume {}, vdb {} ({})\n", i, j, z0 + k,
                                     v, accessor.getValue(ijk),
                                     accessor.isValueOn(ijk) ? "active" : "inactive");
          }
        }
        active += on;
        ++checked;
      }
    }
    fmt::print("{} voxels checked ({} active), {} wrong; the grid: {} leaves, {} active voxels\n",
               checked, active, wrong, grid->tree().leafCount(), grid->activeVoxelCount());
    return wrong == 0 ? 0 : 1;
  } catch (const std::exception& e) {
    std::cerr << "vdb-sample-check: " << e.what() << "\n";
    return 1;
  }
}
