// The store holds exactly what the source gave: every leaf sample, every replicated border
// sample, every filtered inner sample, and min/max ranges that bound whole subtrees.
#include <gtest/gtest.h>

#include <limits>
#include <random>

#include "memory_volume.h"
#include "store_leaf_check.h"
#include "octoray/core/error.h"
#include "octoray/volume/store_builder.h"
#include "octoray/volume/store_reader.h"
#include "test_paths.h"

namespace octoray::volume {
namespace {

using test::MemoryVolume;

// Level samples computed independently of the builder: the 2x2x2 box filter, clamped at the
// edges, applied recursively from the source values, rounded half up in integers.
std::vector<std::vector<int64_t>> referenceLevels(const MemoryVolume& v, const OctreeLayout& layout) {
  std::vector<std::vector<int64_t>> levels(static_cast<std::size_t>(layout.levels()));
  const int leaf = layout.leafLevel();
  const Index3 d = layout.levelDims(leaf);
  auto& leafValues = levels[static_cast<std::size_t>(leaf)];
  for (int64_t k = 0; k < d[2]; ++k)
    for (int64_t j = 0; j < d[1]; ++j)
      for (int64_t i = 0; i < d[0]; ++i) leafValues.push_back(static_cast<int64_t>(v.at(i, j, k)) + 1024);
  for (int l = leaf - 1; l >= 0; --l) {
    const Index3 fd = layout.levelDims(l + 1), cd = layout.levelDims(l);
    const auto& fine = levels[static_cast<std::size_t>(l + 1)];
    auto& coarse = levels[static_cast<std::size_t>(l)];
    const auto f = [&](int64_t i, int64_t j, int64_t k) {
      return fine[static_cast<std::size_t>(std::min(i, fd[0] - 1) + fd[0] * (std::min(j, fd[1] - 1) + fd[1] * std::min(k, fd[2] - 1)))];
    };
    for (int64_t k = 0; k < cd[2]; ++k)
      for (int64_t j = 0; j < cd[1]; ++j)
        for (int64_t i = 0; i < cd[0]; ++i) {
          int64_t sum = 0;
          for (int dz = 0; dz < 2; ++dz)
            for (int dy = 0; dy < 2; ++dy)
              for (int dx = 0; dx < 2; ++dx) sum += f(2 * i + dx, 2 * j + dy, 2 * k + dz);
          coarse.push_back((sum + 4) / 8);
        }
  }
  return levels;
}

void expectStoreMatches(const MemoryVolume& v, const std::string& path, int brickSize, int border) {
  test::expectStoreValid(path);
  const StoreReader store(path);
  const OctreeLayout& layout = store.layout();
  ASSERT_EQ(store.header().brickSize, static_cast<uint32_t>(brickSize));
  const auto levels = referenceLevels(v, layout);
  const int64_t B = brickSize, A = border, E = B + 2 * A;
  for (int64_t id = 0; id < layout.nodeCount(); ++id) {
    const NodeKey key = layout.nodeKey(id);
    const Index3 d = layout.levelDims(key.level);
    const auto& ref = levels[static_cast<std::size_t>(key.level)];
    const Brick brick = store.readBrick(id);
    ASSERT_EQ(brick.u16.size(), static_cast<std::size_t>(E * E * E));
    int64_t lo = INT64_MAX, hi = INT64_MIN;
    for (int64_t z = 0; z < E; ++z)
      for (int64_t y = 0; y < E; ++y)
        for (int64_t x = 0; x < E; ++x) {
          // Border and out-of-volume samples replicate the nearest sample of the same level.
          const int64_t gx = std::clamp(key.brick[0] * B - A + x, int64_t{0}, d[0] - 1);
          const int64_t gy = std::clamp(key.brick[1] * B - A + y, int64_t{0}, d[1] - 1);
          const int64_t gz = std::clamp(key.brick[2] * B - A + z, int64_t{0}, d[2] - 1);
          const int64_t expected = ref[static_cast<std::size_t>(gx + d[0] * (gy + d[1] * gz))];
          const int64_t got = brick.u16[static_cast<std::size_t>(x + E * (y + E * z))];
          ASSERT_EQ(got, expected) << "node " << id << " level " << key.level << " sample " << x << "," << y << "," << z;
          lo = std::min(lo, got);
          hi = std::max(hi, got);
        }
    const NodeRecord& r = store.node(id);
    EXPECT_LE(r.minValue, store.physical(static_cast<double>(lo))) << "node " << id;
    EXPECT_GE(r.maxValue, store.physical(static_cast<double>(hi))) << "node " << id;
    for (int64_t child : layout.children(id)) {
      EXPECT_LE(r.minValue, store.node(child).minValue);
      EXPECT_GE(r.maxValue, store.node(child).maxValue);
    }
  }
}

struct Case {
  std::array<int64_t, 3> dims;
  int brickSize, border;
};

class StoreRoundTrip : public ::testing::TestWithParam<Case> {};

TEST_P(StoreRoundTrip, EveryLeafBorderAndInnerSampleIsExact) {
  const Case c = GetParam();
  std::mt19937 rng(42);
  std::uniform_int_distribution<int> hu(-1024, 3071);
  MemoryVolume volume(c.dims, [&](int64_t i, int64_t, int64_t k) {
    // Random values with constant regions in places, so constant bricks occur too.
    return k % 3 == 0 && i < 20 ? -1000.0f : static_cast<float>(hu(rng));
  });
  const auto dir = test::freshTempDir("store");
  const std::string path = (dir / "v.octoray").string();
  BuildOptions options;
  options.brickSize = c.brickSize;
  options.border = c.border;
  const BuildReport report = buildStore(volume, path, options);
  EXPECT_EQ(report.voxels, c.dims[0] * c.dims[1] * c.dims[2]);
  EXPECT_EQ(report.clampedSamples, 0);
  expectStoreMatches(volume, path, c.brickSize, c.border);
}

INSTANTIATE_TEST_SUITE_P(Sizes, StoreRoundTrip,
                         ::testing::Values(Case{{1, 1, 1}, 16, 1}, Case{{33, 17, 5}, 16, 1},
                                           Case{{33, 17, 5}, 16, 2}, Case{{70, 40, 90}, 32, 1},
                                           Case{{65, 64, 33}, 32, 2}, Case{{130, 20, 70}, 64, 1}));

// A float volume with a NaN or an infinity: refused, naming the source and the sample (it
// used to import and validate, then fail to render with "opacity table range [-inf, inf]").
TEST(StoreBuild, NonFiniteFloatSamplesAreRefusedNamingTheSample) {
  const auto dir = test::freshTempDir("nonfinite");
  for (const float bad : {std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::infinity()}) {
    MemoryVolume volume({20, 18, 16}, [bad](int64_t i, int64_t j, int64_t k) {
      return i == 3 && j == 5 && k == 7 ? bad : 0.25f * static_cast<float>(i + j + k);
    }, "", false);
    BuildOptions options;
    options.brickSize = 16;
    options.format = BuildOptions::Format::Float32;
    const std::string path = (dir / "v.octoray").string();
    try {
      buildStore(volume, path, options);
      FAIL() << "a non-finite sample was stored";
    } catch (const Error& e) {
      EXPECT_NE(e.reason().find("slice 7, column 3, row 5"), std::string::npos) << e.what();
    }
    EXPECT_FALSE(std::filesystem::exists(path));
  }
}

// What the builder records about the source comes back through StoreReader::source(), and
// provenance that is not what the builder writes (another JSON type in a field, no "source",
// not JSON) gives empty fields instead of an exception: octoray-render's own parse of it threw
// nlohmann's type_error, naming no file, on a unit that was not a string.
TEST(StoreBuild, ProvenanceSourceFieldsComeBackAndOtherTypesAreEmpty) {
  const auto dir = test::freshTempDir("provenance_source");
  for (const bool integer : {true, false}) {
    MemoryVolume volume({20, 18, 16}, [integer](int64_t i, int64_t j, int64_t k) {
      return static_cast<float>(i + j + k) + (integer ? 0.0f : 0.25f);
    }, integer ? "HU" : "", integer);
    BuildOptions options;
    options.brickSize = 16;
    options.format = BuildOptions::Format::Float32;
    options.sourceContentHash = "0123456789abcdef";
    if (integer) volume.setWindows({{40, 80, "", ""}, {-600, 1500, "LUNG", "SIGMOID"}});
    const std::string path = (dir / (integer ? "hu.octoray" : "plain.octoray")).string();
    buildStore(volume, path, options);
    const StoreReader store(path);
    EXPECT_EQ(store.source().format, "memory");
    EXPECT_EQ(store.source().unit, integer ? "HU" : "");
    EXPECT_EQ(store.source().contentHash, "0123456789abcdef");
    ASSERT_TRUE(store.source().integerValues.has_value());
    EXPECT_EQ(*store.source().integerValues, integer);
    // The display windows the source names, in order; none where it names none.
    ASSERT_EQ(store.source().windows.size(), integer ? 2u : 0u);
    if (integer) {
      EXPECT_EQ(store.source().windows[0].center, 40);
      EXPECT_EQ(store.source().windows[0].width, 80);
      EXPECT_EQ(store.source().windows[0].explanation, "");
      EXPECT_EQ(store.source().windows[0].function, "");
      EXPECT_EQ(store.source().windows[1].center, -600);
      EXPECT_EQ(store.source().windows[1].width, 1500);
      EXPECT_EQ(store.source().windows[1].explanation, "LUNG");
      EXPECT_EQ(store.source().windows[1].function, "SIGMOID");
    }
  }
  for (const char* provenance :
       {"not json", "[1, 2]", "{}", R"({"source": 5})", R"({"source": null})",
        R"({"source": {"unit": 5, "modality": ["CT"], "integerValues": "yes", "contentHash": {}}})"}) {
    StoreSource source;
    EXPECT_NO_THROW(source = parseStoreSource(provenance)) << provenance;
    EXPECT_EQ(source.unit, "") << provenance;
    EXPECT_EQ(source.modality, "") << provenance;
    EXPECT_EQ(source.contentHash, "") << provenance;
    EXPECT_FALSE(source.integerValues.has_value()) << provenance;
    EXPECT_TRUE(source.windows.empty()) << provenance;
  }
  // DICOM text in the file's character set (ISO_IR 100: Sch\xe4del, not UTF-8) is stored with
  // U+FFFD for the bytes that are not UTF-8, instead of failing the build.
  {
    MemoryVolume latin1({16, 16, 16}, [](int64_t i, int64_t, int64_t) { return static_cast<float>(i); });
    latin1.setDescription("Sch\xe4" "del");
    latin1.setWindows({{40, 80, "Sch\xe4" "del", ""}});
    BuildOptions options;
    options.brickSize = 16;
    const std::string path = (dir / "latin1.octoray").string();
    ASSERT_NO_THROW(buildStore(latin1, path, options));
    const StoreReader store(path);
    EXPECT_EQ(store.source().description, "Sch\xef\xbf\xbd" "del");
    ASSERT_EQ(store.source().windows.size(), 1u);
    EXPECT_EQ(store.source().windows[0].explanation, "Sch\xef\xbf\xbd" "del");
  }
  // A window that is not a finite center with a positive width is left out, the others kept.
  const StoreSource windows = parseStoreSource(
      R"({"source": {"windows": [{"center": 40, "width": 80}, {"center": "40", "width": 80}, 7,
          {"center": 1, "width": 0}, {"center": 1, "width": -5}, {"center": null, "width": 3},
          {"center": -600, "width": 1500, "explanation": ["LUNG"]},
          {"center": 5, "width": 9, "function": "LINEAR_EXACT"}, {"center": 5, "width": 9, "function": "LOG"},
          {"center": 5, "width": 9, "function": 3}]}})");
  ASSERT_EQ(windows.windows.size(), 5u);
  EXPECT_EQ(windows.windows[0].center, 40);
  EXPECT_EQ(windows.windows[1].width, 1500);
  EXPECT_EQ(windows.windows[1].explanation, "");
  // A function that is not a defined term (or not a string) reads as none.
  EXPECT_EQ(windows.windows[2].function, "LINEAR_EXACT");
  EXPECT_EQ(windows.windows[3].function, "");
  EXPECT_EQ(windows.windows[4].function, "");
  EXPECT_TRUE(parseStoreSource(R"({"source": {"windows": {"center": 40, "width": 80}}})").windows.empty());
  const StoreSource ct = parseStoreSource(
      R"({"source": {"modality": "CT", "unit": "HU", "seriesUid": "1.2.3", "integerValues": true}})");
  EXPECT_EQ(ct.modality, "CT");
  EXPECT_EQ(ct.unit, "HU");
  EXPECT_EQ(ct.seriesUid, "1.2.3");
  EXPECT_EQ(ct.integerValues, std::optional<bool>(true));
}

// Whether a store holds Hounsfield units (what the viewer's windows, labels and default
// transfer function, and octoray-render's defaults, follow): what the source says, else integer
// values reaching down to air. The same rule on the source's fields directly.
TEST(StoreBuild, HounsfieldUnitsAreWhatTheSourceSaysOrIntegerValuesDownToAir) {
  const auto dir = test::freshTempDir("store_hounsfield");
  struct UnitCase {
    const char* name;
    float minimum;
    std::string unit;
    bool integer;
    bool hounsfield, guessed;
  };
  const UnitCase cases[] = {
      {"said", 0, "HU", true, true, false},            // unit HU: whatever the values
      {"air", -1024, "", true, true, true},            // NIfTI CT without units
      {"padding", -3024, "", true, true, true},        // outside the field of view
      {"no-air", -500, "", true, false, false},        // nothing down to air
      {"below", -3200, "", true, false, false},        // below any CT value
      {"floats", -1024, "", false, false, false},      // not integers: not judged
  };
  for (const UnitCase& c : cases) {
    MemoryVolume volume({20, 18, 16}, [&](int64_t i, int64_t j, int64_t k) {
      return i + j + k == 0 ? c.minimum : 100.0f + static_cast<float>(i) + (c.integer ? 0.0f : 0.5f);
    }, c.unit, c.integer);
    BuildOptions options;
    options.brickSize = 16;
    const std::string path = (dir / (std::string(c.name) + ".octoray")).string();
    buildStore(volume, path, options);
    const StoreReader store(path);
    bool guessed = !c.guessed;
    EXPECT_EQ(storeHoldsHounsfieldUnits(store, &guessed), c.hounsfield) << c.name;
    EXPECT_EQ(guessed, c.guessed) << c.name;
  }
  // A DICOM modality other than CT says no, whatever the values.
  bool guessed = true;
  EXPECT_FALSE(holdsHounsfieldUnits("", "MR", true, -1024, &guessed));
  EXPECT_FALSE(guessed);
  EXPECT_TRUE(holdsHounsfieldUnits("", "CT", false, 0, &guessed));
  EXPECT_FALSE(guessed);
  EXPECT_FALSE(holdsHounsfieldUnits("", "", true, std::numeric_limits<double>::quiet_NaN()));
}

TEST(StoreBuild, CodecsAreLossless) {
  MemoryVolume volume({50, 45, 40}, [](int64_t i, int64_t j, int64_t k) {
    return static_cast<float>((i * 7 + j * 13 + k * 29) % 2000 - 1000);
  });
  const auto dir = test::freshTempDir("codecs");
  for (Codec codec : {Codec::None, Codec::Lz4, Codec::Zstd}) {
    BuildOptions options;
    options.brickSize = 16;
    options.codec = codec;
    const std::string path = (dir / ("v" + std::to_string(static_cast<int>(codec)) + ".octoray")).string();
    buildStore(volume, path, options);
    expectStoreMatches(volume, path, 16, 1);
  }
}

TEST(StoreBuild, OddSized513x512x140LeavesAreExact) {
  MemoryVolume volume({513, 512, 140}, [](int64_t i, int64_t j, int64_t k) {
    return static_cast<float>((i * 31 + j * 17 + k * 7) % 3000 - 1024);
  });
  const std::string path = (test::freshTempDir("odd") / "odd.octoray").string();
  buildStore(volume, path);
  const StoreReader store(path);
  EXPECT_EQ(test::expectLeavesEqualSource(volume, store), volume.info().sampleCount());
  test::expectStoreValid(path);
}

}  // namespace
}  // namespace octoray::volume
