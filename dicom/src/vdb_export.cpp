// Export of any VolumeSource as an OpenVDB float grid, read slab by slab (each slab one layer of
// 8x8x8 leaf nodes) and written through a temporary file, holding the grid's topology but not
// its values (see "Memory holds the grid's topology" below).

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

// Memory holds the grid's topology, never its values, so that a volume larger than memory can
// be exported. OpenVDB writes a grid as its topology (node masks and tile values) followed by
// one block per leaf, in the order Tree::writeBuffers visits the leaves, and io::Archive can only
// write a grid whose leaves all hold their values. So the export runs in two passes:
//  1. slab by slab, each leaf's block (what LeafNode::writeBuffers writes: its value mask and its
//     compressed values) goes to a spill file beside the target, and the tree gets a leaf with
//     the same origin and value mask but no value buffer (OpenVDB's PartialCreate leaf, the one
//     its own delayed-loading reader makes);
//  2. the file is written as Archive::write writes one grid, by OpenVDB's own code for the
//     header, descriptor, metadata, transform and topology, and the leaf blocks are copied from
//     the spill file in writeBuffers' order. The bytes are those io::File writes for the same
//     grid (tests/dicom/unit_vdb.cpp compares them).

// One 8x8x8 block of a slab: nothing (all below the threshold), a leaf without values and its
// serialised block, or, where all 512 samples are active and equal, an active tile.
struct Block {
  std::unique_ptr<LeafT> leaf;  // PartialCreate: the value mask only
  std::string bytes;            // LeafNode::writeBuffers of the full leaf
  int8_t valueLayout = 0;       // how its values were written (io::MaskCompress's metadata)
  bool tile = false;
  float tileValue = 0;
  int64_t active = 0;
};

// The stream state LeafNode::writeBuffers reads: the grid's compression flags and background.
void prepareLeafStream(std::ios_base& stream, uint32_t compression) {
  static const float background = kVdbBackground;
  openvdb::io::setDataCompression(stream, compression);
  openvdb::io::setGridBackgroundValuePtr(stream, &background);
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
      block.tile = true;
      block.tileValue = values[0];
      return block;
    }
  }
  std::ostringstream bytes(std::ios::binary);
  prepareLeafStream(bytes, compression);
  leaf->writeBuffers(bytes, /*toHalf=*/false);
  block.bytes = std::move(bytes).str();
  // The block is the value mask, then writeCompressedValues' layout byte (with
  // COMPRESS_ACTIVE_MASK), inactive values, a selection mask, and the values.
  if (compression & openvdb::io::COMPRESS_ACTIVE_MASK) {
    block.valueLayout = static_cast<int8_t>(block.bytes.at(LeafT::NodeMaskType::memUsage()));
  }
  block.leaf = std::make_unique<LeafT>(openvdb::PartialCreate(), origin, kVdbBackground, false);
  block.leaf->setValueMask(leaf->getValueMask());
  return block;
}

// Writes one grid as Archive::write(os, {grid}, seekable = true) does, except that the leaf
// blocks come from `writeLeafBlocks` instead of the leaves' (absent) buffers. Checks the stream
// after each part: a full disk is an error rather than a truncated file.
class StreamingVdbWriter final : public openvdb::io::Archive {
 public:
  // The flags the grid's leaf blocks are compressed with (setGridCompression keeps every flag of
  // a GRID_UNKNOWN grid; write() checks that it still does).
  uint32_t leafCompression() const { return compression(); }

  void write(std::ostream& out, openvdb::FloatGrid& grid, int64_t leafCount,
             const std::function<void(openvdb::io::DelayedLoadMetadata&)>& describeLeafBlocks,
             const std::function<void(std::ostream&)>& writeLeafBlocks) const {
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
        *grid.getMetadata<io::DelayedLoadMetadata>(openvdb::GridBase::META_FILE_DELAYED_LOAD));
    if (isGridStatsMetadataEnabled()) {
      grid.addStatsMetadata();  // bounding box and active count: from the masks
      // memUsage counts no values for leaves without a buffer; a reader holds them all.
      const auto withValues = static_cast<int64_t>(grid.memUsage()) +
                              leafCount * static_cast<int64_t>(LeafT::SIZE * sizeof(float));
      grid.insertMeta(openvdb::GridBase::META_FILE_MEM_BYTES, openvdb::Int64Metadata(withValues));
      grid.insertMeta(
          openvdb::GridBase::META_FILE_COMPRESSION,
          openvdb::StringMetadata(io::compressionToString(io::getDataCompression(out))));
    }
    grid.writeMeta(out);
    grid.writeTransform(out);
    grid.writeTopology(out);
    descriptor.setBlockPos(out.tellp());
    if (!out) throw std::ios_base::failure("write failed");
    writeLeafBlocks(out);
    descriptor.setEndPos(out.tellp());
    out.seekp(offsetsAt, std::ios_base::beg);
    descriptor.writeStreamPos(out);
    descriptor.seekToEnd(out);
  }
};

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

// Pass 1's result: the grid's topology and where each 8x8x8 block's leaf block lies in the spill
// file (blocks numbered x fastest, then y, then z; block n's bytes are [start[n], start[n + 1]),
// empty where it has no leaf).
struct SpilledGrid {
  openvdb::FloatGrid::Ptr grid;
  std::array<int64_t, 3> blocks{};
  std::vector<uint64_t> start;
  std::vector<int8_t> valueLayout;  // per block, of its leaf block
  int64_t leafCount = 0;
  int64_t activeVoxels = 0;
};

// Pass 1, one slab of kLeafDim slices at a time; the dense volume is never held.
SpilledGrid spillGrid(VolumeSource& source, const VdbExportOptions& options, uint32_t compression,
                      std::ostream& spill) {
  const VolumeInfo& info = source.info();
  const auto& dims = info.dims;
  SpilledGrid result;
  result.grid = openvdb::FloatGrid::create(kVdbBackground);
  openvdb::FloatTree& tree = result.grid->tree();
  for (int a = 0; a < 3; ++a) result.blocks[a] = (dims[a] + kLeafDim - 1) / kLeafDim;
  const int64_t blocksX = result.blocks[0], blocksY = result.blocks[1];
  result.start.reserve(static_cast<std::size_t>(blocksX * blocksY * result.blocks[2] + 1));
  result.valueLayout.reserve(static_cast<std::size_t>(blocksX * blocksY * result.blocks[2]));
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
      // Trees are not thread-safe to modify: the blocks go in one by one, in block order.
      for (int64_t n = 0; n < rows * blocksX; ++n) {
        Block& block = blocks[static_cast<std::size_t>(n)];
        result.start.push_back(spilled);
        result.valueLayout.push_back(block.valueLayout);
        result.activeVoxels += block.active;
        if (block.leaf) {
          spill.write(block.bytes.data(), static_cast<std::streamsize>(block.bytes.size()));
          spilled += block.bytes.size();
          tree.addLeaf(block.leaf.release());
          ++result.leafCount;
        } else if (block.tile) {
          const openvdb::Coord origin(static_cast<int>((n % blocksX) * kLeafDim),
                                      static_cast<int>((band + n / blocksX) * kLeafDim),
                                      static_cast<int>(z0));
          tree.addTile(/*level=*/1, origin, block.tileValue, /*active=*/true);  // leaf-sized
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

// Calls visit(block number) for every leaf in the order Tree::writeBuffers writes them (the
// root's children in its table's order, each node's children in child-mask order).
template <typename Visit>
void forEachLeafInFileOrder(const SpilledGrid& spilled, Visit&& visit) {
  const openvdb::FloatTree::RootNodeType& root = spilled.grid->tree().root();
  for (auto upper = root.cbeginChildOn(); upper; ++upper) {
    for (auto lower = upper->cbeginChildOn(); lower; ++lower) {
      for (auto leaf = lower->cbeginChildOn(); leaf; ++leaf) {
        const openvdb::Coord& origin = leaf->origin();
        visit(static_cast<std::size_t>(
            ((origin.z() / kLeafDim) * spilled.blocks[1] + origin.y() / kLeafDim) *
                spilled.blocks[0] +
            origin.x() / kLeafDim));
      }
    }
  }
}

// The delayed-load metadata of the leaf blocks, from their layout bytes and sizes: what
// io::Archive computes from the leaves' values (the compressed size is what follows the
// block's value mask, layout byte, inactive values and selection mask).
void describeLeafBlocks(const SpilledGrid& spilled, uint32_t compression,
                        openvdb::io::DelayedLoadMetadata& metadata) {
  namespace io = openvdb::io;
  if (spilled.leafCount == 0) return;
  const bool sized = compression & (io::COMPRESS_BLOSC | io::COMPRESS_ZIP);
  metadata.resizeMask(static_cast<std::size_t>(spilled.leafCount));
  if (sized) metadata.resizeCompressedSize(static_cast<std::size_t>(spilled.leafCount));
  std::size_t index = 0;
  forEachLeafInFileOrder(spilled, [&](std::size_t n) {
    const int8_t layout = spilled.valueLayout[n];
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
      metadata.setCompressedSize(
          index, static_cast<int64_t>(spilled.start[n + 1] - spilled.start[n]) - header);
    }
    ++index;
  });
}

// Pass 2's leaf blocks, copied from the spill file in the order Tree::writeBuffers writes them.
void copyLeafBlocks(const SpilledGrid& spilled, const std::string& spillPath, std::ostream& out) {
  std::ifstream in(spillPath, std::ios::binary);
  if (!in) throw std::ios_base::failure("cannot read back the spill file");
  std::string bytes;
  forEachLeafInFileOrder(spilled, [&](std::size_t n) {
    const uint64_t begin = spilled.start[n], size = spilled.start[n + 1] - begin;
    bytes.resize(size);
    in.seekg(static_cast<std::streamoff>(begin));
    in.read(bytes.data(), static_cast<std::streamsize>(size));
    if (!in || size == 0) throw std::ios_base::failure("the spill file is short");
    out.write(bytes.data(), static_cast<std::streamsize>(size));
    if (!out) throw std::ios_base::failure("write failed");
  });
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
    openvdb::FloatGrid& grid = *spilled.grid;
    grid.setTransform(gridTransform(info.patientFromIndex));
    addMetadata(grid, info, options.thresholdHu);

    std::ofstream out(temp.path, std::ios::binary | std::ios::trunc);
    if (!out) throw Error(path, "cannot create the temporary output file " + temp.path);
    writer.write(
        out, grid, spilled.leafCount,
        [&](openvdb::io::DelayedLoadMetadata& metadata) {
          describeLeafBlocks(spilled, writer.leafCompression(), metadata);
        },
        [&](std::ostream& os) { copyLeafBlocks(spilled, spillFile.path, os); });
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
