// Export of any VolumeSource as an OpenVDB float grid, read slab by slab (each slab one layer of
// 8x8x8 leaf nodes) and written through a temporary file, without holding the grid in memory
// (see "Memory holds neither the grid's values nor its topology" below).

#include "octoray/core/atomic_file.h"
#include "octoray/dicom/vdb.h"

#include <unistd.h>

#include <openvdb/io/Archive.h>
#include <openvdb/io/Compression.h>
#include <openvdb/io/DelayedLoadMetadata.h>
#include <openvdb/io/GridDescriptor.h>
#include <openvdb/openvdb.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <ios>
#include <limits>
#include <memory>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <vector>

#include <fmt/format.h>

#include "octoray/core/error.h"

namespace octoray {

namespace {

namespace fs = std::filesystem;
using LeafT = openvdb::FloatTree::LeafNodeType;
using UpperT = openvdb::FloatTree::RootNodeType::ChildNodeType;  // 4096^3 voxels
using LowerT = UpperT::ChildNodeType;                            // 128^3 voxels
constexpr int64_t kLeafDim = LeafT::DIM;                         // 8: a slab is one layer of leaves
constexpr int64_t kLowerLeaves = LowerT::DIM / LeafT::DIM;       // 16 per axis
constexpr int64_t kUpperLowers = UpperT::DIM / LowerT::DIM;      // 32 per axis
static_assert(kLeafDim == 8 && kLowerLeaves == 16 && kUpperLowers == 32);

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

// Memory holds neither the grid's values nor its topology, so that a volume larger than memory
// can be exported. OpenVDB writes a grid as its metadata, its transform, its topology (node masks
// and tile values, from the root down) and then one block per leaf, in the same depth-first
// order; io::Archive writes only a grid held wholly in memory. So the export runs in two passes:
//  1. slab by slab, each 8x8x8 block that has a leaf is serialised by LeafNode::writeBuffers
//     (its value mask, then its compressed values) into a spill file beside the target, and a
//     leaf-sized tile's value goes there too; memory keeps 9 bytes per block (where its bytes
//     start, and how its values were laid out) and the statistics OpenVDB writes;
//  2. the file is written as Archive::write writes one grid: header, descriptor, metadata and
//     transform by OpenVDB's own code; the topology one 128^3 node at a time, each built from its
//     leaves' value masks read back from the spill file and written by
//     InternalNode::writeTopology, inside the root and 4096^3 nodes' own records; then the leaf
//     blocks, copied from the spill file. The bytes are those io::File writes for the same grid
//     (tests/dicom/unit_vdb.cpp compares them).

// How a block's values went to the spill file: io::MaskCompress's metadata byte (0..6) for a
// leaf, or a tile (its value, 4 bytes).
constexpr int8_t kTileBlock = 127;

// One 8x8x8 block of a slab: nothing (all below the threshold), a leaf's serialised block, or,
// where all 512 samples are active and equal, an active tile.
struct Block {
  std::string bytes;  // LeafNode::writeBuffers of the leaf, or the tile's value
  int8_t layout = 0;
  int64_t active = 0;
  openvdb::CoordBBox activeBox;  // of its active samples
};

// The stream state LeafNode::writeBuffers and InternalNode::writeTopology read: the grid's
// compression flags and background.
const float kBackgroundValue = kVdbBackground;
void prepareStream(std::ios_base& stream, uint32_t compression) {
  openvdb::io::setDataCompression(stream, compression);
  openvdb::io::setGridBackgroundValuePtr(stream, &kBackgroundValue);
}

Block buildBlock(std::span<const float> slab, const std::array<int64_t, 3>& dims, int64_t x0,
                 int64_t y0, int64_t z0, int64_t sliceCount, double threshold,
                 uint32_t compression) {
  Block block;
  const openvdb::Coord origin(static_cast<int>(x0), static_cast<int>(y0), static_cast<int>(z0));
  std::unique_ptr<LeafT> leaf;
  const int64_t nx = std::min(kLeafDim, dims[0] - x0), ny = std::min(kLeafDim, dims[1] - y0);
  for (int64_t z = 0; z < sliceCount; ++z) {
    for (int64_t y = 0; y < ny; ++y) {
      const float* row = slab.data() + (z * dims[1] + y0 + y) * dims[0] + x0;
      for (int64_t x = 0; x < nx; ++x) {
        if (!(static_cast<double>(row[x]) >= threshold)) continue;
        if (!leaf) leaf = std::make_unique<LeafT>(origin, kVdbBackground, false);
        // A leaf stores z fastest: offset = x * 64 + y * 8 + z.
        leaf->setValueOn(static_cast<openvdb::Index>((x << 6) + (y << 3) + z), row[x]);
        block.activeBox.expand(
            origin.offsetBy(static_cast<int>(x), static_cast<int>(y), static_cast<int>(z)));
        ++block.active;
      }
    }
  }
  if (!leaf) return block;
  if (block.active == static_cast<int64_t>(LeafT::SIZE)) {
    const float* values = leaf->buffer().data();
    const auto first = std::bit_cast<uint32_t>(values[0]);
    if (std::all_of(values, values + LeafT::SIZE,
                    [&](float v) { return std::bit_cast<uint32_t>(v) == first; })) {
      block.layout = kTileBlock;
      block.bytes.assign(reinterpret_cast<const char*>(values), sizeof(float));
      return block;
    }
  }
  std::ostringstream bytes(std::ios::binary);
  prepareStream(bytes, compression);
  leaf->writeBuffers(bytes, /*toHalf=*/false);
  block.bytes = std::move(bytes).str();
  // The block is the value mask, then writeCompressedValues' layout byte (with
  // COMPRESS_ACTIVE_MASK), inactive values, a selection mask, and the values.
  if (compression & openvdb::io::COMPRESS_ACTIVE_MASK) {
    block.layout = static_cast<int8_t>(block.bytes.at(LeafT::NodeMaskType::memUsage()));
  }
  return block;
}

// Removes a file it names unless told to keep it.
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

// Pass 1's result: where each 8x8x8 block's bytes lie in the spill file (blocks numbered x
// fastest, then y, then z; block n's bytes are [start[n], start[n + 1]), empty where it has no
// leaf and no tile) and what the grid's metadata needs.
struct SpilledGrid {
  std::array<int64_t, 3> blocks{};  // per axis
  std::vector<uint64_t> start;
  std::vector<int8_t> layout;       // per block
  std::array<int64_t, 3> lowers{};  // 128^3 nodes per axis
  std::vector<bool> lowerUsed;      // holds a leaf or a tile
  int64_t leafCount = 0;
  int64_t activeVoxels = 0;
  openvdb::CoordBBox activeBox;

  std::size_t blockIndex(int64_t bx, int64_t by, int64_t bz) const {
    return static_cast<std::size_t>((bz * blocks[1] + by) * blocks[0] + bx);
  }
  std::size_t lowerIndex(int64_t lx, int64_t ly, int64_t lz) const {
    return static_cast<std::size_t>((lz * lowers[1] + ly) * lowers[0] + lx);
  }
  bool isLeaf(std::size_t n) const { return start[n + 1] > start[n] && layout[n] != kTileBlock; }
  bool isTile(std::size_t n) const { return start[n + 1] > start[n] && layout[n] == kTileBlock; }
};

// Pass 1, one slab of kLeafDim slices at a time; the dense volume is never held.
SpilledGrid spillGrid(VolumeSource& source, const VdbExportOptions& options, uint32_t compression,
                      std::ostream& spill) {
  const VolumeInfo& info = source.info();
  const auto& dims = info.dims;
  SpilledGrid result;
  for (int a = 0; a < 3; ++a) {
    result.blocks[a] = (dims[a] + kLeafDim - 1) / kLeafDim;
    result.lowers[a] = (result.blocks[a] + kLowerLeaves - 1) / kLowerLeaves;
  }
  result.lowerUsed.assign(
      static_cast<std::size_t>(result.lowers[0] * result.lowers[1] * result.lowers[2]), false);
  const int64_t blocksX = result.blocks[0], blocksY = result.blocks[1];
  result.start.reserve(static_cast<std::size_t>(blocksX * blocksY * result.blocks[2] + 1));
  result.layout.reserve(static_cast<std::size_t>(blocksX * blocksY * result.blocks[2]));
  std::vector<float> slab(
      static_cast<std::size_t>(info.sliceSamples() * std::min(dims[2], kLeafDim)));
  // A slab's blocks are built and spilled a band of rows at a time, so that the serialised
  // blocks waiting for the spill file stay a few MiB however wide the slices are.
  constexpr int64_t kBandRows = 16;
  std::vector<Block> blocks(static_cast<std::size_t>(blocksX * std::min(blocksY, kBandRows)));
  uint64_t spilled = 0;
  for (int64_t z0 = 0; z0 < dims[2]; z0 += kLeafDim) {
    const int64_t count = std::min(kLeafDim, dims[2] - z0);
    std::span<float> values(slab.data(), static_cast<std::size_t>(info.sliceSamples() * count));
    source.readSlab(z0, count, values);
    for (int64_t band = 0; band < blocksY; band += kBandRows) {
      const int64_t rows = std::min(kBandRows, blocksY - band);
      tbb::parallel_for(int64_t{0}, rows, [&](int64_t row) {
        for (int64_t bx = 0; bx < blocksX; ++bx) {
          blocks[static_cast<std::size_t>(row * blocksX + bx)] =
              buildBlock(values, dims, bx * kLeafDim, (band + row) * kLeafDim, z0, count,
                         options.thresholdHu, compression);
        }
      });
      // The blocks go to the spill file in block order.
      for (int64_t n = 0; n < rows * blocksX; ++n) {
        Block& block = blocks[static_cast<std::size_t>(n)];
        result.start.push_back(spilled);
        result.layout.push_back(block.layout);
        if (!block.bytes.empty()) {
          spill.write(block.bytes.data(), static_cast<std::streamsize>(block.bytes.size()));
          spilled += block.bytes.size();
          result.leafCount += block.layout != kTileBlock;
          result.activeVoxels += block.active;
          result.activeBox.expand(block.activeBox);
          result.lowerUsed[result.lowerIndex((n % blocksX) / kLowerLeaves,
                                             (band + n / blocksX) / kLowerLeaves,
                                             z0 / kLeafDim / kLowerLeaves)] = true;
        }
        block = Block{};
      }
    }
    if (!spill) throw std::ios_base::failure("write failed");
    if (options.progress) options.progress(z0 + count, dims[2]);
  }
  result.start.push_back(spilled);
  return result;
}

// The grid's nodes in the order OpenVDB writes them, depth first: the 4096^3 nodes in the root's
// table order (its coordinates' lexicographic order), each node's children in its child-mask
// order (x slowest, z fastest). visitUpper(origin, usedLowers) is called before the upper node's
// lowers, visitLower(lx, ly, lz) (the 128^3 node's index) before its blocks, and
// visitBlock(n, bx, by, bz) for each block that has a leaf or a tile.
template <typename Upper, typename Lower, typename Visit>
void forEachNodeInFileOrder(const SpilledGrid& g, Upper&& visitUpper, Lower&& visitLower,
                            Visit&& visitBlock) {
  std::array<int64_t, 3> uppers{};
  for (int a = 0; a < 3; ++a) uppers[a] = (g.lowers[a] + kUpperLowers - 1) / kUpperLowers;
  for (int64_t ux = 0; ux < uppers[0]; ++ux) {
    for (int64_t uy = 0; uy < uppers[1]; ++uy) {
      for (int64_t uz = 0; uz < uppers[2]; ++uz) {
        // The lowers of this upper node, in its child order.
        std::vector<std::array<int64_t, 3>> used;
        for (int64_t lx = ux * kUpperLowers; lx < std::min(g.lowers[0], (ux + 1) * kUpperLowers);
             ++lx)
          for (int64_t ly = uy * kUpperLowers; ly < std::min(g.lowers[1], (uy + 1) * kUpperLowers);
               ++ly)
            for (int64_t lz = uz * kUpperLowers;
                 lz < std::min(g.lowers[2], (uz + 1) * kUpperLowers); ++lz)
              if (g.lowerUsed[g.lowerIndex(lx, ly, lz)]) used.push_back({lx, ly, lz});
        if (used.empty()) continue;
        visitUpper(
            openvdb::Coord(static_cast<int>(ux * UpperT::DIM), static_cast<int>(uy * UpperT::DIM),
                           static_cast<int>(uz * UpperT::DIM)),
            used);
        for (const auto& [lx, ly, lz] : used) {
          visitLower(lx, ly, lz);
          for (int64_t bx = lx * kLowerLeaves; bx < std::min(g.blocks[0], (lx + 1) * kLowerLeaves);
               ++bx)
            for (int64_t by = ly * kLowerLeaves;
                 by < std::min(g.blocks[1], (ly + 1) * kLowerLeaves); ++by)
              for (int64_t bz = lz * kLowerLeaves;
                   bz < std::min(g.blocks[2], (lz + 1) * kLowerLeaves); ++bz) {
                const std::size_t n = g.blockIndex(bx, by, bz);
                if (g.start[n + 1] > g.start[n]) visitBlock(n, bx, by, bz);
              }
        }
      }
    }
  }
}

// Reads block n's first `size` bytes (or all of it) from the spill file.
class SpillReader {
 public:
  explicit SpillReader(const std::string& path) : in_(path, std::ios::binary) {
    if (!in_) throw std::ios_base::failure("cannot read back the spill file");
  }
  const std::string& read(const SpilledGrid& g, std::size_t n, uint64_t size = 0) {
    const uint64_t begin = g.start[n], end = g.start[n + 1];
    if (size == 0 || size > end - begin) size = end - begin;
    bytes_.resize(size);
    in_.seekg(static_cast<std::streamoff>(begin));
    in_.read(bytes_.data(), static_cast<std::streamsize>(size));
    if (!in_) throw std::ios_base::failure("the spill file is short");
    return bytes_;
  }

 private:
  std::ifstream in_;
  std::string bytes_;
};

// The delayed-load metadata of the leaf blocks, from their layout bytes and sizes: what
// io::Archive computes from the leaves' values (the compressed size is what follows the
// block's value mask, layout byte, inactive values and selection mask).
void describeLeafBlocks(const SpilledGrid& g, uint32_t compression,
                        openvdb::io::DelayedLoadMetadata& metadata) {
  namespace io = openvdb::io;
  if (g.leafCount == 0) return;
  const bool sized = compression & (io::COMPRESS_BLOSC | io::COMPRESS_ZIP);
  metadata.resizeMask(static_cast<std::size_t>(g.leafCount));
  if (sized) metadata.resizeCompressedSize(static_cast<std::size_t>(g.leafCount));
  std::size_t index = 0;
  auto none = [](auto&&...) {};
  forEachNodeInFileOrder(g, none, none, [&](std::size_t n, auto&&...) {
    if (!g.isLeaf(n)) return;
    const int8_t layout = g.layout[n];
    metadata.setMask(index, layout);
    if (sized) {
      const bool maskCompressed = compression & io::COMPRESS_ACTIVE_MASK;
      const int64_t inactiveValues =
          layout == io::NO_MASK_AND_ONE_INACTIVE_VAL || layout == io::MASK_AND_ONE_INACTIVE_VAL
              ? 1
              : (layout == io::MASK_AND_TWO_INACTIVE_VALS ? 2 : 0);
      const bool selectionMask = layout == io::MASK_AND_NO_INACTIVE_VALS ||
                                 layout == io::MASK_AND_ONE_INACTIVE_VAL ||
                                 layout == io::MASK_AND_TWO_INACTIVE_VALS;
      const auto maskBytes = static_cast<int64_t>(LeafT::NodeMaskType::memUsage());
      int64_t header = maskBytes;
      if (maskCompressed) {
        header += 1 + inactiveValues * static_cast<int64_t>(sizeof(float)) +
                  (selectionMask ? maskBytes : 0);
      }
      metadata.setCompressedSize(index, static_cast<int64_t>(g.start[n + 1] - g.start[n]) - header);
    }
    ++index;
  });
}

// What tools::memUsage would count for the grid with every leaf loaded.
template <typename NodeT>
constexpr int64_t internalNodeBytes() {
  return int64_t{NodeT::NUM_VALUES} * int64_t{sizeof(typename NodeT::UnionType)} +
         2 * int64_t{NodeT::NodeMaskType::memUsage()} + int64_t{sizeof(openvdb::Coord)};
}
int64_t loadedMemoryBytes(const SpilledGrid& g) {
  int64_t uppers = 0, lowers = 0;
  auto none = [](auto&&...) {};
  forEachNodeInFileOrder(
      g, [&](auto&&...) { ++uppers; }, [&](auto&&...) { ++lowers; }, none);
  return int64_t{sizeof(openvdb::FloatTree)} + int64_t{sizeof(openvdb::FloatTree::RootNodeType)} +
         uppers * internalNodeBytes<UpperT>() + lowers * internalNodeBytes<LowerT>() +
         g.leafCount * int64_t{sizeof(LeafT) + LeafT::SIZE * sizeof(float)};
}

// Tree::writeTopology of the grid, a 128^3 node at a time: the root's and each 4096^3 node's own
// records as RootNode and InternalNode write them (children only: the export makes no tiles
// above the leaf level), and each 128^3 node built from its leaves' value masks (leaves without
// values, OpenVDB's PartialCreate) and tiles, and written by InternalNode::writeTopology.
void writeTopology(const SpilledGrid& g, SpillReader& spill, std::ostream& out) {
  const int32_t bufferCount = 1;  // TreeBase::writeTopology
  out.write(reinterpret_cast<const char*>(&bufferCount), sizeof bufferCount);
  out.write(reinterpret_cast<const char*>(&kBackgroundValue), sizeof kBackgroundValue);
  openvdb::io::setGridBackgroundValuePtr(out, &kBackgroundValue);
  uint32_t upperCount = 0;
  auto none = [](auto&&...) {};
  forEachNodeInFileOrder(
      g, [&](auto&&...) { ++upperCount; }, none, none);
  const openvdb::Index tiles = 0, children = upperCount;
  out.write(reinterpret_cast<const char*>(&tiles), sizeof tiles);
  out.write(reinterpret_cast<const char*>(&children), sizeof children);

  std::unique_ptr<LowerT> lower;
  auto flushLower = [&] {
    if (lower) lower->writeTopology(out, /*toHalf=*/false);
    lower.reset();
  };
  forEachNodeInFileOrder(
      g,
      [&](const openvdb::Coord& origin, const std::vector<std::array<int64_t, 3>>& used) {
        flushLower();
        out.write(reinterpret_cast<const char*>(origin.asPointer()), 3 * sizeof(int32_t));
        UpperT::NodeMaskType childMask, valueMask;
        for (const auto& l : used) {
          childMask.setOn(UpperT::coordToOffset(openvdb::Coord(
              static_cast<int>(l[0] * LowerT::DIM), static_cast<int>(l[1] * LowerT::DIM),
              static_cast<int>(l[2] * LowerT::DIM))));
        }
        childMask.save(out);
        valueMask.save(out);
        std::vector<float> values(UpperT::NUM_VALUES);
        for (openvdb::Index i = 0; i < UpperT::NUM_VALUES; ++i) {
          values[i] = childMask.isOn(i) ? 0.0f : kVdbBackground;
        }
        openvdb::io::writeCompressedValues(out, values.data(), UpperT::NUM_VALUES, valueMask,
                                           childMask, /*toHalf=*/false);
      },
      [&](int64_t lx, int64_t ly, int64_t lz) {
        flushLower();
        lower = std::make_unique<LowerT>(
            openvdb::Coord(static_cast<int>(lx * LowerT::DIM), static_cast<int>(ly * LowerT::DIM),
                           static_cast<int>(lz * LowerT::DIM)),
            kVdbBackground, false);
      },
      [&](std::size_t n, int64_t bx, int64_t by, int64_t bz) {
        const openvdb::Coord origin(static_cast<int>(bx * kLeafDim),
                                    static_cast<int>(by * kLeafDim),
                                    static_cast<int>(bz * kLeafDim));
        if (g.isTile(n)) {
          float value;
          std::memcpy(&value, spill.read(g, n).data(), sizeof value);
          lower->addTile(/*level=*/1, origin, value, /*active=*/true);  // leaf-sized
          return;
        }
        auto leaf =
            std::make_unique<LeafT>(openvdb::PartialCreate(), origin, kVdbBackground, false);
        std::istringstream mask(spill.read(g, n, LeafT::NodeMaskType::memUsage()));
        leaf->getValueMask().load(mask);
        lower->addLeaf(leaf.release());
      });
  flushLower();
}

// The leaf blocks, copied from the spill file in the order Tree::writeBuffers writes them.
void copyLeafBlocks(const SpilledGrid& g, SpillReader& spill, std::ostream& out) {
  auto none = [](auto&&...) {};
  forEachNodeInFileOrder(g, none, none, [&](std::size_t n, auto&&...) {
    if (!g.isLeaf(n)) return;
    const std::string& bytes = spill.read(g, n);
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    if (!out) throw std::ios_base::failure("write failed");
  });
}

// Writes one grid as Archive::write(os, {grid}, seekable = true) does; the grid brings its name,
// metadata and transform (its tree is empty), `g` the rest. Checks the stream after each part:
// a full disk is an error rather than a truncated file.
class StreamingVdbWriter final : public openvdb::io::Archive {
 public:
  // The flags the grid's leaf blocks are compressed with (setGridCompression keeps every flag of
  // a GRID_UNKNOWN grid; write() checks that it still does).
  uint32_t leafCompression() const { return compression(); }

  void write(std::ostream& out, openvdb::FloatGrid& grid, const SpilledGrid& g,
             SpillReader& spill) const {
    namespace io = openvdb::io;
    io::StreamMetadata::Ptr metadata = std::make_shared<io::StreamMetadata>();
    io::setStreamMetadataPtr(out, metadata, /*transfer=*/false);
    io::setDataCompression(out, compression());
    io::setWriteGridStatsMetadata(out, isGridStatsMetadataEnabled());
    writeHeader(out, /*seekable=*/true);
    openvdb::MetaMap().writeMeta(out);  // no file-level metadata
    const int32_t gridCount = 1;
    out.write(reinterpret_cast<const char*>(&gridCount), sizeof gridCount);

    metadata->setHalfFloat(grid.saveFloatAsHalf());
    io::GridDescriptor descriptor(grid.getName(), grid.type(), grid.saveFloatAsHalf());
    descriptor.writeHeader(out);
    const int64_t offsetsAt = out.tellp();
    descriptor.writeStreamPos(out);  // placeholders until the end is known
    descriptor.setGridPos(out.tellp());
    setGridCompression(out, grid);
    if (io::getDataCompression(out) != leafCompression()) {
      throw std::logic_error("the grid's compression differs from its leaf blocks'");
    }
    // What io::Archive adds for readers that load leaves lazily: each leaf block's layout byte
    // and the size of its compressed values, in writeBuffers' order.
    grid.insertMeta(openvdb::GridBase::META_FILE_DELAYED_LOAD, io::DelayedLoadMetadata());
    describeLeafBlocks(
        g, leafCompression(),
        *grid.getMetadata<io::DelayedLoadMetadata>(openvdb::GridBase::META_FILE_DELAYED_LOAD));
    if (isGridStatsMetadataEnabled()) {
      grid.addStatsMetadata();  // the keys and their types; the values are the spilled grid's
      const openvdb::CoordBBox& box = g.activeBox;
      grid.insertMeta(openvdb::GridBase::META_FILE_BBOX_MIN,
                      openvdb::Vec3IMetadata(box.min().asVec3i()));
      grid.insertMeta(openvdb::GridBase::META_FILE_BBOX_MAX,
                      openvdb::Vec3IMetadata(box.max().asVec3i()));
      grid.insertMeta(openvdb::GridBase::META_FILE_MEM_BYTES,
                      openvdb::Int64Metadata(loadedMemoryBytes(g)));
      grid.insertMeta(openvdb::GridBase::META_FILE_VOXEL_COUNT,
                      openvdb::Int64Metadata(g.activeVoxels));
      grid.insertMeta(
          openvdb::GridBase::META_FILE_COMPRESSION,
          openvdb::StringMetadata(io::compressionToString(io::getDataCompression(out))));
    }
    grid.writeMeta(out);
    grid.writeTransform(out);
    writeTopology(g, spill, out);
    descriptor.setBlockPos(out.tellp());
    if (!out) throw std::ios_base::failure("write failed");
    copyLeafBlocks(g, spill, out);
    descriptor.setEndPos(out.tellp());
    out.seekp(offsetsAt, std::ios_base::beg);
    descriptor.writeStreamPos(out);
    descriptor.seekToEnd(out);
  }
};

}  // namespace

VdbExportReport exportVdb(VolumeSource& source, const std::string& path,
                          const VdbExportOptions& options) {
  const VolumeInfo& info = source.info();
  checkOutputIsNotAnInput(path, info.sourceFiles);
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
      (target.parent_path() /
       fmt::format(".{}.partial-{}", target.filename().string(), static_cast<long>(::getpid())))
          .string()};
  TempFileGuard spillFile{
      (target.parent_path() /
       fmt::format(".{}.spill-{}", target.filename().string(), static_cast<long>(::getpid())))
          .string()};
  try {
    StreamingVdbWriter writer;
    SpilledGrid spilled;
    {
      std::ofstream spill(spillFile.path, std::ios::binary | std::ios::trunc);
      if (!spill) throw Error(path, "cannot create the temporary file " + spillFile.path);
      spilled = spillGrid(source, options, writer.leafCompression(), spill);
      spill.close();
      if (spill.fail())
        throw Error(path, "write failed while closing " + spillFile.path + " (disk full?)");
    }
    report.activeVoxels = spilled.activeVoxels;
    if (report.activeVoxels == 0) {
      throw Error(path, fmt::format("no sample is at or above the threshold {} {}: the grid would "
                                    "be empty (lower the threshold)",
                                    options.thresholdHu, info.unit));
    }
    // The grid's name, metadata and transform; its tree stays empty.
    openvdb::FloatGrid::Ptr grid = openvdb::FloatGrid::create(kVdbBackground);
    grid->setTransform(gridTransform(info.patientFromIndex));
    addMetadata(*grid, info, options.thresholdHu);

    std::ofstream out(temp.path, std::ios::binary | std::ios::trunc);
    if (!out) throw Error(path, "cannot create the temporary output file " + temp.path);
    SpillReader spillReader(spillFile.path);
    writer.write(out, *grid, spilled, spillReader);
    out.flush();
    if (!out) throw Error(path, "write failed (disk full?)");
    out.close();
    if (out.fail()) throw Error(path, "write failed while closing the file (disk full?)");
  } catch (const openvdb::Exception& e) {
    throw Error(path, fmt::format("OpenVDB: {}", e.what()));
  } catch (const std::ios_base::failure& e) {
    throw Error(path, fmt::format("{} (disk full?)", e.what()));
  }

  std::error_code ec;
  report.bytesOnDisk = fs::file_size(temp.path, ec);
  fs::rename(temp.path, path, ec);
  if (ec) throw Error(path, "cannot move the finished file into place: " + ec.message());
  temp.keep = true;
  return report;
}

}  // namespace octoray
