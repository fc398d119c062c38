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

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <filesystem>
#include <istream>
#include <limits>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <streambuf>
#include <variant>
#include <vector>

#include <fmt/format.h>

#include "octoray/core/error.h"
#include "octoray/dicom/formats.h"
#include "octoray/dicom/vdb.h"
#include "raw_slab_reader.h"

namespace octoray {

namespace {

// A grid as messages name it: grid 'density', or the unnamed grid (a grid need not have a name).
std::string gridLabel(const std::string& name) {
  return name.empty() ? "the unnamed grid" : fmt::format("grid '{}'", name);
}

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

// Active tiles above the leaves (depth treeDepth() - 1 would be the leaf voxels).
template <typename TreeT>
void scanActiveTiles(const TreeT& tree, ValueScan& scan) {
  auto tile = tree.cbeginValueOn();
  tile.setMaxDepth(tree.treeDepth() - 2);
  for (; tile; ++tile) scan.add(static_cast<double>(*tile));
}

template <typename LeafT>
void scanLeaf(const LeafT& leaf, ValueScan& scan) {
  for (auto it = leaf.cbeginValueOn(); it; ++it) scan.add(static_cast<double>(*it));
}

template <typename TreeT>
ValueScan scanActiveValues(const TreeT& tree) {
  openvdb::tree::LeafManager<const TreeT> leaves(tree);
  ValueScan scan = tbb::parallel_reduce(
      leaves.leafRange(), ValueScan{},
      [](const auto& range, ValueScan s) {
        for (auto leaf = range.begin(); leaf; ++leaf) scanLeaf(*leaf, s);
        return s;
      },
      [](ValueScan a, const ValueScan& b) {
        a.join(b);
        return a;
      });
  scanActiveTiles(tree, scan);
  return scan;
}

// A read-only stream buffer over a file, read with pread through a 1 MiB window: a seek or a
// position query that lands inside the window costs no system call. A band's leaves lie a few
// kilobytes apart in the file, and the reader asks where it is at every leaf; through
// std::filebuf each of those seeks and queries is an lseek, and a seek also drops the buffer.
class WindowedFileBuffer final : public std::streambuf {
 public:
  explicit WindowedFileBuffer(const std::string& path)
      : fd_(::open(path.c_str(), O_RDONLY | O_CLOEXEC)), window_(std::size_t{1} << 20) {
    setg(window_.data(), window_.data(), window_.data());
  }
  ~WindowedFileBuffer() override {
    if (fd_ >= 0) ::close(fd_);
  }
  WindowedFileBuffer(const WindowedFileBuffer&) = delete;
  WindowedFileBuffer& operator=(const WindowedFileBuffer&) = delete;

  bool isOpen() const { return fd_ >= 0; }

  // The file's size and when it was last written, from one fstat.
  struct Status {
    int64_t size = 0;
    int64_t modifiedNs = 0;
  };
  std::optional<Status> status() const {
    struct stat st {};
    if (::fstat(fd_, &st) != 0) return std::nullopt;
    return Status{static_cast<int64_t>(st.st_size),
                  int64_t{st.st_mtim.tv_sec} * 1'000'000'000 + st.st_mtim.tv_nsec};
  }

  // Forgets the window's bytes (not the position): the next read comes from the file.
  void discardWindow() {
    windowStart_ += gptr() - eback();
    setg(window_.data(), window_.data(), window_.data());
  }

 protected:
  int_type underflow() override {
    if (gptr() < egptr()) return traits_type::to_int_type(*gptr());
    return fill(windowStart_ + (egptr() - eback())) ? traits_type::to_int_type(*gptr())
                                                    : traits_type::eof();
  }

  pos_type seekoff(off_type offset, std::ios_base::seekdir dir,
                   std::ios_base::openmode which) override {
    off_type base = windowStart_ + (gptr() - eback());
    if (dir == std::ios_base::beg) {
      base = 0;
    } else if (dir == std::ios_base::end) {
      const auto now = status();
      if (!now) return pos_type(off_type(-1));
      base = now->size;
    }
    return seekpos(pos_type(base + offset), which);
  }

  pos_type seekpos(pos_type position, std::ios_base::openmode which) override {
    const auto target = static_cast<off_type>(position);
    if (!(which & std::ios_base::in) || target < 0) return pos_type(off_type(-1));
    if (target >= windowStart_ && target <= windowStart_ + (egptr() - eback())) {
      setg(eback(), eback() + (target - windowStart_), egptr());
    } else {
      windowStart_ = target;  // an empty window there: the next read fills it
      setg(window_.data(), window_.data(), window_.data());
    }
    return position;
  }

 private:
  // The window from file offset `at`; false at the end of the file or on a read error (the
  // stream then fails, and the reader says the file is truncated or unreadable).
  bool fill(off_type at) {
    ssize_t got = 0;
    do {
      got = ::pread(fd_, window_.data(), window_.size(), static_cast<off_t>(at));
    } while (got < 0 && errno == EINTR);
    windowStart_ = at;
    setg(window_.data(), window_.data(), window_.data() + std::max<ssize_t>(got, 0));
    return got > 0;
  }

  int fd_;
  std::vector<char> window_;
  off_type windowStart_ = 0;  // the file offset of window_[0]
};

// Reads the grid descriptors of a .vdb, and then one grid, through a stream that throws on any
// short read. OpenVDB's io::File does not check its reads: a truncated file gave garbage values
// or a gigabyte-sized string instead of an error. The steps are io::File::open's. Each grid's
// recorded end is checked against the file size before the grid is read, since OpenVDB leaks
// the node being read when a read inside its topology throws.
class CheckedVdbReader final : public openvdb::io::Archive {
 public:
  explicit CheckedVdbReader(const std::string& path) : path_(path), file_(path), in_(&file_) {
    if (!file_.isOpen()) throw Error(path, "cannot open the file");
    const auto opened = file_.status();
    if (!opened) throw Error(path, "cannot read the file's size");
    const int64_t fileBytes = opened->size;
    openedModifiedNs_ = opened->modifiedNs;
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
        // An instance records metadata and a transform only, and no block position.
        const bool blocksInside = d.isInstance() || (d.getGridPos() <= d.getBlockPos() &&
                                                     d.getBlockPos() <= d.getEndPos());
        if (!(d.getGridPos() > 0 && d.getGridPos() <= d.getEndPos() &&
              d.getEndPos() <= fileBytes && blocksInside)) {
          throw Error(
              path, fmt::format("truncated or damaged: {} is recorded at bytes "
                                "{}..{} of a {}-byte file",
                                gridLabel(d.gridName()), d.getGridPos(), d.getEndPos(), fileBytes));
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

  // Whether readTopology and readingLeafValues can read grids in parts: the file records where
  // each grid is, and stores a grid's transform before its topology (format 216 and later).
  bool readsInParts() const {
    return inputHasGridOffsets() && fileVersion() >= openvdb::OPENVDB_FILE_VERSION_GRID_INSTANCING;
  }

  // Grid n's metadata, transform and topology (which voxels and tiles are active, and the
  // tiles' values) without its leaves' values: the active box and voxel count at about a
  // twentieth of the memory of the whole grid. Its leaves must not be read. The steps are
  // Archive::readGrid's, less the buffers.
  openvdb::GridBase::Ptr readTopology(std::size_t n) {
    openvdb::GridBase::Ptr grid = freshGrid(n);
    const openvdb::io::GridDescriptor& d = entries_[n].descriptor;
    startRead(n);
    d.seekToGrid(in_);
    if (d.isInstance()) {
      Archive::readGrid(grid, d, in_);  // an instance records its metadata and transform only
      grid->setTree(readTopology(instanceParent(n))->baseTreePtr());
      return grid;
    }
    readGridCompression(in_);
    GridStreamMetadata gridMetadata(in_, streamMetadata_, grid->saveFloatAsHalf());
    openvdb::io::setGridClass(in_, openvdb::GRID_UNKNOWN);
    openvdb::io::setGridBackgroundValuePtr(in_, nullptr);
    grid->readMeta(in_);
    // OpenVDB's writer puts a delayed-load table (a few bytes a leaf) in the grid's metadata,
    // of use only to io::File's delayed loading: not kept with the topology.
    grid->removeMeta(openvdb::GridBase::META_FILE_DELAYED_LOAD);
    gridMetadata.metadata->gridMetadata() = static_cast<openvdb::MetaMap&>(*grid);
    openvdb::io::setGridClass(in_, grid->getGridClass());
    grid->readTransform(in_);
    grid->readTopology(in_);
    entries_[n].leafValuesPos = in_.tellg();
    return grid;
  }

  // Runs read(stream, fromHalf, start) with the stream set up as Archive::readGrid sets it up
  // for the leaf values of grid n (its parent's, for an instance), `start` being where the first
  // leaf's values are. `topology` is grid n as readTopology read it; the values go into its
  // leaves, whose background `background` is. `read` seeks to the leaves it reads.
  template <typename Read>
  void readingLeafValues(std::size_t n, const openvdb::GridBase& topology, const void* background,
                         Read&& read) {
    const std::size_t owner = entries_[n].descriptor.isInstance() ? instanceParent(n) : n;
    const Entry& entry = entries_[owner];
    if (entry.leafValuesPos < 0) throw std::logic_error("leaf values read before the topology");
    startRead(owner);
    entry.descriptor.seekToGrid(in_);
    readGridCompression(in_);
    const bool fromHalf = topology.saveFloatAsHalf();  // as Grid::readBuffers takes it
    GridStreamMetadata gridMetadata(in_, streamMetadata_, fromHalf);
    gridMetadata.metadata->gridMetadata() = static_cast<const openvdb::MetaMap&>(topology);
    openvdb::io::setGridClass(in_, topology.getGridClass());
    openvdb::io::setGridBackgroundValuePtr(in_, background);
    read(in_, fromHalf, entry.leafValuesPos);
  }

  // Grid n with its tree, and its instance parent's tree where it shares one.
  openvdb::GridBase::Ptr read(std::size_t n) {
    Entry& entry = entries_[n];
    if (!entry.loaded) {
      startRead(n);
      entry.descriptor.seekToGrid(in_);
      Archive::readGrid(entry.grid, entry.descriptor, in_);
      entry.loaded = true;
    }
    if (entry.descriptor.isInstance()) {
      entry.grid->setTree(read(instanceParent(n))->baseTreePtr());
    }
    return entry.grid;
  }

 private:
  // Grid-level stream metadata (a copy of the file's, with the grid's half-float flag) for as
  // long as one grid is read; the file's is restored after, also when the read throws. The
  // stream keeps the address of the shared pointer it is given, not a copy: both pointers
  // must outlive their time on the stream.
  struct GridStreamMetadata {
    GridStreamMetadata(std::istream& stream, openvdb::io::StreamMetadata::Ptr& file, bool halfFloat)
        : in(stream),
          metadata(std::make_shared<openvdb::io::StreamMetadata>(*file)),
          fileMetadata(file) {
      metadata->setHalfFloat(halfFloat);
      openvdb::io::setStreamMetadataPtr(in, metadata, /*transfer=*/false);
    }
    ~GridStreamMetadata() {
      openvdb::io::setStreamMetadataPtr(in, fileMetadata, /*transfer=*/false);
    }
    GridStreamMetadata(const GridStreamMetadata&) = delete;
    GridStreamMetadata& operator=(const GridStreamMetadata&) = delete;
    std::istream& in;
    openvdb::io::StreamMetadata::Ptr metadata;
    openvdb::io::StreamMetadata::Ptr& fileMetadata;
  };

  // Each grid read starts from the file, not from what an earlier read left in the window, and
  // with the stream good again after an earlier read failed (a band read that threw).
  // The grid's recorded end is checked against the file's size again first: a file cut short
  // after it was opened would otherwise fail inside OpenVDB's topology read, which leaks the
  // node it was reading.
  void startRead(std::size_t n) {
    file_.discardWindow();
    in_.clear();
    const openvdb::io::GridDescriptor& d = entries_[n].descriptor;
    const auto now = file_.status();
    if (!now) throw Error(path_, "cannot read the file's size");
    if (inputHasGridOffsets() && now->size < d.getEndPos()) {
      throw Error(path_, fmt::format("the file is now {} bytes, shorter than when it was opened: "
                                     "{} ends at byte {}",
                                     now->size, gridLabel(d.gridName()), d.getEndPos()));
    }
    // Where each leaf starts was recorded from the file as it was: a file written since could
    // put other bytes there.
    if (now->modifiedNs != openedModifiedNs_) {
      throw Error(path_, "the file was written to after it was opened: open it again");
    }
  }

  // An empty grid of grid n's type, to read into.
  openvdb::GridBase::Ptr freshGrid(std::size_t n) const {
    const openvdb::io::GridDescriptor& d = entries_[n].descriptor;
    openvdb::GridBase::Ptr grid = openvdb::GridBase::createGrid(d.gridType());
    grid->setSaveFloatAsHalf(d.saveFloatAsHalf());
    return grid;
  }

  // The grid whose tree instance n shares. OpenVDB writes that grid's tree itself, so a parent
  // that is an instance too (which could lead round in a circle) is a damaged file.
  std::size_t instanceParent(std::size_t n) const {
    const openvdb::io::GridDescriptor& d = entries_[n].descriptor;
    for (std::size_t p = 0; p < entries_.size(); ++p) {
      if (p == n || entries_[p].descriptor.uniqueName() != d.instanceParentName()) continue;
      if (entries_[p].descriptor.isInstance()) {
        throw openvdb::KeyError(fmt::format("{} is an instance of {}, which is an instance itself",
                                            gridLabel(d.gridName()),
                                            gridLabel(entries_[p].descriptor.gridName())));
      }
      return p;
    }
    throw openvdb::KeyError(
        fmt::format("{} is an instance of a grid the file lacks", gridLabel(d.gridName())));
  }

  struct Entry {
    openvdb::io::GridDescriptor descriptor;
    openvdb::GridBase::Ptr grid;
    bool loaded = false;
    std::streamoff leafValuesPos = -1;  // where readTopology found the leaf values to begin
  };
  std::string path_;
  WindowedFileBuffer file_;
  int64_t openedModifiedNs_ = -1;
  std::istream in_;
  openvdb::io::StreamMetadata::Ptr streamMetadata_;
  std::vector<Entry> entries_;
};

// The grid to read, by index: the one named "density" when it holds floats or doubles, else
// the first such grid in the file.
std::size_t chooseGrid(const CheckedVdbReader& file, const std::string& path,
                       std::vector<std::string>& warnings) {
  if (file.size() == 0) throw Error(path, "the file holds no grids");
  std::vector<std::string> seen;
  std::optional<std::size_t> chosen;
  std::size_t candidates = 0;
  for (std::size_t n = 0; n < file.size(); ++n) {
    const openvdb::GridBase& grid = file.typed(n);
    seen.push_back(file.name(n).empty() ? fmt::format("unnamed ({})", grid.valueType())
                                        : fmt::format("'{}' ({})", file.name(n), grid.valueType()));
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
    warnings.push_back(fmt::format("{} grids ({}): read {}{}", file.size(), fmt::join(seen, ", "),
                                   gridLabel(file.name(*chosen)),
                                   candidates > 1 ? ", the other scalar grids are ignored" : ""));
  }
  return *chosen;
}

// Runs `read`, turning what OpenVDB and the stream throw into an Error naming the file.
template <typename Read>
auto readingVdb(const std::string& path, Read&& read) {
  try {
    return read();
  } catch (const openvdb::Exception& e) {
    throw Error(path, fmt::format("not a readable OpenVDB file ({})", e.what()));
  } catch (const std::ios_base::failure&) {
    throw Error(path, "truncated or unreadable OpenVDB file (it ends before its grids do)");
  } catch (const std::length_error&) {
    throw Error(path, "damaged OpenVDB file (a length field is out of range)");
  }
}

// Slices [z0, z1] of the grid's box in a band aligned to OpenVDB's 8-voxel leaves, so that no
// leaf is read by two bands of a front-to-back pass: from z0 down to a leaf boundary, up to
// at least bandSlices slices and a leaf boundary, within the box.
openvdb::CoordBBox bandAround(const openvdb::CoordBBox& box, int32_t z0, int32_t z1,
                              int32_t bandSlices) {
  const int32_t aligned = z0 & ~7;
  const int32_t first = std::max(box.min().z(), aligned);
  const int64_t wanted = std::max<int64_t>(z1, int64_t{aligned} + bandSlices - 1);
  const int32_t last = static_cast<int32_t>(std::min<int64_t>(box.max().z(), wanted | 7));
  return {openvdb::Coord(box.min().x(), box.min().y(), first),
          openvdb::Coord(box.max().x(), box.max().y(), last)};
}

// The leaf values of a grid read in parts, a leaf at a time into the leaves of its topology, each
// leaf once per pass. The first pass reads every leaf in the order of the file, for the value
// range, and records where each leaf's values start; after it, the leaves of one band of slices
// at a time are read from there, and those of the band before are let go. The topology stays in
// memory (about a twentieth of the values), so no band reads it again.
template <typename GridT>
class LeafValues {
 public:
  using LeafT = typename GridT::TreeType::LeafNodeType;

  LeafValues(std::shared_ptr<CheckedVdbReader> file, std::size_t gridIndex,
             typename GridT::Ptr topology)
      : file_(std::move(file)), gridIndex_(gridIndex), grid_(std::move(topology)) {
    // The order in which OpenVDB writes the leaves (root table, then each node's children by
    // index), which is its leaf iterator's.
    for (auto leaf = grid_->tree().beginLeaf(); leaf; ++leaf) leaves_.push_back(leaf.getLeaf());
  }
  LeafValues(const LeafValues&) = delete;
  LeafValues& operator=(const LeafValues&) = delete;

  const GridT& grid() const { return *grid_; }

  // Reads every leaf once, front of the file to back, recording where each one starts; returns
  // the range of the active values, tiles included. One leaf is in memory at a time.
  ValueScan scan() {
    release();
    starts_.clear();
    starts_.reserve(leaves_.size());
    ValueScan scan;
    reading([&](std::istream& in, bool fromHalf, std::streamoff firstLeaf) {
      in.seekg(firstLeaf);
      for (LeafT* leaf : leaves_) {
        starts_.push_back(in.tellg());
        loaded_.push_back(leaf);
        leaf->readBuffers(in, fromHalf);
        scanLeaf(*leaf, scan);
        release();
      }
    });
    scanActiveTiles(grid_->tree(), scan);
    return scan;
  }

  // Reads the values of the leaves that meet slices [z0, z1], after letting go of those read
  // before. scan() must have run.
  void load(int32_t z0, int32_t z1) {
    release();
    if (starts_.size() != leaves_.size()) {
      throw std::logic_error("leaf values loaded before the scan");
    }
    reading([&](std::istream& in, bool fromHalf, std::streamoff) {
      for (std::size_t i = 0; i < leaves_.size(); ++i) {
        LeafT* leaf = leaves_[i];
        const int32_t z = leaf->origin().z();
        if (z > z1 || int64_t{z} + LeafT::DIM <= z0) continue;
        in.seekg(starts_[i]);
        loaded_.push_back(leaf);
        leaf->readBuffers(in, fromHalf);
      }
    });
  }

 private:
  template <typename Read>
  void reading(Read&& read) {
    file_->readingLeafValues(gridIndex_, *grid_, &grid_->tree().background(), read);
  }

  // The leaves read go back to holding no values (as readTopology left them).
  void release() {
    for (LeafT* leaf : loaded_) {
      typename LeafT::Buffer none(openvdb::PartialCreate(), grid_->background());
      leaf->swap(none);  // `none` takes the values and frees them
    }
    loaded_.clear();
  }

  std::shared_ptr<CheckedVdbReader> file_;
  std::size_t gridIndex_;
  typename GridT::Ptr grid_;        // the topology, with the leaves of loaded_ holding values
  std::vector<LeafT*> leaves_;      // in the file's order
  std::vector<std::streamoff> starts_;  // where each of leaves_ starts in the file
  std::vector<LeafT*> loaded_;
};

// Slabs of the grid: from the whole grid in memory, or from the band of slices whose leaf values
// are read, read from the file when the slab leaves that band.
template <typename GridT>
class VdbSource final : public VolumeSource {
 public:
  // The whole grid, every value in memory; or its leaf values, read bandSlices at a time.
  using Values = std::variant<typename GridT::ConstPtr, std::unique_ptr<LeafValues<GridT>>>;

  VdbSource(VolumeInfo info, const openvdb::CoordBBox& box, Values values, int32_t bandSlices)
      : info_(std::move(info)), box_(box), values_(std::move(values)), bandSlices_(bandSlices) {}

  const VolumeInfo& info() const override { return info_; }

  void readSlab(int64_t firstSlice, int64_t sliceCount, std::span<float> out) override {
    checkSlabRequest(info_, firstSlice, sliceCount, out.size());
    // Slices lie inside the grid's box, so their z fits the grid's 32-bit coordinates.
    const auto z0 = static_cast<int32_t>(box_.min().z() + firstSlice);
    const auto z1 = static_cast<int32_t>(z0 + sliceCount - 1);
    const GridT* grid = nullptr;
    if (const auto* whole = std::get_if<typename GridT::ConstPtr>(&values_)) {
      grid = whole->get();
    } else {
      LeafValues<GridT>& leaves = *std::get<std::unique_ptr<LeafValues<GridT>>>(values_);
      if (!(band_ && band_->min().z() <= z0 && z1 <= band_->max().z())) {
        band_.reset();
        const openvdb::CoordBBox band = bandAround(box_, z0, z1, bandSlices_);
        readingVdb(info_.sourcePath, [&] { leaves.load(band.min().z(), band.max().z()); });
        band_ = band;
      }
      grid = &leaves.grid();
    }
    const openvdb::Coord min(box_.min().x(), box_.min().y(), z0);
    const openvdb::Coord max(box_.max().x(), box_.max().y(), z1);
    // x fastest (LayoutXYZ) is our slab layout; inactive voxels come out as the background.
    openvdb::tools::Dense<float, openvdb::tools::LayoutXYZ> dense(openvdb::CoordBBox(min, max),
                                                                  out.data());
    openvdb::tools::copyToDense(*grid, dense);
  }

 private:
  VolumeInfo info_;
  openvdb::CoordBBox box_;         // the volume's index box in grid coordinates
  Values values_;
  int32_t bandSlices_;
  std::optional<openvdb::CoordBBox> band_;  // the slices whose leaf values are read, in bands
};

// `grid` is the whole grid (file null), or its topology alone, to be read from `file` in bands.
template <typename GridT>
std::unique_ptr<VolumeSource> openGrid(typename GridT::Ptr grid, VolumeInfo info,
                                       const std::string& path,
                                       std::shared_ptr<CheckedVdbReader> file,
                                       std::size_t gridIndex, uint64_t wholeGridBytes) {
  const openvdb::CoordBBox active = grid->evalActiveVoxelBoundingBox();
  if (active.empty()) {
    throw Error(path, fmt::format("{} has no active voxels", gridLabel(grid->getName())));
  }
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

  // A band holds at most about a quarter of wholeGridBytes of values (whole leaves, so the
  // box's slices rounded out to 8 voxels), and at least one layer of leaves. Each leaf is read
  // once whatever the band's size; a smaller band costs more passes over the file and saves
  // memory (import to a store, 2026-12-07; 1024 x 1024 x 768 phantom, 678,503 leaves: 8-9 s at
  // 612 MiB with a quarter, 9-10 s at 777 MiB with half; 2048 x 2048 x 768, 2,675,458
  // leaves: 40 s at 1.21 GiB, 37 s at 1.37 GiB). In doubles: a slice of a grid near the
  // 32-bit limits would overflow 64 bits.
  using Value = typename GridT::ValueType;
  const double bandSliceBytes = (static_cast<double>(info.dims[0]) + 14) *
                                (static_cast<double>(info.dims[1]) + 14) * sizeof(Value);
  const double fitting =
      std::floor(static_cast<double>(wholeGridBytes) / 4 / bandSliceBytes / 8) * 8;
  const auto bandSlices = static_cast<int32_t>(std::clamp(fitting, 8.0, double{1 << 24}));

  // Bounds cover every sample: the active values, and the background where voxels are inactive.
  const bool someInactive =
      grid->activeVoxelCount() < static_cast<openvdb::Index64>(info.sampleCount());
  const auto background = static_cast<double>(grid->background());
  ValueScan scan;
  typename VdbSource<GridT>::Values values;
  if (!file) {
    scan = scanActiveValues(grid->tree());
    values = typename GridT::ConstPtr(std::move(grid));
  } else {
    auto leaves = std::make_unique<LeafValues<GridT>>(std::move(file), gridIndex, std::move(grid));
    scan = leaves->scan();
    values = std::move(leaves);
  }
  if (someInactive) scan.add(background);
  info.integerValues = scan.integers;
  if (!scan.nonFinite) {
    info.valueLowerBound = scan.lo;
    info.valueUpperBound = scan.hi;
  }
  return std::make_unique<VdbSource<GridT>>(std::move(info), box, std::move(values), bandSlices);
}

}  // namespace

std::unique_ptr<VolumeSource> openVdb(const std::string& path, uint64_t wholeGridBytes) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) throw Error(path, "not a readable file");
  if (std::filesystem::file_size(path, ec) == 0) throw Error(path, "empty file");
  initializeOpenVdb();
  VolumeInfo info;
  info.format = "vdb";
  info.sourcePath = path;
  info.sourceFiles = {path};
  return readingVdb(path, [&]() -> std::unique_ptr<VolumeSource> {
    auto file = std::make_shared<CheckedVdbReader>(path);
    const std::size_t chosen = chooseGrid(*file, path, info.warnings);
    // The topology first where the file allows: a grid whose leaves hold more values than
    // wholeGridBytes is then read in bands, never whole.
    openvdb::GridBase::Ptr grid;
    if (file->readsInParts()) {
      grid = file->readTopology(chosen);
      const uint64_t leafValueBytes = grid->baseTree().leafCount() * uint64_t{512} *
                                      (grid->isType<openvdb::FloatGrid>() ? 4 : 8);
      if (leafValueBytes <= wholeGridBytes) grid.reset();
    }
    if (!grid) {
      grid = file->read(chosen);
      file.reset();
    }

    info.description = std::filesystem::path(path).filename().string();
    if (const auto d = metaValue<std::string>(*grid, vdb_meta::kDescription); d && !d->empty()) {
      info.description = *d;
    }
    info.modality = metaValue<std::string>(*grid, vdb_meta::kModality).value_or("");
    info.unit = metaValue<std::string>(*grid, vdb_meta::kValueUnit).value_or("");
    if (metaValue<std::string>(*grid, vdb_meta::kCoordinates).value_or("") != "LPS") {
      info.warnings.push_back(
          fmt::format("{} does not say its world space is patient LPS in mm: taken as such",
                      gridLabel(grid->getName())));
    }
    // openGrid holds the only reference, so that it can let the topology go.
    if (auto floats = openvdb::gridPtrCast<openvdb::FloatGrid>(grid)) {
      grid.reset();
      return openGrid<openvdb::FloatGrid>(std::move(floats), std::move(info), path, std::move(file),
                                          chosen, wholeGridBytes);
    }
    info.warnings.push_back("double-precision grid: samples are read as float32");
    auto doubles = openvdb::gridPtrCast<openvdb::DoubleGrid>(grid);
    grid.reset();
    return openGrid<openvdb::DoubleGrid>(std::move(doubles), std::move(info), path, std::move(file),
                                         chosen, wholeGridBytes);
  });
}

}  // namespace octoray
