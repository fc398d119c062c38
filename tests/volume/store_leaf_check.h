#pragma once
// Compares every leaf brick's interior samples of a store with the source it was built from.

#include <gtest/gtest.h>

#include <vector>

#include "octoray/dicom/volume_source.h"
#include "octoray/volume/store_reader.h"
#include "octoray/volume/store_validator.h"

namespace octoray::test {

// Reads the source slab by slab (one brick row at a time) and checks that each leaf brick's
// interior holds exactly the source's physical values. Returns the number of samples checked.
inline int64_t expectLeavesEqualSource(VolumeSource& source, const volume::StoreReader& store) {
  using namespace volume;
  const OctreeLayout& layout = store.layout();
  const int leaf = layout.leafLevel();
  const Index3 dims = layout.levelDims(leaf);
  const Index3 bricks = layout.levelBricks(leaf);
  const int64_t B = layout.brickSize(), A = layout.border(), E = layout.storedEdge();
  int64_t checked = 0;
  std::vector<float> slab;
  for (int64_t bz = 0; bz < bricks[2]; ++bz) {
    const int64_t z0 = bz * B, nz = std::min(B, dims[2] - z0);
    slab.resize(static_cast<std::size_t>(source.info().sliceSamples() * nz));
    source.readSlab(z0, nz, slab);
    for (int64_t by = 0; by < bricks[1]; ++by)
      for (int64_t bx = 0; bx < bricks[0]; ++bx) {
        const int64_t id = layout.nodeId({leaf, {bx, by, bz}});
        const Brick brick = store.readBrick(id);
        for (int64_t z = 0; z < nz; ++z)
          for (int64_t y = by * B; y < std::min((by + 1) * B, dims[1]); ++y)
            for (int64_t x = bx * B; x < std::min((bx + 1) * B, dims[0]); ++x) {
              const std::size_t s = static_cast<std::size_t>((x - bx * B + A) + E * ((y - by * B + A) + E * (z + A)));
              const double stored = brick.format == SampleFormat::UInt16 ? brick.u16[s] : brick.f32[s];
              const double expected = slab[static_cast<std::size_t>(x + dims[0] * (y + dims[1] * z))];
              if (store.physical(stored) != expected) {
                ADD_FAILURE() << "leaf sample (" << x << ", " << y << ", " << z0 + z << ") is "
                              << store.physical(stored) << ", the source has " << expected;
                return checked;
              }
              ++checked;
            }
      }
  }
  return checked;
}

// Every store a test builds must also pass octoray-validate's checks.
inline void expectStoreValid(const std::string& path) {
  const volume::ValidationReport report = volume::validateStore(path);
  for (const auto& check : report.checks) {
    EXPECT_TRUE(check.passed()) << path << ": check " << check.name << " failed"
                                << (check.failures.empty() ? "" : ": " + check.failures[0].message);
  }
  EXPECT_TRUE(report.passed()) << path;
}

}  // namespace octoray::test
