// OpenVDB export and input: a small sheared volume with values below, at and above the
// threshold, exported and read back through our reader and, independently, through OpenVDB's
// own API; damaged files, non-affine transforms and other grid types written with OpenVDB.

#include <gtest/gtest.h>

#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <set>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "format_test_helpers.h"
#include "octoray/core/error.h"
#include "octoray/dicom/formats.h"
#include "octoray/dicom/vdb.h"
#include "test_paths.h"

namespace octoray {
namespace {

namespace fs = std::filesystem;
using namespace formats_test;
using VoxelFunction = std::function<float(int64_t, int64_t, int64_t)>;

// An in-memory source from a function; optionally fails when slice `failAtSlice` is read.
class FunctionSource final : public VolumeSource {
 public:
  FunctionSource(std::array<int64_t, 3> dims, Mat4 patientFromIndex, VoxelFunction value,
                 int64_t failAtSlice = -1)
      : value_(std::move(value)), failAtSlice_(failAtSlice) {
    info_.dims = dims;
    info_.patientFromIndex = patientFromIndex;
    info_.integerValues = false;
    info_.format = "memory";
    info_.description = "phantom head";
    info_.modality = "CT";
    info_.unit = "HU";
  }
  const VolumeInfo& info() const override { return info_; }
  void readSlab(int64_t firstSlice, int64_t sliceCount, std::span<float> out) override {
    checkSlabRequest(info_, firstSlice, sliceCount, out.size());
    if (failAtSlice_ >= firstSlice && failAtSlice_ < firstSlice + sliceCount) {
      throw Error("memory", "simulated read failure");
    }
    maxSlabSlices = std::max(maxSlabSlices, sliceCount);
    std::size_t n = 0;
    for (int64_t k = firstSlice; k < firstSlice + sliceCount; ++k)
      for (int64_t j = 0; j < info_.dims[1]; ++j)
        for (int64_t i = 0; i < info_.dims[0]; ++i) out[n++] = value_(i, j, k);
  }
  int64_t maxSlabSlices = 0;

 private:
  VolumeInfo info_;
  VoxelFunction value_;
  int64_t failAtSlice_;
};

// A gantry tilt (the slice step leans along y) on an oblique in-plane rotation.
Mat4 tiltedAffine() {
  return Mat4::fromColumns({0.3, 0.4, 0}, {-0.6, 0.45, 0}, {0, 0.2, 1.25}, {-100.5, 20.25, 7});
}

constexpr std::array<int64_t, 3> kDims{21, 19, 13};  // not multiples of the 8-voxel leaves

// Air, exactly the threshold, just below it, fractional tissue values, and one 8x8x8 block of
// one value (stored as a tile rather than a leaf).
float headValue(int64_t i, int64_t j, int64_t k) {
  if (i >= 8 && i < 16 && j < 8 && k >= 8) return 40.0f;
  switch ((i * 7 + j * 13 + k * 29) % 6) {
    case 0:
      return -1024.0f;
    case 1:
      return -900.0f;
    case 2:
      return -900.25f;
    case 3:
      return 0.125f * static_cast<float>(i * j) - 50.0f;
    case 4:
      return 1200.5f + static_cast<float>(k);
    default:
      return -950.0f + static_cast<float>(j);
  }
}

int64_t countAtOrAbove(double threshold) {
  int64_t n = 0;
  for (int64_t k = 0; k < kDims[2]; ++k)
    for (int64_t j = 0; j < kDims[1]; ++j)
      for (int64_t i = 0; i < kDims[0]; ++i) n += headValue(i, j, k) >= threshold;
  return n;
}

void initializeOpenVdb() { openvdb::initialize(); }

// The grid of `file` as OpenVDB itself reads it (not through our reader).
openvdb::FloatGrid::Ptr readWithOpenVdb(const fs::path& file) {
  initializeOpenVdb();
  openvdb::io::File vdb(file.string());
  vdb.open(false);
  const openvdb::GridPtrVecPtr grids = vdb.getGrids();
  vdb.close();
  EXPECT_EQ(grids->size(), 1u);
  return openvdb::gridPtrCast<openvdb::FloatGrid>(grids->front());
}

// Writes `grids` with OpenVDB's own writer.
void writeWithOpenVdb(const fs::path& file, const openvdb::GridPtrVec& grids) {
  initializeOpenVdb();
  openvdb::io::File(file.string()).write(grids);
}

bool onlyFiles(const fs::path& dir, const std::set<std::string>& names) {
  std::set<std::string> found;
  for (const auto& e : fs::directory_iterator(dir)) found.insert(e.path().filename().string());
  return found == names;
}

// ---- export ---------------------------------------------------------------------------------

TEST(VdbExport, ActiveVoxelsKeepExactValuesAndTheAffine) {
  const auto dir = test::freshTempDir("vdb_roundtrip");
  const fs::path file = dir / "head.vdb";
  FunctionSource source(kDims, tiltedAffine(), headValue);
  int64_t lastDone = 0, lastTotal = 0;
  VdbExportOptions options;
  options.progress = [&](int64_t done, int64_t total) {
    EXPECT_GT(done, lastDone);
    lastDone = done;
    lastTotal = total;
  };
  const VdbExportReport report = exportVdb(source, file.string(), options);
  EXPECT_EQ(lastDone, kDims[2]);
  EXPECT_EQ(lastTotal, kDims[2]);
  EXPECT_LE(source.maxSlabSlices, 8) << "the volume must be read a slab at a time";
  const int64_t expectedActive = countAtOrAbove(-900);
  EXPECT_EQ(report.activeVoxels, expectedActive);
  EXPECT_EQ(report.bytesOnDisk, fs::file_size(file));
  EXPECT_TRUE(onlyFiles(dir, {"head.vdb"})) << "a temporary file was left behind";

  // Independently, through OpenVDB: the active set, the values, the transform, the metadata.
  const openvdb::FloatGrid::Ptr grid = readWithOpenVdb(file);
  ASSERT_TRUE(grid) << "not a float grid";
  EXPECT_EQ(grid->getName(), "density");
  EXPECT_EQ(grid->background(), -1000.0f);
  EXPECT_EQ(grid->getGridClass(), openvdb::GRID_UNKNOWN);
  EXPECT_EQ(grid->activeVoxelCount(), static_cast<openvdb::Index64>(expectedActive));
  EXPECT_EQ(grid->evalActiveVoxelBoundingBox(),
            openvdb::CoordBBox(openvdb::Coord(0, 0, 0), openvdb::Coord(20, 18, 12)));
  const auto accessor = grid->getConstAccessor();
  int64_t mismatches = 0;
  for (int64_t k = 0; k < kDims[2]; ++k)
    for (int64_t j = 0; j < kDims[1]; ++j)
      for (int64_t i = 0; i < kDims[0]; ++i) {
        const openvdb::Coord ijk(static_cast<int>(i), static_cast<int>(j), static_cast<int>(k));
        const float v = headValue(i, j, k);
        const bool active = v >= -900.0f;
        mismatches += accessor.isValueOn(ijk) != active;
        mismatches += accessor.getValue(ijk) != (active ? v : -1000.0f);
        // The grid transform maps index to patient LPS exactly as our affine does.
        const openvdb::Vec3d world = grid->indexToWorld(openvdb::Vec3d(ijk.asVec3d()));
        const Vec3 expected = tiltedAffine().transformPoint(
            {static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)});
        for (int a = 0; a < 3; ++a) EXPECT_NEAR(world[a], expected[a], 1e-9);
      }
  EXPECT_EQ(mismatches, 0);
  EXPECT_TRUE(grid->transform().isLinear());

  std::set<std::string> keys;
  for (auto it = grid->beginMeta(); it != grid->endMeta(); ++it) keys.insert(it->first);
  for (const char* key : {vdb_meta::kCoordinates, vdb_meta::kUnits, vdb_meta::kValueUnit,
                          vdb_meta::kThreshold, vdb_meta::kDescription, vdb_meta::kModality}) {
    EXPECT_TRUE(keys.count(key)) << key;
  }
  EXPECT_EQ(grid->metaValue<std::string>(vdb_meta::kCoordinates), "LPS");
  EXPECT_EQ(grid->metaValue<std::string>(vdb_meta::kUnits), "mm");
  EXPECT_EQ(grid->metaValue<std::string>(vdb_meta::kValueUnit), "HU");
  EXPECT_EQ(grid->metaValue<double>(vdb_meta::kThreshold), -900.0);
  EXPECT_EQ(grid->metaValue<std::string>(vdb_meta::kDescription), "phantom head");
  // No patient identifiers: only OpenVDB's own keys and ours.
  const std::set<std::string> openVdbKeys = {
      "class",           "creator",          "name",           "file_bbox_min",
      "file_bbox_max",   "file_compression", "file_mem_bytes", "file_voxel_count",
      "is_local_space",  "is_saved_as_half_float", "vector_type"};
  for (const std::string& key : keys) {
    EXPECT_TRUE(key.rfind("octoray_", 0) == 0 || openVdbKeys.count(key)) << key;
    std::string lower = key;
    for (char& c : lower) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    for (const char* banned : {"patient", "birth", "date", "accession", "institution"}) {
      EXPECT_EQ(lower.find(banned), std::string::npos) << key;
    }
  }

  // Through our reader: the same extent, affine and samples, air where inactive.
  const auto back = openVdb(file.string());
  const VolumeInfo& info = back->info();
  EXPECT_EQ(info.format, "vdb");
  EXPECT_EQ(info.dims, kDims);
  expectAffineNear(info.patientFromIndex, tiltedAffine(), 1e-9);
  EXPECT_EQ(info.unit, "HU");
  EXPECT_EQ(info.modality, "CT");
  EXPECT_EQ(info.description, "phantom head");
  EXPECT_FALSE(info.integerValues);
  EXPECT_EQ(info.valueLowerBound, -1000.0);
  EXPECT_EQ(info.valueUpperBound, 1200.5 + 12);
  EXPECT_TRUE(info.warnings.empty()) << info.warnings.front();
  expectValues(*back, 5, [](int64_t i, int64_t j, int64_t k) {
    const float v = headValue(i, j, k);
    return v >= -900.0f ? v : -1000.0f;
  });
  // openVolume picks the reader by extension.
  EXPECT_EQ(openVolume(file.string())->info().format, "vdb");
}

TEST(VdbExport, ActiveCountFollowsTheThreshold) {
  const auto dir = test::freshTempDir("vdb_threshold");
  for (double threshold : {-2000.0, -900.0, -900.125, 0.0, 1000.0}) {
    SCOPED_TRACE(threshold);
    FunctionSource source(kDims, tiltedAffine(), headValue);
    VdbExportOptions options;
    options.thresholdHu = threshold;
    const fs::path file = dir / "t.vdb";
    const VdbExportReport report = exportVdb(source, file.string(), options);
    EXPECT_EQ(report.activeVoxels, countAtOrAbove(threshold));
    EXPECT_EQ(readWithOpenVdb(file)->activeVoxelCount(),
              static_cast<openvdb::Index64>(countAtOrAbove(threshold)));
    EXPECT_EQ(readWithOpenVdb(file)->metaValue<double>(vdb_meta::kThreshold), threshold);
  }
  EXPECT_TRUE(onlyFiles(dir, {"t.vdb"}));
}

// The same grid built in memory, independently of the export: every sample at or above the
// threshold an active voxel, and an 8x8x8 block of 512 equal active samples a tile.
openvdb::FloatGrid::Ptr gridInMemory(const std::array<int64_t, 3>& dims, const VoxelFunction& value,
                                     float threshold) {
  auto grid = openvdb::FloatGrid::create(kVdbBackground);
  auto accessor = grid->getAccessor();
  for (int64_t k = 0; k < dims[2]; ++k)
    for (int64_t j = 0; j < dims[1]; ++j)
      for (int64_t i = 0; i < dims[0]; ++i) {
        const float v = value(i, j, k);
        if (v >= threshold) {
          accessor.setValueOn(openvdb::Coord(static_cast<int>(i), static_cast<int>(j),
                                             static_cast<int>(k)),
                              v);
        }
      }
  std::vector<std::pair<openvdb::Coord, float>> uniform;
  for (auto leaf = grid->tree().cbeginLeaf(); leaf; ++leaf) {
    const float* v = leaf->buffer().data();
    if (leaf->isValueMaskOn() && std::all_of(v, v + 512, [&](float x) { return x == v[0]; })) {
      uniform.emplace_back(leaf->origin(), v[0]);
    }
  }
  for (const auto& [origin, v] : uniform) grid->tree().addTile(1, origin, v, true);
  return grid;
}

// The export writes the topology and the leaves' values itself, from a spill file, around
// OpenVDB's own code for the rest; the file must be the one OpenVDB's writer makes of the same
// grid built in memory, byte for byte but for the random UUID in the header. Over several
// 128^3 nodes (their leaves are written in another order than the slabs produce them), and over
// two of the root's 4096^3 children, with leaves, empty blocks and nodes, and a tile.
TEST(VdbExport, WritesTheBytesOpenVdbWritesForTheSameGrid) {
  const auto dir = test::freshTempDir("vdb_bytes");
  for (const std::array<int64_t, 3> dims : {std::array<int64_t, 3>{260, 21, 137},  // 3 x 1 x 2
                                            std::array<int64_t, 3>{4100, 9, 20}}) {
    SCOPED_TRACE(fmt::format("{}x{}x{}", dims[0], dims[1], dims[2]));
    FunctionSource source(dims, tiltedAffine(), headValue);
    const fs::path streamed = dir / "streamed.vdb", inMemory = dir / "in_memory.vdb";
    exportVdb(source, streamed.string());
    const openvdb::FloatGrid::Ptr exported = readWithOpenVdb(streamed);
    ASSERT_TRUE(exported);
    const openvdb::FloatGrid::Ptr grid = gridInMemory(dims, headValue, -900.0f);
    EXPECT_GT(grid->tree().leafCount(), 100u);
    EXPECT_GT(grid->tree().activeTileCount(), 0u);
    EXPECT_EQ(grid->tree().root().childCount(), dims[0] > 4096 ? 2u : 1u);
    // The name, metadata and transform are OpenVDB's to write; the tree is the test's.
    for (auto meta = exported->beginMeta(); meta != exported->endMeta(); ++meta) {
      if (meta->first.rfind("file_", 0) != 0) grid->insertMeta(meta->first, *meta->second);
    }
    grid->setTransform(exported->transform().copy());
    writeWithOpenVdb(inMemory, {grid});

    auto bytes = [](const fs::path& file) {
      std::ifstream in(file, std::ios::binary);
      return std::string(std::istreambuf_iterator<char>(in), {});
    };
    const std::string a = bytes(streamed), b = bytes(inMemory);
    ASSERT_EQ(a.size(), b.size());
    // The header: magic (8 bytes), file and library versions (12), offsets flag (1), then the
    // 36-character UUID: bytes 21..56.
    int64_t differing = 0;
    for (std::size_t n = 0; n < a.size(); ++n) {
      if (a[n] != b[n] && (n < 21 || n >= 57)) {
        if (++differing <= 5) ADD_FAILURE() << "byte " << n << " of " << a.size() << " differs";
      }
    }
    EXPECT_EQ(differing, 0);
  }
}

TEST(VdbExport, FailureLeavesNoFile) {
  const auto dir = test::freshTempDir("vdb_fail");
  const fs::path file = dir / "f.vdb";
  FunctionSource failing(kDims, tiltedAffine(), headValue, 10);
  EXPECT_THROW(exportVdb(failing, file.string()), Error);
  EXPECT_TRUE(fs::is_empty(dir)) << "a partial or temporary file was left behind";

  // Nothing reaches the threshold: the grid would be empty, which is an error, not a file.
  FunctionSource air({9, 9, 9}, tiltedAffine(), [](int64_t, int64_t, int64_t) { return -1000.0f; });
  expectErrorMentioning([&] { exportVdb(air, file.string()); }, "threshold");
  EXPECT_TRUE(fs::is_empty(dir));

  // A failed export leaves an existing file untouched.
  writeFile(file, "previous contents");
  EXPECT_THROW(exportVdb(failing, file.string()), Error);
  EXPECT_TRUE(onlyFiles(dir, {"f.vdb"}));
  std::ifstream in(file);
  std::string contents((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_EQ(contents, "previous contents");

  FunctionSource ok({2, 2, 2}, tiltedAffine(), headValue);
  expectErrorMentioning([&] { exportVdb(ok, (dir / "no_such_folder" / "x.vdb").string()); },
                        "x.vdb");
}

// ---- input ----------------------------------------------------------------------------------

TEST(VdbFormat, ForeignGridUsesItsActiveBoundingBox) {
  const auto dir = test::freshTempDir("vdb_foreign");
  initializeOpenVdb();
  // Double values, a negative-index box, a scale-and-translate map, background 0, no metadata.
  auto grid = openvdb::DoubleGrid::create(0.0);
  grid->setTransform(openvdb::math::Transform::createLinearTransform(0.5));
  grid->transform().postTranslate(openvdb::Vec3d(10, -20, 30));
  auto accessor = grid->getAccessor();
  accessor.setValue(openvdb::Coord(-5, 3, 2), 7.0);
  accessor.setValue(openvdb::Coord(4, 9, 6), -3.0);
  accessor.setValue(openvdb::Coord(0, 5, 4), 2.5);
  grid->setName("temperature");
  auto other = openvdb::Vec3SGrid::create();
  other->setName("velocity");
  writeWithOpenVdb(dir / "foreign.vdb", {other, grid});

  const auto source = openVdb((dir / "foreign.vdb").string());
  const VolumeInfo& info = source->info();
  EXPECT_EQ(info.dims, (std::array<int64_t, 3>{10, 7, 5}));
  // patientFromIndex = 0.5 * (index + box min) + translation.
  expectAffineNear(info.patientFromIndex,
                   Mat4::fromColumns({0.5, 0, 0}, {0, 0.5, 0}, {0, 0, 0.5},
                                     {10 - 2.5, -20 + 1.5, 30 + 1}),
                   1e-12);
  EXPECT_FALSE(info.integerValues);
  EXPECT_EQ(info.valueLowerBound, -3.0);
  EXPECT_EQ(info.valueUpperBound, 7.0);
  EXPECT_EQ(info.description, "foreign.vdb");
  std::string warnings;
  for (const auto& w : info.warnings) warnings += w + "\n";
  EXPECT_NE(warnings.find("'velocity' (vec3s)"), std::string::npos) << warnings;
  EXPECT_NE(warnings.find("read grid 'temperature'"), std::string::npos) << warnings;
  EXPECT_NE(warnings.find("LPS"), std::string::npos) << warnings;
  expectValues(*source, 3, [](int64_t i, int64_t j, int64_t k) {
    if (i == 0 && j == 0 && k == 0) return 7.0f;
    if (i == 9 && j == 6 && k == 4) return -3.0f;
    if (i == 5 && j == 2 && k == 2) return 2.5f;
    return 0.0f;
  });
}

TEST(VdbFormat, TheDensityGridIsPreferred) {
  const auto dir = test::freshTempDir("vdb_density");
  initializeOpenVdb();
  openvdb::GridPtrVec grids;
  for (const char* name : {"albedo", "density", "flame"}) {
    auto grid = openvdb::FloatGrid::create(0.0f);
    grid->tree().setValue(openvdb::Coord(1, 2, 3), std::string(name) == "density" ? 2.0f : 1.0f);
    grid->setName(name);
    grids.push_back(grid);
  }
  writeWithOpenVdb(dir / "smoke.vdb", grids);
  const auto source = openVdb((dir / "smoke.vdb").string());
  EXPECT_EQ(source->info().dims, (std::array<int64_t, 3>{1, 1, 1}));
  EXPECT_TRUE(source->info().integerValues);
  expectValues(*source, 1, [](int64_t, int64_t, int64_t) { return 2.0f; });
}

TEST(VdbFormat, NonAffineTransformIsAClearError) {
  const auto dir = test::freshTempDir("vdb_frustum");
  initializeOpenVdb();
  auto grid = openvdb::FloatGrid::create(-1000.0f);
  const openvdb::BBoxd frustumBox(openvdb::Vec3d(0, 0, 0), openvdb::Vec3d(10, 10, 10));
  grid->setTransform(openvdb::math::Transform::createFrustumTransform(frustumBox, 0.5, 2.0, 1.0));
  grid->tree().setValue(openvdb::Coord(1, 2, 3), 100.0f);
  writeWithOpenVdb(dir / "frustum.vdb", {grid});
  ASSERT_FALSE(readWithOpenVdb(dir / "frustum.vdb")->transform().isLinear());
  const std::string path = (dir / "frustum.vdb").string();
  expectErrorMentioning([&] { openVdb(path); }, path);
  expectErrorMentioning([&] { openVdb(path); }, "non-affine transform (frustum)");
}

TEST(VdbFormat, GridsThatAreNotVolumesAreClearErrors) {
  const auto dir = test::freshTempDir("vdb_types");
  initializeOpenVdb();
  auto vectors = openvdb::Vec3SGrid::create();
  vectors->tree().setValue(openvdb::Coord(0, 0, 0), openvdb::Vec3s(1, 2, 3));
  vectors->setName("velocity");
  writeWithOpenVdb(dir / "vectors.vdb", {vectors});
  expectErrorMentioning([&] { openVdb((dir / "vectors.vdb").string()); }, "vec3s");
  expectErrorMentioning([&] { openVdb((dir / "vectors.vdb").string()); }, "vectors.vdb");

  writeWithOpenVdb(dir / "empty.vdb", {openvdb::FloatGrid::create(0.0f)});
  // A grid need not have a name: messages call it the unnamed grid, not grid ''.
  expectErrorMentioning([&] { openVdb((dir / "empty.vdb").string()); },
                        "the unnamed grid has no active voxels");
  vectors->setName("");
  writeWithOpenVdb(dir / "unnamed.vdb", {vectors});
  expectErrorMentioning([&] { openVdb((dir / "unnamed.vdb").string()); },
                        "no float or double grid to read as a volume (found unnamed (vec3s))");

  writeWithOpenVdb(dir / "none.vdb", {});
  expectErrorMentioning([&] { openVdb((dir / "none.vdb").string()); }, "no grids");
}

// A grid whose leaves hold more values than openVdb's limit is read in bands of slices: the same
// box, bounds and values as a whole read, slabs in any order, an active tile across many bands.
TEST(VdbFormat, AGridAboveTheLimitIsReadInBands) {
  const auto dir = test::freshTempDir("vdb_bands");
  initializeOpenVdb();
  // Voxels over x -3..36, y 5..30, z -13..41 (bands of 8 slices start at z = -16, -8, ..., so
  // the first is partial), every eleventh left inactive, and an active 128^3 tile at x 128..255.
  const auto voxel = [](int64_t x, int64_t y, int64_t z, float offset) {
    return static_cast<float>((x * 31 + y * 17 + z * 7) % 1000) + 0.5f * static_cast<float>(z % 2) +
           offset;
  };
  const auto inVoxels = [](int64_t x, int64_t y, int64_t z) {
    return x >= -3 && x <= 36 && y >= 5 && y <= 30 && z >= -13 && z <= 41 && (x + y + z) % 11 != 0;
  };
  const auto inTile = [](int64_t x, int64_t y, int64_t z) {
    return x >= 128 && x < 256 && y >= 0 && y < 128 && z >= 0 && z < 128;
  };
  // Uncompressed, so that a grid of the same topology and other values has the same bytes in
  // the same places.
  const auto write = [&](const fs::path& file, float offset) {
    auto grid = openvdb::FloatGrid::create(-1000.0f);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(0.75));
    grid->setName("density");
    auto accessor = grid->getAccessor();
    for (int z = -13; z <= 41; ++z)
      for (int y = 5; y <= 30; ++y)
        for (int x = -3; x <= 36; ++x) {
          if (inVoxels(x, y, z)) accessor.setValue(openvdb::Coord(x, y, z), voxel(x, y, z, offset));
        }
    grid->tree().addTile(2, openvdb::Coord(128, 0, 0), 2500.0f + offset, true);
    openvdb::io::File vdb(file.string());
    vdb.setCompression(openvdb::io::COMPRESS_NONE);
    vdb.write({grid});
  };
  const fs::path path = dir / "bands.vdb";
  write(path, 0.0f);
  // The box: x -3..255, y 0..127, z -13..127.
  // Tiles hold the value of the topology read at open, leaf voxels that of the file read.
  const auto expected = [&](float offset, float tileOffset) {
    return [&, offset, tileOffset](int64_t i, int64_t j, int64_t k) {
      const int64_t x = i - 3, y = j, z = k - 13;
      if (inTile(x, y, z)) return 2500.0f + tileOffset;
      return inVoxels(x, y, z) ? voxel(x, y, z, offset) : -1000.0f;
    };
  };

  const auto whole = openVdb(path.string());
  const auto banded = openVdb(path.string(), /*wholeGridBytes=*/1);
  const VolumeInfo& info = banded->info();
  EXPECT_EQ(info.dims, (std::array<int64_t, 3>{259, 128, 141}));
  EXPECT_EQ(info.dims, whole->info().dims);
  expectAffineNear(info.patientFromIndex, whole->info().patientFromIndex, 0);
  EXPECT_EQ(info.valueLowerBound, whole->info().valueLowerBound);
  EXPECT_EQ(info.valueUpperBound, whole->info().valueUpperBound);
  EXPECT_EQ(info.valueLowerBound, -1000.0);
  EXPECT_EQ(info.valueUpperBound, 2500.0);
  EXPECT_FALSE(info.integerValues);
  EXPECT_FALSE(whole->info().integerValues);
  // Front to back in slabs of 5, across the bands' edges.
  expectValues(*banded, 5, expected(0.0f, 0.0f));
  // Back to front: every slab lies before the band in memory and is read from the file again.
  const int64_t sliceSamples = info.sliceSamples();
  for (int64_t first = info.dims[2] - 3; first >= 0; first -= 9) {
    std::vector<float> slab(static_cast<std::size_t>(sliceSamples * 3));
    banded->readSlab(first, 3, slab);
    for (int64_t n = 0; n < sliceSamples * 3; ++n) {
      const int64_t k = first + n / sliceSamples, j = n % sliceSamples / info.dims[0],
                    i = n % info.dims[0];
      ASSERT_EQ(slab[static_cast<std::size_t>(n)], expected(0.0f, 0.0f)(i, j, k))
          << "at " << i << "," << j << "," << k;
    }
  }

  // The banded source holds one band of leaf values, no more: with the file's values changed
  // in place (the same bytes but the values, the same inode) it reads the new ones outside the
  // band in memory, while the whole grid read at open keeps the old. The band in memory is
  // the last one, which the first slabs below lie outside. The tiles' values are part of the
  // topology, which the banded source keeps from open.
  {
    std::vector<float> slab(static_cast<std::size_t>(sliceSamples));
    banded->readSlab(info.dims[2] - 1, 1, slab);
  }
  const auto openedAt = fs::last_write_time(path);
  write(dir / "other.vdb", 100.0f);
  std::string other;
  {
    std::ifstream in(dir / "other.vdb", std::ios::binary);
    other.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  ASSERT_EQ(other.size(), fs::file_size(path));
  std::fstream(path, std::ios::in | std::ios::out | std::ios::binary)
      .write(other.data(), static_cast<std::streamsize>(other.size()));
  const auto readFirstSlices = [&] {
    std::vector<float> slab(static_cast<std::size_t>(sliceSamples * 2));
    banded->readSlab(0, 2, slab);
  };
  // A file written to after it was opened is refused: where each leaf starts was read from the
  // file as it was then.
  expectErrorMentioning(readFirstSlices, path.string());
  expectErrorMentioning(readFirstSlices, "written to after it was opened");
  // With its modification time put back (the same layout, other values), it reads on.
  fs::last_write_time(path, openedAt);
  expectValues(*banded, 7, expected(100.0f, 0.0f));
  expectValues(*whole, 7, expected(0.0f, 0.0f));

  // A band read that fails (the file cut short under it) is an error naming the file, and
  // leaves no band behind; once the file is whole again the source reads on.
  fs::resize_file(path, other.size() / 2);
  expectErrorMentioning(readFirstSlices, path.string());
  expectErrorMentioning(readFirstSlices, "shorter than when it was opened");
  std::fstream(path, std::ios::in | std::ios::out | std::ios::binary)
      .write(other.data(), static_cast<std::streamsize>(other.size()));
  fs::last_write_time(path, openedAt);
  expectValues(*banded, 11, expected(100.0f, 0.0f));
}

// Read a leaf at a time, the values come out as OpenVDB's own whole read gives them, whatever
// the compression and with half floats: inactive voxels that hold the background (which active-
// mask compression does not store, and fills in from the tree's background) and ones that hold
// another value (which it stores).
TEST(VdbFormat, BandsReadEveryCompressionAsTheWholeGridDoes) {
  const auto dir = test::freshTempDir("vdb_band_compression");
  initializeOpenVdb();
  auto grid = openvdb::FloatGrid::create(-1000.0f);
  grid->setName("density");
  auto accessor = grid->getAccessor();
  for (int z = 0; z < 50; ++z)
    for (int y = 0; y < 30; ++y)
      for (int x = 0; x < 40; ++x) {
        const openvdb::Coord c(x, y, z);
        const float v = static_cast<float>((x * 13 + y * 7 + z * 29) % 3001) - 1000.25f;
        if ((x * y + z) % 5 == 0) {
          // Inactive: the background below z 24, another value above it.
          if (z >= 24) accessor.setValueOff(c, 7.0f + static_cast<float>(z));
        } else {
          accessor.setValue(c, v);
        }
      }
  using openvdb::io::COMPRESS_ACTIVE_MASK, openvdb::io::COMPRESS_ZIP;
  std::vector<uint32_t> compressions = {openvdb::io::COMPRESS_NONE, COMPRESS_ZIP,
                                        COMPRESS_ZIP | COMPRESS_ACTIVE_MASK, COMPRESS_ACTIVE_MASK};
  if (openvdb::io::Archive::hasBloscCompression()) {
    compressions.push_back(openvdb::io::COMPRESS_BLOSC | COMPRESS_ACTIVE_MASK);
  }
  for (const bool half : {false, true}) {
    for (const uint32_t compression : compressions) {
      SCOPED_TRACE(fmt::format("compression {}, half floats {}", compression, half));
      grid->setSaveFloatAsHalf(half);
      const fs::path path = dir / fmt::format("c{}h{}.vdb", compression, half ? 1 : 0);
      {
        openvdb::io::File vdb(path.string());
        vdb.setCompression(compression);
        vdb.write({grid});
      }
      const auto whole = openVdb(path.string());
      const auto banded = openVdb(path.string(), /*wholeGridBytes=*/1);
      ASSERT_EQ(banded->info().dims, whole->info().dims);
      EXPECT_EQ(banded->info().valueLowerBound, whole->info().valueLowerBound);
      EXPECT_EQ(banded->info().valueUpperBound, whole->info().valueUpperBound);
      const int64_t sliceSamples = whole->info().sliceSamples(), slices = whole->info().dims[2];
      std::vector<float> all(static_cast<std::size_t>(sliceSamples * slices));
      whole->readSlab(0, slices, all);
      // Spot checks of the whole read itself: an inactive voxel with the background, one with
      // its own value, an active one (at full precision where not stored as half).
      const auto at = [&](int64_t x, int64_t y, int64_t z) {
        return all[static_cast<std::size_t>(z * sliceSamples + y * 40 + x)];
      };
      EXPECT_EQ(at(0, 0, 0), -1000.0f);
      EXPECT_EQ(at(0, 0, 25), 32.0f);
      if (!half) {
        EXPECT_EQ(at(1, 1, 1), static_cast<float>((13 + 7 + 29) % 3001) - 1000.25f);
      }
      expectValues(*banded, 6, [&](int64_t i, int64_t j, int64_t k) { return at(i, j, k); });
    }
  }
}

// A grid that shares another's tree is written as an instance: its own metadata and transform,
// the parent's voxels. Read whole and in bands alike.
TEST(VdbFormat, AnInstanceGridReadsItsParentsVoxelsWithItsOwnTransform) {
  const auto dir = test::freshTempDir("vdb_instance");
  initializeOpenVdb();
  auto smoke = openvdb::FloatGrid::create(-1000.0f);
  smoke->setName("smoke");
  for (int z = 0; z < 20; ++z)
    for (int y = 0; y < 3; ++y)
      for (int x = 0; x < 4; ++x) {
        smoke->tree().setValue(openvdb::Coord(x, y, z), static_cast<float>(x + 10 * y + 100 * z));
      }
  auto density = openvdb::gridPtrCast<openvdb::FloatGrid>(smoke->copyGrid());  // the same tree
  density->setName("density");
  density->setTransform(openvdb::math::Transform::createLinearTransform(2.0));
  writeWithOpenVdb(dir / "instance.vdb", {smoke, density});
  const std::string path = (dir / "instance.vdb").string();
  for (const uint64_t wholeGridBytes : {kVdbWholeGridBytes, uint64_t{1}}) {
    SCOPED_TRACE(wholeGridBytes);
    const auto source = openVdb(path, wholeGridBytes);
    EXPECT_EQ(source->info().dims, (std::array<int64_t, 3>{4, 3, 20}));
    expectAffineNear(source->info().patientFromIndex,
                     Mat4::fromColumns({2, 0, 0}, {0, 2, 0}, {0, 0, 2}, {0, 0, 0}), 0);
    EXPECT_EQ(source->info().valueUpperBound, 3.0 + 20 + 1900);
    expectValues(*source, 6, [](int64_t i, int64_t j, int64_t k) {
      return static_cast<float>(i + 10 * j + 100 * k);
    });
  }
}

TEST(VdbFormat, DamagedFilesAreClearErrors) {
  const auto dir = test::freshTempDir("vdb_damaged");
  FunctionSource source(kDims, tiltedAffine(), headValue);
  const fs::path good = dir / "good.vdb";
  exportVdb(source, good.string());
  std::string bytes;
  {
    std::ifstream in(good, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  ASSERT_GT(bytes.size(), 200u);

  writeFile(dir / "text.vdb", "this is not a VDB file\n");
  expectErrorMentioning([&] { openVdb((dir / "text.vdb").string()); }, "text.vdb");
  writeFile(dir / "zero.vdb", "");
  expectErrorMentioning([&] { openVdb((dir / "zero.vdb").string()); }, "zero.vdb");
  // Cut in the header, in the grid descriptor and metadata, in the tree, and at the last bytes.
  for (std::size_t keep : {std::size_t{8}, std::size_t{100}, bytes.size() / 2, bytes.size() - 8}) {
    SCOPED_TRACE(keep);
    const fs::path cut = dir / fmt::format("cut{}.vdb", keep);
    writeFile(cut, bytes.substr(0, keep));
    expectErrorMentioning([&] { openVdb(cut.string()); }, cut.string());
  }
  expectErrorMentioning([&] { openVdb((dir / "missing.vdb").string()); }, "missing.vdb");
}

}  // namespace
}  // namespace octoray
