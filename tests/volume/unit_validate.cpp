// The validator passes every store the builder writes, and each kind of damage fails the
// check that names it (and not the checks that cannot see it). octoray-validate's exit status
// and output follow the report; DICOM folder validation on the Philips data names what is
// missing and what is not a volume.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <fmt/format.h>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <nlohmann/json.hpp>
#include <random>

#define XXH_INLINE_ALL
#include <xxhash.h>

#include "memory_volume.h"
#include "octoray/core/error.h"
#include "octoray/volume/store_builder.h"
#include "octoray/volume/store_reader.h"
#include "octoray/volume/store_validator.h"
#include "run_process.h"
#include "test_paths.h"

namespace octoray::volume {
namespace {

namespace fs = std::filesystem;
using test::MemoryVolume;
using Bytes = std::vector<char>;

const char* const kAllChecks[] = {"header",  "geometry", "checksums", "ranges",
                                  "borders", "filter",   "constants"};

// A CT-like volume: a smooth ramp with detail, and air (constant bricks) in its last slices.
MemoryVolume ctVolume(Index3 dims) {
  return MemoryVolume(dims, [dims](int64_t i, int64_t j, int64_t k) {
    if (k >= dims[2] * 3 / 4 && dims[2] > 40) return -1024.0f;
    return static_cast<float>((i * 7 + j * 13 + k * 5) % 301 - 150 +
                              40 * std::sin(0.2 * static_cast<double>(i + 2 * j)));
  });
}

// Non-integer values with no unit: stored as Float32.
MemoryVolume floatVolume(Index3 dims) {
  return MemoryVolume(
      dims,
      [](int64_t i, int64_t j, int64_t k) {
        return static_cast<float>(std::sin(0.31 * static_cast<double>(i)) * 100.25 +
                                  std::cos(0.17 * static_cast<double>(j * k)) * 3.1 +
                                  0.001 * static_cast<double>(k));
      },
      "", false);
}

std::string buildTestStore(MemoryVolume& volume, const std::string& name, int brickSize,
                           int border) {
  const fs::path dir = test::freshTempDir("validate_" + name);
  const std::string path = (dir / "store.octoray").string();
  BuildOptions options;
  options.brickSize = brickSize;
  options.border = border;
  options.memoryBudgetBytes = uint64_t{64} << 20;
  buildStore(volume, path, options);
  return path;
}

Bytes readBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return Bytes(std::istreambuf_iterator<char>(in), {});
}

void writeBytes(const std::string& path, const Bytes& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

StoreHeader headerOf(const Bytes& bytes) {
  StoreHeader h;
  std::memcpy(&h, bytes.data(), sizeof h);
  return h;
}

// The node table, copied out of (and back into) the file's bytes: the table need not be
// aligned in the file, so it is never accessed in place.
std::vector<NodeRecord> readTable(const Bytes& bytes) {
  const StoreHeader h = headerOf(bytes);
  std::vector<NodeRecord> table(h.nodeCount);
  std::memcpy(table.data(), bytes.data() + h.nodeTableOffset, h.nodeTableBytes);
  return table;
}

void writeTable(Bytes& bytes, const std::vector<NodeRecord>& table) {
  const StoreHeader h = headerOf(bytes);
  std::memcpy(bytes.data() + h.nodeTableOffset, table.data(), h.nodeTableBytes);
}

// Recomputes the node table checksum and the header checksum, so that only the intended
// damage remains.
void resealChecksums(Bytes& bytes) {
  StoreHeader h = headerOf(bytes);
  h.nodeTableChecksum = XXH3_64bits(bytes.data() + h.nodeTableOffset, h.nodeTableBytes);
  h.headerChecksum = XXH3_64bits(&h, offsetof(StoreHeader, headerChecksum));
  std::memcpy(bytes.data(), &h, sizeof h);
}

std::string copyWith(const std::string& path, const std::string& name, const Bytes& bytes) {
  const std::string out = (fs::path(path).parent_path() / name).string();
  writeBytes(out, bytes);
  return out;
}

// Every check ran; those in `failing` failed and every other passed.
void expectOnlyFailing(const ValidationReport& report, std::initializer_list<std::string> failing) {
  ASSERT_EQ(report.checks.size(), std::size(kAllChecks));
  for (const CheckResult& c : report.checks) {
    const bool shouldFail = std::find(failing.begin(), failing.end(), c.name) != failing.end();
    std::string failures;
    for (const auto& f : c.failures)
      failures += "\n  node " + std::to_string(f.nodeId) + ": " + f.message;
    EXPECT_EQ(c.status, shouldFail ? CheckStatus::Failed : CheckStatus::Passed)
        << c.name << " is " << toString(c.status) << failures;
  }
}

// A non-constant leaf node; `skip` picks a later one.
int64_t payloadNode(const StoreReader& store, int skip = 0) {
  for (int64_t id = store.layout().levelNodeOffset(store.layout().leafLevel());
       id < store.layout().nodeCount(); ++id) {
    if (!(store.node(id).flags & kNodeConstant) && skip-- == 0) return id;
  }
  return -1;
}

struct StoreCase {
  Index3 dims;
  int brickSize, border;
  bool float32;
};

class ValidStores : public ::testing::TestWithParam<StoreCase> {};

TEST_P(ValidStores, PassEveryCheck) {
  const StoreCase& c = GetParam();
  MemoryVolume volume = c.float32 ? floatVolume(c.dims) : ctVolume(c.dims);
  const std::string path = buildTestStore(volume, "valid", c.brickSize, c.border);
  int64_t calls = 0, last = 0;
  StoreValidationOptions options;
  options.progress = [&](int64_t done, int64_t) { ++calls, last = std::max(last, done); };
  options.cacheBudgetBytes = 1 << 20;  // small: bricks are evicted and read again
  const ValidationReport report = validateStore(path, options);
  expectOnlyFailing(report, {});
  EXPECT_TRUE(report.passed());
  const StoreReader store(path);
  EXPECT_EQ(store.sampleFormat(), c.float32 ? SampleFormat::Float32 : SampleFormat::UInt16);
  EXPECT_EQ(report.find("checksums")->checked, store.layout().nodeCount());
  EXPECT_EQ(report.find("borders")->checked, store.layout().nodeCount());
  EXPECT_EQ(
      report.find("filter")->checked,
      store.layout().nodeCount() - store.layout().levelBricks(store.layout().leafLevel())[0] *
                                       store.layout().levelBricks(store.layout().leafLevel())[1] *
                                       store.layout().levelBricks(store.layout().leafLevel())[2]);
  EXPECT_GT(calls, 0);
  EXPECT_EQ(last, store.layout().nodeCount());
}

INSTANTIATE_TEST_SUITE_P(
    Sizes, ValidStores,
    ::testing::Values(StoreCase{{40, 37, 23}, 16, 1, false}, StoreCase{{17, 16, 16}, 16, 2, false},
                      StoreCase{{70, 33, 50}, 32, 2, false}, StoreCase{{100, 66, 80}, 32, 1, false},
                      StoreCase{{35, 49, 18}, 16, 1, true}, StoreCase{{70, 33, 50}, 32, 2, true},
                      StoreCase{{5, 3, 1}, 16, 1, false}));

class DamagedStore : public ::testing::Test {
 protected:
  void SetUp() override {
    static MemoryVolume volume = ctVolume({70, 45, 60});
    static const std::string built = buildTestStore(volume, "damaged", 16, 1);
    path_ = built;
    bytes_ = readBytes(path_);
  }
  std::string path_;
  Bytes bytes_;
};

TEST_F(DamagedStore, FlippedPayloadByteFailsChecksumsOnly) {
  const StoreReader store(path_);
  const int64_t id = payloadNode(store);
  ASSERT_GE(id, 0);
  const NodeRecord& r = store.node(id);
  bytes_[r.payloadOffset + r.payloadBytes / 2] ^= 0x20;
  const ValidationReport report = validateStore(copyWith(path_, "flipped.octoray", bytes_));
  expectOnlyFailing(report, {"checksums"});
  const CheckResult& checksums = *report.find("checksums");
  EXPECT_EQ(checksums.failedCount, 1);
  ASSERT_EQ(checksums.failures.size(), 1u);
  EXPECT_EQ(checksums.failures[0].nodeId, id);
  EXPECT_NE(checksums.failures[0].message.find("checksum"), std::string::npos)
      << checksums.failures[0].message;
}

TEST_F(DamagedStore, TruncatedTailFailsHeaderOnFileSize) {
  bytes_.resize(bytes_.size() - 7);
  const ValidationReport report = validateStore(copyWith(path_, "truncated.octoray", bytes_));
  const CheckResult& header = *report.find("header");
  EXPECT_EQ(header.status, CheckStatus::Failed);
  ASSERT_FALSE(header.failures.empty());
  EXPECT_NE(header.failures[0].message.find("bytes"), std::string::npos)
      << header.failures[0].message;
  EXPECT_EQ(report.find("checksums")->status, CheckStatus::NotRun);
  EXPECT_FALSE(report.passed());
}

TEST_F(DamagedStore, WrongVersionFailsHeaderNamingTheVersion) {
  StoreHeader h = headerOf(bytes_);
  h.version = kStoreVersion + 1;
  h.headerChecksum = XXH3_64bits(&h, offsetof(StoreHeader, headerChecksum));
  std::memcpy(bytes_.data(), &h, sizeof h);
  const ValidationReport report = validateStore(copyWith(path_, "version.octoray", bytes_));
  const CheckResult& header = *report.find("header");
  EXPECT_EQ(header.status, CheckStatus::Failed);
  ASSERT_FALSE(header.failures.empty());
  EXPECT_NE(header.failures[0].message.find("version"), std::string::npos)
      << header.failures[0].message;
  EXPECT_EQ(report.find("geometry")->status, CheckStatus::NotRun);
}

// Header fields that the checksum covers but no build writes (a forged or mis-written header,
// resealed): each fails the header check (the geometry check for the affine) by name, before
// anything reads a brick or renders.
TEST_F(DamagedStore, ImpossibleHeaderFieldsFailHeaderNamingTheField) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const float nanf = std::numeric_limits<float>::quiet_NaN();
  struct Case {
    std::function<void(StoreHeader&)> forge;
    std::string check, message;
  };
  const std::vector<Case> cases = {
      {[&](StoreHeader& h) { h.valueScale = nan; }, "header", "header: invalid value mapping"},
      {[](StoreHeader& h) { h.valueScale = 0; }, "header", "header: invalid value mapping"},
      {[&](StoreHeader& h) { h.patientFromIndex[3] = nan; }, "geometry",
       "header: non-finite affine"},
      {[](StoreHeader& h) { h.flags = 0x6; }, "header", "header: unknown flags 0x6"},
      {[&](StoreHeader& h) { h.gradientScale = nanf; }, "header",
       "header: gradient scale nan is not a finite non-negative number"},
      {[](StoreHeader& h) { h.gradientScale = -1; }, "header",
       "header: gradient scale -1 is not a finite non-negative number"},
      {[](StoreHeader& h) { h.flags = kStoreHasGradients, h.gradientScale = 0; }, "header",
       "header: gradient scale 0 is not a positive number"},
  };
  ASSERT_EQ(headerOf(bytes_).flags, 0u);
  ASSERT_EQ(headerOf(bytes_).gradientScale, 0.0f);
  int n = 0;
  for (const Case& c : cases) {
    Bytes bytes = bytes_;
    StoreHeader h = headerOf(bytes);
    c.forge(h);
    h.headerChecksum = XXH3_64bits(&h, offsetof(StoreHeader, headerChecksum));
    std::memcpy(bytes.data(), &h, sizeof h);
    const std::string path = copyWith(path_, fmt::format("forged{}.octoray", n++), bytes);
    const ValidationReport report = validateStore(path);
    const CheckResult& failed = *report.find(c.check);
    EXPECT_EQ(failed.status, CheckStatus::Failed) << c.message;
    ASSERT_EQ(failed.failures.size(), 1u) << c.message;
    EXPECT_EQ(failed.failures[0].message, c.message);
    EXPECT_EQ(report.find("checksums")->status, CheckStatus::NotRun) << c.message;
    EXPECT_THROW(StoreReader{path}, Error) << c.message;
  }
}

TEST_F(DamagedStore, SwappedBricksFailBordersOrFilterNotChecksums) {
  const StoreReader store(path_);
  const int64_t a = payloadNode(store, 0), b = payloadNode(store, 5);
  ASSERT_GE(b, 0);
  ASSERT_NE(store.readBrick(a).u16, store.readBrick(b).u16);
  // Each record points at the other's payload, with the other's checksum: every brick still
  // reads and verifies, but sits in the wrong place.
  std::vector<NodeRecord> table = readTable(bytes_);
  std::swap(table[a].payloadOffset, table[b].payloadOffset);
  std::swap(table[a].payloadBytes, table[b].payloadBytes);
  std::swap(table[a].gradientBytes, table[b].gradientBytes);
  std::swap(table[a].payloadChecksum, table[b].payloadChecksum);
  writeTable(bytes_, table);
  resealChecksums(bytes_);
  const ValidationReport report = validateStore(copyWith(path_, "swapped.octoray", bytes_));
  EXPECT_EQ(report.find("header")->status, CheckStatus::Passed);
  EXPECT_EQ(report.find("checksums")->status, CheckStatus::Passed);
  EXPECT_TRUE(!report.find("borders")->passed() || !report.find("filter")->passed());
  bool namesA = false;
  for (const auto& f : report.find("borders")->failures)
    namesA = namesA || f.nodeId == a || f.nodeId == b;
  EXPECT_TRUE(namesA);
}

// A flipped byte in the version field is damage ("corrupted"), not a store from the future.
TEST_F(DamagedStore, FlippedVersionByteIsCorruptionNotAFutureVersion) {
  bytes_[offsetof(StoreHeader, version) + 3] ^= 0xe6;
  const std::string damaged = copyWith(path_, "version.octoray", bytes_);
  try {
    StoreReader reader(damaged);
    FAIL() << "opened";
  } catch (const octoray::Error& e) {
    EXPECT_NE(e.reason().find("header: corrupted (version field reads"), std::string::npos) << e.what();
  }
}

TEST_F(DamagedStore, NarrowedRangeFailsRanges) {
  const StoreReader store(path_);
  const int64_t id = payloadNode(store, 2);
  ASSERT_GE(id, 0);
  std::vector<NodeRecord> table = readTable(bytes_);
  ASSERT_LT(table[id].minValue, table[id].maxValue);
  table[id].minValue = table[id].maxValue;
  writeTable(bytes_, table);
  resealChecksums(bytes_);
  const std::string damaged = copyWith(path_, "range.octoray", bytes_);
  const ValidationReport report = validateStore(damaged);
  expectOnlyFailing(report, {"ranges"});
  const CheckResult& ranges = *report.find("ranges");
  ASSERT_EQ(ranges.failures.size(), 1u);
  EXPECT_EQ(ranges.failures[0].nodeId, id);
  // Everything that renders reads bricks through readBrick, which refuses the lying node.
  const StoreReader reader(damaged);
  try {
    reader.readBrick(id);
    FAIL() << "a brick outside its node's range was accepted";
  } catch (const octoray::Error& e) {
    EXPECT_EQ(e.path(), damaged);
    EXPECT_NE(e.reason().find(fmt::format("node {} ", id)), std::string::npos) << e.what();
    EXPECT_NE(e.reason().find("outside the node's recorded range"), std::string::npos) << e.what();
  }
  EXPECT_NO_THROW(reader.readBrickUnchecked(id));
}

// Every node's range rewritten to air with the checksums resealed (a store whose table lies
// throughout): rendering it was a black picture with exit 0; now both renderers stop with an
// error naming the store and a node.
TEST_F(DamagedStore, LyingRangesFailTheRenderNamingANode) {
  std::vector<NodeRecord> table = readTable(bytes_);
  for (NodeRecord& n : table) n.minValue = n.maxValue = -1000.0f;
  writeTable(bytes_, table);
  resealChecksums(bytes_);
  const std::string damaged = copyWith(path_, "lying.octoray", bytes_);
  EXPECT_THROW(StoreReader(damaged).readBrick(0), octoray::Error);
  const fs::path render = test::toolPath("octoray-render");
  if (!fs::exists(render)) GTEST_SKIP() << "octoray-render not built";
  for (const char* renderer : {"--reference", "--gpu"}) {
    SCOPED_TRACE(renderer);
    const std::string out = (fs::path(damaged).parent_path() / "lying.png").string();
    const test::ProcessResult r = test::runProcess({render.string(), damaged, "-o", out, "--preset", "bone",
                                                    "--size", "32x32", renderer});
    EXPECT_EQ(r.exitCode, 1) << r.err;
    EXPECT_NE(r.err.find(damaged), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("outside the node's recorded range"), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(out));
  }
}

TEST_F(DamagedStore, ConstantNodeWithWideRangeFailsConstants) {
  const StoreReader store(path_);
  int64_t id = -1;
  for (int64_t n = 0; n < store.layout().nodeCount() && id < 0; ++n) {
    if (store.node(n).flags & kNodeConstant) id = n;
  }
  ASSERT_GE(id, 0) << "the test volume has constant bricks of air";
  std::vector<NodeRecord> table = readTable(bytes_);
  // Its range moved above its own value: the value no longer lies in the range.
  const float width = table[id].maxValue - table[id].minValue;
  table[id].minValue += width + 10;
  table[id].maxValue += width + 10;
  writeTable(bytes_, table);
  resealChecksums(bytes_);
  const ValidationReport report = validateStore(copyWith(path_, "constant.octoray", bytes_));
  ASSERT_FALSE(report.find("constants")->passed());
  EXPECT_EQ(report.find("constants")->failures.at(0).nodeId, id);
}

// Found by this validator: a node whose own samples are constant while its children vary keeps
// its own value (NodeRecord::constantSample), not the lower end of its subtree range.
TEST(StoreBuilder, ConstantParentOfVaryingChildrenKeepsItsValue) {
  // A checkerboard of 0 and 2 HU filters to a constant 1 HU parent.
  MemoryVolume volume({32, 32, 32},
                      [](int64_t i, int64_t j, int64_t k) { return ((i + j + k) % 2) * 2.0f; });
  const std::string path = buildTestStore(volume, "checker", 16, 1);
  const ValidationReport report = validateStore(path);
  expectOnlyFailing(report, {});
}

TEST(ValidateStoreInput, AnythingThatIsNotAStoreFailsHeaderWithoutThrowing) {
  const fs::path dir = test::freshTempDir("validate_garbage");
  std::vector<std::string> paths;
  writeBytes((dir / "empty").string(), {});
  paths.push_back((dir / "empty").string());
  std::mt19937 random(7);
  for (std::size_t size : {1u, 255u, 256u, 4096u}) {
    Bytes noise(size);
    for (char& c : noise) c = static_cast<char>(random());
    const std::string p = (dir / ("random" + std::to_string(size))).string();
    writeBytes(p, noise);
    paths.push_back(p);
  }
  Bytes magicOnly(300, 0);
  std::memcpy(magicOnly.data(), kStoreMagic, sizeof kStoreMagic);
  writeBytes((dir / "magic").string(), magicOnly);
  paths.push_back((dir / "magic").string());
  paths.push_back(dir.string());
  paths.push_back((dir / "absent").string());
  for (const std::string& p : paths) {
    ValidationReport report;
    EXPECT_NO_THROW(report = validateStore(p)) << p;
    EXPECT_FALSE(report.passed()) << p;
    ASSERT_NE(report.find("header"), nullptr);
    EXPECT_EQ(report.find("header")->status, CheckStatus::Failed) << p;
    EXPECT_FALSE(report.find("header")->failures.empty()) << p;
  }
}

// What decides between opening a store and importing a volume: the store's magic, or the name
// *.octoray, so that a store damaged at its start is reported as a damaged store (the renderer
// said "not a DICOM file" of it).
TEST(ValidateStoreInput, StoresAreKnownByMagicOrByName) {
  const fs::path dir = test::freshTempDir("store_or_not");
  Bytes magicOnly(300, 0);
  std::memcpy(magicOnly.data(), kStoreMagic, sizeof kStoreMagic);
  writeBytes((dir / "named-otherwise.bin").string(), magicOnly);
  writeBytes((dir / "empty.octoray").string(), {});
  writeBytes((dir / "garbage.OCTORAY").string(), Bytes(26, 'X'));
  writeBytes((dir / "volume.nrrd").string(), Bytes(26, 'X'));
  EXPECT_TRUE(isStoreFile(dir / "named-otherwise.bin"));
  EXPECT_TRUE(isStoreFile(dir / "empty.octoray"));
  EXPECT_TRUE(isStoreFile(dir / "garbage.OCTORAY"));
  EXPECT_FALSE(isStoreFile(dir / "volume.nrrd"));
  EXPECT_FALSE(isStoreFile(dir));
  EXPECT_FALSE(isStoreFile(dir / "absent.octoray"));
  try {
    StoreReader reader((dir / "garbage.OCTORAY").string());
    ADD_FAILURE() << "garbage opened as a store";
  } catch (const Error& e) {
    EXPECT_EQ(e.reason(), "header: file too short (26 bytes) to be an octoray store");
  }
}

// --- octoray-validate, run as a user would ---------------------------------------------------

struct ToolRun {
  int exitCode = -1;
  std::string out;
};

ToolRun runValidate(const std::vector<std::string>& args) {
  std::string command = "'" + test::toolPath("octoray-validate").string() + "'";
  for (const std::string& a : args) command += " '" + a + "'";
  command += " 2>&1";
  ToolRun run;
  FILE* pipe = ::popen(command.c_str(), "r");
  if (!pipe) return run;
  char buffer[4096];
  std::size_t n;
  while ((n = std::fread(buffer, 1, sizeof buffer, pipe)) > 0) run.out.append(buffer, n);
  const int status = ::pclose(pipe);
  run.exitCode = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return run;
}

class ValidateTool : public DamagedStore {
 protected:
  void SetUp() override {
    DamagedStore::SetUp();
    if (!fs::exists(test::toolPath("octoray-validate")))
      GTEST_SKIP() << "octoray-validate is not built";
  }
};

TEST_F(ValidateTool, GoodStoreExitsZero) {
  const ToolRun run = runValidate({path_});
  EXPECT_EQ(run.exitCode, 0) << run.out;
  EXPECT_NE(run.out.find("all checks passed"), std::string::npos) << run.out;
  const ToolRun json = runValidate({path_, "--json"});
  EXPECT_EQ(json.exitCode, 0) << json.out;
  const auto j = nlohmann::json::parse(json.out, nullptr, false);
  ASSERT_FALSE(j.is_discarded()) << json.out;
  EXPECT_EQ(j["kind"], "store");
  EXPECT_EQ(j["passed"], true);
  EXPECT_EQ(j["checks"].size(), std::size(kAllChecks));
}

TEST_F(ValidateTool, CorruptedStoreExitsOneNamingTheCheck) {
  const StoreReader store(path_);
  const NodeRecord& r = store.node(payloadNode(store, 1));
  bytes_[r.payloadOffset + 3] ^= 0x01;
  const std::string damaged = copyWith(path_, "tool_flipped.octoray", bytes_);
  const ToolRun run = runValidate({damaged});
  EXPECT_EQ(run.exitCode, 1) << run.out;
  EXPECT_NE(run.out.find("FAIL    checksums"), std::string::npos) << run.out;
  const ToolRun json = runValidate({damaged, "--json"});
  EXPECT_EQ(json.exitCode, 1);
  const auto j = nlohmann::json::parse(json.out, nullptr, false);
  ASSERT_FALSE(j.is_discarded()) << json.out;
  for (const auto& check : j["checks"]) {
    EXPECT_EQ(check["status"], check["name"] == "checksums" ? "fail" : "pass") << check.dump();
  }
}

TEST_F(ValidateTool, GarbageExitsOneAndUsageErrorsExitTwo) {
  const fs::path dir = test::freshTempDir("validate_tool_garbage");
  writeBytes((dir / "empty").string(), {});
  const ToolRun empty = runValidate({(dir / "empty").string()});
  EXPECT_EQ(empty.exitCode, 1) << empty.out;
  EXPECT_NE(empty.out.find("FAIL    header"), std::string::npos) << empty.out;
  EXPECT_EQ(runValidate({}).exitCode, 2);
  EXPECT_EQ(runValidate({(dir / "absent").string()}).exitCode, 2);
  EXPECT_EQ(runValidate({path_, "--no-such-option"}).exitCode, 2);
  // An empty folder is DICOM input without any series.
  const ToolRun folder = runValidate({dir.string()});
  EXPECT_EQ(folder.exitCode, 1) << folder.out;
}

TEST(ValidateDicom, PhilipsFolderReportsMissingFilesAndNonVolumeSeries) {
  OCTORAY_REQUIRE_PATH(test::philipsDir());
  const ValidationReport report = validateDicomFolder(test::philipsDir().string());
  ASSERT_EQ(report.kind, "dicom");
  const CheckResult* files = report.find("dicom-files");
  ASSERT_NE(files, nullptr);
  EXPECT_EQ(files->status, CheckStatus::Failed);
  bool namesMissing = false;
  for (const auto& f : files->failures)
    namesMissing = namesMissing || f.message.find("does not exist") != std::string::npos;
  EXPECT_TRUE(namesMissing) << "the DICOMDIR lists files of series S2030 that are absent";
  const CheckResult* series = report.find("dicom-series");
  ASSERT_NE(series, nullptr);
  std::string notes;
  for (const auto& n : series->notes) notes += n + "\n";
  EXPECT_NE(notes.find("localizer"), std::string::npos) << notes;
  EXPECT_TRUE(notes.find("secondary-capture") != std::string::npos ||
              notes.find("derived") != std::string::npos)
      << notes;
  EXPECT_FALSE(report.series.empty());
  for (const auto& s : report.series) {
    EXPECT_TRUE(s.error.empty()) << s.seriesUid << ": " << s.error;
    EXPECT_GT(s.slices, 1);
    EXPECT_GT(s.medianGapMm, 0);
  }

  if (!fs::exists(test::toolPath("octoray-validate"))) return;
  const ToolRun run = runValidate({test::philipsDir().string()});
  EXPECT_EQ(run.exitCode, 1) << run.out;
  EXPECT_NE(run.out.find("FAIL    dicom-files"), std::string::npos) << run.out;
  EXPECT_NE(run.out.find("does not exist"), std::string::npos) << run.out;
  EXPECT_NE(run.out.find("localizer"), std::string::npos) << run.out;
}

}  // namespace
}  // namespace octoray::volume
