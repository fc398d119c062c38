// Export of any VolumeSource as an OpenVDB float grid, built slab by slab (each slab one layer of
// 8x8x8 leaf nodes) and written through a temporary file.

#include "octoray/dicom/vdb.h"

#include <unistd.h>

#include <openvdb/io/Archive.h>
#include <openvdb/openvdb.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <mutex>
#include <vector>

#include <fmt/format.h>

#include "octoray/core/error.h"

namespace octoray {

namespace {

namespace fs = std::filesystem;
using LeafT = openvdb::FloatTree::LeafNodeType;
constexpr int64_t kLeafDim = LeafT::DIM;  // 8: a slab is one layer of leaves
static_assert(kLeafDim == 8);

void initializeOpenVdb() {
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });
}

// OpenVDB's matrices act on row vectors (translation in the last row): the transpose of our
// column-vector patientFromIndex.
openvdb::math::Transform::Ptr gridTransform(const Mat4& patientFromIndex) {
  openvdb::math::Mat4d worldFromIndex;
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) worldFromIndex(r, c) = patientFromIndex.m[c][r];
  }
  return openvdb::math::Transform::createLinearTransform(worldFromIndex);
}

// One 8x8x8 block of a slab: nothing (all below the threshold), a leaf, or, where all 512
// samples are active and equal, an active tile in place of the leaf.
struct Block {
  std::unique_ptr<LeafT> leaf;
  bool tile = false;
  float tileValue = 0;
  int64_t active = 0;
};

Block buildBlock(std::span<const float> slab, const std::array<int64_t, 3>& dims, int64_t x0,
                 int64_t y0, int64_t z0, int64_t sliceCount, double threshold) {
  Block block;
  const int64_t nx = std::min(kLeafDim, dims[0] - x0), ny = std::min(kLeafDim, dims[1] - y0);
  for (int64_t z = 0; z < sliceCount; ++z) {
    for (int64_t y = 0; y < ny; ++y) {
      const float* row = slab.data() + (z * dims[1] + y0 + y) * dims[0] + x0;
      for (int64_t x = 0; x < nx; ++x) {
        if (!(static_cast<double>(row[x]) >= threshold)) continue;
        if (!block.leaf) {
          block.leaf = std::make_unique<LeafT>(
              openvdb::Coord(static_cast<int>(x0), static_cast<int>(y0), static_cast<int>(z0)),
              kVdbBackground, false);
        }
        // A leaf stores z fastest: offset = x * 64 + y * 8 + z.
        block.leaf->setValueOn(static_cast<openvdb::Index>((x << 6) + (y << 3) + z), row[x]);
        ++block.active;
      }
    }
  }
  if (block.active == static_cast<int64_t>(LeafT::SIZE)) {
    const float* values = block.leaf->buffer().data();
    const auto first = std::bit_cast<uint32_t>(values[0]);
    if (std::all_of(values, values + LeafT::SIZE,
                    [&](float v) { return std::bit_cast<uint32_t>(v) == first; })) {
      block.tile = true;
      block.tileValue = values[0];
      block.leaf.reset();
    }
  }
  return block;
}

// io::File::write does not check the stream after writing; this writes the same seekable
// layout to a stream we check, so a full disk is an error rather than a truncated file.
class CheckedVdbWriter final : public openvdb::io::Archive {
 public:
  void writeTo(std::ostream& out, const openvdb::GridCPtrVec& grids) const {
    Archive::write(out, grids, /*seekable=*/true);
  }
};

// Removes the temporary file unless the export completed.
struct TempFileGuard {
  std::string path;
  bool keep = false;
  ~TempFileGuard() {
    if (!keep) {
      std::error_code ec;
      fs::remove(path, ec);
    }
  }
};

void addMetadata(openvdb::FloatGrid& grid, const VolumeInfo& info, double threshold) {
  grid.setName(kVdbGridName);
  grid.setCreator("octoray");
  // Not GRID_FOG_VOLUME: a fog volume means densities in [0, 1] over a zero background, and
  // HU are negative down to the background of -1000.
  grid.setGridClass(openvdb::GRID_UNKNOWN);
  grid.insertMeta(vdb_meta::kCoordinates, openvdb::StringMetadata("LPS"));
  grid.insertMeta(vdb_meta::kUnits, openvdb::StringMetadata("mm"));
  grid.insertMeta(vdb_meta::kValueUnit, openvdb::StringMetadata(info.unit));
  grid.insertMeta(vdb_meta::kThreshold, openvdb::DoubleMetadata(threshold));
  grid.insertMeta(vdb_meta::kDescription, openvdb::StringMetadata(info.description));
  grid.insertMeta(vdb_meta::kModality, openvdb::StringMetadata(info.modality));
  grid.insertMeta(vdb_meta::kIndexMin, openvdb::Vec3IMetadata(openvdb::Vec3i(0, 0, 0)));
  grid.insertMeta(vdb_meta::kIndexMax,
                  openvdb::Vec3IMetadata(openvdb::Vec3i(static_cast<int>(info.dims[0] - 1),
                                                        static_cast<int>(info.dims[1] - 1),
                                                        static_cast<int>(info.dims[2] - 1))));
}

// Builds the sparse grid, one slab of kLeafDim slices at a time; the dense volume is never held.
openvdb::FloatGrid::Ptr buildGrid(VolumeSource& source, const VdbExportOptions& options,
                                  int64_t& activeVoxels) {
  const VolumeInfo& info = source.info();
  const auto& dims = info.dims;
  auto grid = openvdb::FloatGrid::create(kVdbBackground);
  openvdb::FloatTree& tree = grid->tree();
  const int64_t blocksX = (dims[0] + kLeafDim - 1) / kLeafDim;
  const int64_t blocksY = (dims[1] + kLeafDim - 1) / kLeafDim;
  std::vector<float> slab(static_cast<std::size_t>(info.sliceSamples() * std::min(dims[2], kLeafDim)));
  std::vector<Block> blocks(static_cast<std::size_t>(blocksX * blocksY));
  activeVoxels = 0;
  for (int64_t z0 = 0; z0 < dims[2]; z0 += kLeafDim) {
    const int64_t count = std::min(kLeafDim, dims[2] - z0);
    std::span<float> values(slab.data(), static_cast<std::size_t>(info.sliceSamples() * count));
    source.readSlab(z0, count, values);
    tbb::parallel_for(int64_t{0}, blocksY, [&](int64_t by) {
      for (int64_t bx = 0; bx < blocksX; ++bx) {
        blocks[static_cast<std::size_t>(by * blocksX + bx)] =
            buildBlock(values, dims, bx * kLeafDim, by * kLeafDim, z0, count, options.thresholdHu);
      }
    });
    // Trees are not thread-safe to modify: the blocks go in one by one.
    for (int64_t n = 0; n < blocksX * blocksY; ++n) {
      Block& block = blocks[static_cast<std::size_t>(n)];
      activeVoxels += block.active;
      if (block.leaf) {
        tree.addLeaf(block.leaf.release());
      } else if (block.tile) {
        const openvdb::Coord origin(static_cast<int>((n % blocksX) * kLeafDim),
                                    static_cast<int>((n / blocksX) * kLeafDim),
                                    static_cast<int>(z0));
        tree.addTile(/*level=*/1, origin, block.tileValue, /*active=*/true);  // leaf-sized tile
      }
      block = Block{};
    }
    if (options.progress) options.progress(z0 + count, dims[2]);
  }
  return grid;
}

}  // namespace

VdbExportReport exportVdb(VolumeSource& source, const std::string& path,
                          const VdbExportOptions& options) {
  const VolumeInfo& info = source.info();
  for (int64_t d : info.dims) {
    if (d < 1 || d > std::numeric_limits<int32_t>::max()) {
      throw Error(path, fmt::format("OpenVDB cannot hold dimensions {}x{}x{} (each 1..2^31-1)",
                                    info.dims[0], info.dims[1], info.dims[2]));
    }
  }
  if (!std::isfinite(options.thresholdHu)) throw Error(path, "the VDB threshold must be finite");
  initializeOpenVdb();

  VdbExportReport report;
  const fs::path target(path);
  TempFileGuard temp{
      (target.parent_path() / fmt::format(".{}.partial-{}", target.filename().string(),
                                          static_cast<long>(::getpid())))
          .string()};
  try {
    openvdb::FloatGrid::Ptr grid = buildGrid(source, options, report.activeVoxels);
    if (report.activeVoxels == 0) {
      throw Error(path, fmt::format("no sample is at or above the threshold {} {}: the grid would "
                                    "be empty (lower the threshold)",
                                    options.thresholdHu, info.unit));
    }
    grid->setTransform(gridTransform(info.patientFromIndex));
    addMetadata(*grid, info, options.thresholdHu);

    std::ofstream out(temp.path, std::ios::binary | std::ios::trunc);
    if (!out) throw Error(path, "cannot create the temporary output file " + temp.path);
    CheckedVdbWriter().writeTo(out, openvdb::GridCPtrVec{grid});
    out.flush();
    if (!out) throw Error(path, "write failed (disk full?)");
    out.close();
    if (out.fail()) throw Error(path, "write failed while closing the file (disk full?)");
  } catch (const openvdb::Exception& e) {
    throw Error(path, fmt::format("OpenVDB: {}", e.what()));
  }

  std::error_code ec;
  report.bytesOnDisk = fs::file_size(temp.path, ec);
  fs::rename(temp.path, path, ec);
  if (ec) throw Error(path, "cannot move the finished file into place: " + ec.message());
  temp.keep = true;
  return report;
}

}  // namespace octoray
