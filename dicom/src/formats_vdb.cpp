// OpenVDB (.vdb): one float or double grid read as a volume. The extent is the active voxels'
// bounding box (or the index box octoray's export records, where it holds them); the grid's
// linear transform becomes patientFromIndex, world space taken as patient LPS in mm. Inactive
// voxels read as the grid's background.

#include <openvdb/io/Archive.h>
#include <openvdb/io/GridDescriptor.h>
#include <openvdb/io/io.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/Dense.h>
#include <openvdb/tree/LeafManager.h>
#include <tbb/parallel_reduce.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <mutex>
#include <optional>
#include <vector>

#include <fmt/format.h>

#include "octoray/core/error.h"
#include "octoray/dicom/formats.h"
#include "octoray/dicom/vdb.h"
#include "raw_slab_reader.h"

namespace octoray {

namespace {

void initializeOpenVdb() {
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });
}

// The transpose of OpenVDB's row-vector matrix: our column-vector index -> world affine.
Mat4 worldFromGridIndex(const openvdb::math::Transform& transform, const std::string& path) {
  if (!transform.isLinear()) {
    const std::string kind = transform.mapType() == openvdb::math::NonlinearFrustumMap::mapType()
                                 ? "frustum"
                                 : transform.mapType();
    throw Error(path, fmt::format("non-affine transform ({}) not supported: only a linear "
                                  "transform has an index->patient affine",
                                  kind));
  }
  const openvdb::math::Mat4d m = transform.baseMap()->getAffineMap()->getMat4();
  Mat4 world;
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) world.m[r][c] = m(c, r);
  }
  return world;
}

template <typename T>
std::optional<T> metaValue(const openvdb::GridBase& grid, const char* key) {
  const auto meta = grid.getMetadata<openvdb::TypedMetadata<T>>(key);
  if (!meta) return std::nullopt;
  return meta->value();
}

// Range and integrality of every active value (voxels and tiles), over all cores.
struct ValueScan {
  double lo = std::numeric_limits<double>::infinity();
  double hi = -std::numeric_limits<double>::infinity();
  bool integers = true;
  bool nonFinite = false;

  void add(double v) {
    if (!std::isfinite(v)) {
      nonFinite = true;
      integers = false;
      return;
    }
    lo = std::min(lo, v);
    hi = std::max(hi, v);
    if (integers && v != std::nearbyint(v)) integers = false;
  }
  void join(const ValueScan& other) {
    lo = std::min(lo, other.lo);
    hi = std::max(hi, other.hi);
    integers = integers && other.integers;
    nonFinite = nonFinite || other.nonFinite;
  }
};

template <typename TreeT>
ValueScan scanActiveValues(const TreeT& tree) {
  openvdb::tree::LeafManager<const TreeT> leaves(tree);
  ValueScan scan = tbb::parallel_reduce(
      leaves.leafRange(), ValueScan{},
      [](const auto& range, ValueScan s) {
        for (auto leaf = range.begin(); leaf; ++leaf) {
          for (auto it = leaf->cbeginValueOn(); it; ++it) s.add(static_cast<double>(*it));
        }
        return s;
      },
      [](ValueScan a, const ValueScan& b) {
        a.join(b);
        return a;
      });
  // Active tiles above the leaves (depth treeDepth() - 1 would be the leaf voxels).
  auto tile = tree.cbeginValueOn();
  tile.setMaxDepth(tree.treeDepth() - 2);
  for (; tile; ++tile) scan.add(static_cast<double>(*tile));
  return scan;
}

template <typename GridT>
class VdbSource final : public VolumeSource {
 public:
  VdbSource(VolumeInfo info, typename GridT::ConstPtr grid, const openvdb::CoordBBox& box)
      : info_(std::move(info)), grid_(std::move(grid)), box_(box) {}

  const VolumeInfo& info() const override { return info_; }

  void readSlab(int64_t firstSlice, int64_t sliceCount, std::span<float> out) override {
    checkSlabRequest(info_, firstSlice, sliceCount, out.size());
    // Slices lie inside the grid's box, so their z fits the grid's 32-bit coordinates.
    const auto z0 = static_cast<int32_t>(box_.min().z() + firstSlice);
    const openvdb::Coord min(box_.min().x(), box_.min().y(), z0);
    const openvdb::Coord max(box_.max().x(), box_.max().y(),
                             static_cast<int32_t>(z0 + sliceCount - 1));
    // x fastest (LayoutXYZ) is our slab layout; inactive voxels come out as the background.
    openvdb::tools::Dense<float, openvdb::tools::LayoutXYZ> dense(openvdb::CoordBBox(min, max),
                                                                  out.data());
    openvdb::tools::copyToDense(*grid_, dense);
  }

 private:
  VolumeInfo info_;
  typename GridT::ConstPtr grid_;
  openvdb::CoordBBox box_;  // the volume's index box in grid coordinates
};

// Reads the grid descriptors of a .vdb, and then one grid, through a stream that throws on any
// short read. OpenVDB's io::File does not check its reads: a truncated file gave garbage values
// or a gigabyte-sized string instead of an error. The steps are io::File::open's. Each grid's
// recorded end is checked against the file size before the grid is read, since OpenVDB leaks
// the node being read when a read inside its topology throws.
class CheckedVdbReader final : public openvdb::io::Archive {
 public:
  explicit CheckedVdbReader(const std::string& path) : in_(path, std::ios::binary) {
    if (!in_) throw Error(path, "cannot open the file");
    const auto fileBytes = static_cast<int64_t>(std::filesystem::file_size(path));
    in_.exceptions(std::ios::failbit | std::ios::badbit);
    readHeader(in_);
    streamMetadata_ = std::make_shared<openvdb::io::StreamMetadata>();
    streamMetadata_->setSeekable(true);
    openvdb::io::setStreamMetadataPtr(in_, streamMetadata_, /*transfer=*/false);
    setFormatVersion(in_);
    setLibraryVersion(in_);
    setDataCompression(in_);
    openvdb::MetaMap fileMetadata;
    fileMetadata.readMeta(in_);
    const int32_t count = readGridCount(in_);
    if (count < 0) throw Error(path, fmt::format("invalid grid count {}", count));
    for (int32_t i = 0; i < count; ++i) {
      Entry entry;
      entry.grid = entry.descriptor.read(in_);  // an empty grid of the stored type
      if (inputHasGridOffsets()) {
        const openvdb::io::GridDescriptor& d = entry.descriptor;
        if (!(d.getGridPos() > 0 && d.getGridPos() <= d.getBlockPos() &&
              d.getBlockPos() <= d.getEndPos() && d.getEndPos() <= fileBytes)) {
          throw Error(path, fmt::format("truncated or damaged: grid '{}' is recorded at bytes "
                                        "{}..{} of a {}-byte file",
                                        d.gridName(), d.getGridPos(), d.getEndPos(), fileBytes));
        }
        entry.descriptor.seekToEnd(in_);
      } else {
        Archive::readGrid(entry.grid, entry.descriptor, in_);  // no offsets: read in order
        entry.loaded = true;
      }
      entries_.push_back(std::move(entry));
    }
  }

  std::size_t size() const { return entries_.size(); }
  const std::string& name(std::size_t n) const { return entries_[n].descriptor.gridName(); }
  // An empty grid of grid n's type (the tree is read by read()).
  const openvdb::GridBase& typed(std::size_t n) const { return *entries_[n].grid; }

  // Grid n with its tree, and its instance parent's tree where it shares one.
  openvdb::GridBase::Ptr read(std::size_t n) {
    Entry& entry = entries_[n];
    if (!entry.loaded) {
      entry.descriptor.seekToGrid(in_);
      Archive::readGrid(entry.grid, entry.descriptor, in_);
      entry.loaded = true;
    }
    if (entry.descriptor.isInstance()) {
      for (std::size_t p = 0; p < entries_.size(); ++p) {
        if (entries_[p].descriptor.uniqueName() == entry.descriptor.instanceParentName()) {
          entry.grid->setTree(read(p)->baseTreePtr());
        }
      }
    }
    return entry.grid;
  }

 private:
  struct Entry {
    openvdb::io::GridDescriptor descriptor;
    openvdb::GridBase::Ptr grid;
    bool loaded = false;
  };
  std::ifstream in_;
  openvdb::io::StreamMetadata::Ptr streamMetadata_;
  std::vector<Entry> entries_;
};

// The grid to read: the one named "density" when it holds floats or doubles, else the first
// such grid in the file.
openvdb::GridBase::Ptr chooseGrid(CheckedVdbReader& file, const std::string& path,
                                  std::vector<std::string>& warnings) {
  if (file.size() == 0) throw Error(path, "the file holds no grids");
  std::vector<std::string> seen;
  std::optional<std::size_t> chosen;
  std::size_t candidates = 0;
  for (std::size_t n = 0; n < file.size(); ++n) {
    const openvdb::GridBase& grid = file.typed(n);
    seen.push_back(fmt::format("'{}' ({})", file.name(n), grid.valueType()));
    if (!grid.isType<openvdb::FloatGrid>() && !grid.isType<openvdb::DoubleGrid>()) continue;
    ++candidates;
    if (!chosen || (file.name(n) == kVdbGridName && file.name(*chosen) != kVdbGridName)) {
      chosen = n;
    }
  }
  if (!chosen) {
    throw Error(path, fmt::format("no float or double grid to read as a volume (found {})",
                                  fmt::join(seen, ", ")));
  }
  if (file.size() > 1) {
    warnings.push_back(fmt::format("{} grids ({}): read '{}'{}", file.size(),
                                   fmt::join(seen, ", "), file.name(*chosen),
                                   candidates > 1 ? ", the other scalar grids are ignored" : ""));
  }
  return file.read(*chosen);
}

template <typename GridT>
std::unique_ptr<VolumeSource> openGrid(typename GridT::ConstPtr grid, VolumeInfo info,
                                       const std::string& path) {
  const openvdb::CoordBBox active = grid->evalActiveVoxelBoundingBox();
  if (active.empty()) throw Error(path, fmt::format("grid '{}' has no active voxels", grid->getName()));
  openvdb::CoordBBox box = active;
  const auto declaredMin = metaValue<openvdb::Vec3i>(*grid, vdb_meta::kIndexMin);
  const auto declaredMax = metaValue<openvdb::Vec3i>(*grid, vdb_meta::kIndexMax);
  if (declaredMin && declaredMax) {
    const openvdb::CoordBBox declared{openvdb::Coord(*declaredMin), openvdb::Coord(*declaredMax)};
    if (!declared.empty() && declared.isInside(active)) {
      box = declared;
    } else {
      info.warnings.push_back(
          "the recorded index box does not hold every active voxel: the active voxels' bounding "
          "box is used");
    }
  }
  // Coord::dim() is 32-bit: widen before it can wrap, then check the volume's size.
  for (int a = 0; a < 3; ++a) {
    info.dims[static_cast<std::size_t>(a)] = int64_t{box.max()[a]} - int64_t{box.min()[a]} + 1;
  }
  detail::volumeBytes(info.dims, SampleType::Float32, path);

  const Mat4 indexFromBox = Mat4::fromColumns({1, 0, 0}, {0, 1, 0}, {0, 0, 1},
                                              {static_cast<double>(box.min().x()),
                                               static_cast<double>(box.min().y()),
                                               static_cast<double>(box.min().z())});
  info.patientFromIndex = worldFromGridIndex(grid->transform(), path) * indexFromBox;
  detail::checkAffine(info.patientFromIndex, path);

  // Bounds cover every sample: the active values, and the background where voxels are inactive.
  ValueScan scan = scanActiveValues(grid->tree());
  if (grid->activeVoxelCount() < static_cast<openvdb::Index64>(info.sampleCount())) {
    scan.add(static_cast<double>(grid->background()));
  }
  info.integerValues = scan.integers;
  if (!scan.nonFinite) {
    info.valueLowerBound = scan.lo;
    info.valueUpperBound = scan.hi;
  }
  return std::make_unique<VdbSource<GridT>>(std::move(info), std::move(grid), box);
}

}  // namespace

std::unique_ptr<VolumeSource> openVdb(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) throw Error(path, "not a readable file");
  if (std::filesystem::file_size(path, ec) == 0) throw Error(path, "empty file");
  initializeOpenVdb();
  VolumeInfo info;
  info.format = "vdb";
  info.sourcePath = path;
  info.sourceFiles = {path};
  try {
    CheckedVdbReader file(path);
    const openvdb::GridBase::Ptr grid = chooseGrid(file, path, info.warnings);

    info.description = std::filesystem::path(path).filename().string();
    if (const auto d = metaValue<std::string>(*grid, vdb_meta::kDescription); d && !d->empty()) {
      info.description = *d;
    }
    info.modality = metaValue<std::string>(*grid, vdb_meta::kModality).value_or("");
    info.unit = metaValue<std::string>(*grid, vdb_meta::kValueUnit).value_or("");
    if (metaValue<std::string>(*grid, vdb_meta::kCoordinates).value_or("") != "LPS") {
      info.warnings.push_back(fmt::format(
          "grid '{}' does not say its world space is patient LPS in mm: taken as such",
          grid->getName()));
    }
    if (auto floats = openvdb::gridPtrCast<openvdb::FloatGrid>(grid)) {
      return openGrid<openvdb::FloatGrid>(floats, std::move(info), path);
    }
    info.warnings.push_back("double-precision grid: samples are read as float32");
    return openGrid<openvdb::DoubleGrid>(openvdb::gridPtrCast<openvdb::DoubleGrid>(grid),
                                         std::move(info), path);
  } catch (const openvdb::Exception& e) {
    throw Error(path, fmt::format("not a readable OpenVDB file ({})", e.what()));
  } catch (const std::ios_base::failure&) {
    throw Error(path, "truncated or unreadable OpenVDB file (it ends before its grids do)");
  } catch (const std::length_error&) {
    throw Error(path, "damaged OpenVDB file (a length field is out of range)");
  }
}

}  // namespace octoray
