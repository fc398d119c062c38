// octoray-batch on a real archive (batch_archive.h): the plan's items and skips, stores equal to
// octoray-import's, a second run that does nothing, a changed file reported and rebuilt, runs
// killed at random moments resumed to complete stores, and no patient name anywhere.

#include <gtest/gtest.h>

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <map>
#include <random>
#include <set>
#include <thread>

#include <fmt/format.h>

#include "batch_archive.h"
#include "octoray/batch/plan.h"
#include "octoray/volume/store_validator.h"
#include "test_paths.h"

extern char** environ;

namespace octoray::test {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

bool sameBytes(const fs::path& a, const fs::path& b) {
  return fs::file_size(a) == fs::file_size(b) && readText(a) == readText(b);
}

std::map<std::string, fs::file_time_type> storeTimes(const json& plan) {
  std::map<std::string, fs::file_time_type> times;
  for (const auto& it : plan["items"]) {
    const std::string out = it["output"].get<std::string>();
    times[out] = fs::last_write_time(out);
  }
  return times;
}

// Hidden temporaries (".NAME.partial-PID") anywhere under `dir`.
int partialFiles(const fs::path& dir) {
  int n = 0;
  std::error_code ec;
  for (const auto& e : fs::recursive_directory_iterator(dir, ec)) {
    if (e.path().filename().string().find(".partial-") != std::string::npos) ++n;
  }
  return n;
}

class BatchArchiveTest : public ::testing::Test {
 protected:
  void SetUp() override {
    OCTORAY_REQUIRE_PATH(philipsDir());
    dir_ = freshTempDir("batch");
    archive_ = makeBatchArchive(dir_ / "archive");
    planPath_ = dir_ / "work/plan.json";
  }
  json plan() const { return json::parse(readText(planPath_)); }

  fs::path dir_, planPath_;
  BatchArchive archive_;
};

TEST_F(BatchArchiveTest, PlansRunsAndRerunsTheArchive) {
  const ToolRun planned = runTool("octoray-batch", {"plan", archive_.root.string(), "-o", planPath_.string()});
  ASSERT_EQ(planned.exitCode, 0) << planned.err;
  const json p = plan();
  ASSERT_EQ(p["items"].size(), static_cast<std::size_t>(BatchArchive::kItems)) << p.dump(1);
  EXPECT_EQ(p["outDir"], (dir_ / "work/stores").string());

  // Every volumetric series is an item; localisers, secondary captures and broken files are
  // listed with the reason, not imported.
  std::map<std::string, int> slicesByDescription;
  for (const auto& it : p["items"]) {
    slicesByDescription[it["description"].get<std::string>() + "/" + std::to_string(it["dims"][2].get<int>())]++;
  }
  EXPECT_EQ(slicesByDescription["STD BRAIN 1MM, iDose/140"], 1) << p["items"].dump(1);
  int localizers = 0, secondary = 0;
  bool badNrrd = false;
  for (const auto& s : p["skipped"]) {
    const std::string reason = s["reason"];
    localizers += reason.starts_with("localizer") ? 1 : 0;
    secondary += reason.starts_with("secondary-capture") ? 1 : 0;
    if (s["path"].get<std::string>().ends_with("broken/bad.nrrd")) {
      badNrrd = true;
      EXPECT_NE(reason.find("NRRD header lacks"), std::string::npos) << reason;
    }
  }
  EXPECT_EQ(localizers, 3);  // two Philips scouts, the synthetic one
  EXPECT_EQ(secondary, 6);
  EXPECT_TRUE(badNrrd);
  std::set<std::string> unreadable;
  for (const auto& u : p["unreadableFiles"]) unreadable.insert(fs::path(u["path"].get<std::string>()).filename().string());
  EXPECT_TRUE(unreadable.contains("junk.dcm") && unreadable.contains("cut.dcm"));
  EXPECT_NE(p["warnings"].dump().find("S2030"), std::string::npos) << "the DICOMDIR's missing series";

  // The patient-ID hash names the folder, one per patient.
  const std::string patientA = batch::patientIdHash("PAT-A-001", "");
  int ofPatientA = 0;
  for (const auto& it : p["items"]) {
    const std::string out = it["output"];
    if (out.find("/" + patientA + "/") != std::string::npos) ++ofPatientA;
  }
  EXPECT_EQ(ofPatientA, 2);

  const ToolRun run = runTool("octoray-batch", {"run", planPath_.string(), "--jobs", "2", "--json"});
  ASSERT_EQ(run.exitCode, 0) << run.out << run.err;
  const json summary = run.json();
  EXPECT_EQ(summary["built"], BatchArchive::kItems);
  EXPECT_EQ(summary["failed"], 0);

  // Each store passes the validator and equals the one octoray-import builds.
  for (const auto& it : p["items"]) {
    const std::string out = it["output"];
    const volume::ValidationReport report = volume::validateStore(out);
    EXPECT_TRUE(report.passed()) << out;
    const fs::path reference = dir_ / fmt::format("reference-{}.octoray", it["index"].get<int>());
    const ToolRun imported =
        it["kind"] == "dicom"
            ? runTool("octoray-import", {archive_.root.string(), "--series", it["seriesUid"], "-o", reference.string()})
            : runTool("octoray-import", {it["path"], "-o", reference.string()});
    ASSERT_EQ(imported.exitCode, 0) << imported.err;
    EXPECT_TRUE(sameBytes(out, reference)) << out << " differs from octoray-import's " << reference;
  }

  // A second run does nothing: no store is written again.
  const auto before = storeTimes(p);
  const auto start = std::chrono::steady_clock::now();
  const ToolRun again = runTool("octoray-batch", {"run", planPath_.string(), "--json"});
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  ASSERT_EQ(again.exitCode, 0) << again.err;
  EXPECT_EQ(again.json()["built"], 0);
  EXPECT_EQ(again.json()["upToDate"], BatchArchive::kItems);
  EXPECT_EQ(storeTimes(p), before);
  EXPECT_LT(seconds, 10.0);

  const ToolRun status = runTool("octoray-batch", {"status", planPath_.string(), "--json"});
  ASSERT_EQ(status.exitCode, 0);
  EXPECT_EQ(status.json()["done"], BatchArchive::kItems);
  EXPECT_EQ(status.json()["pending"], 0);
  const ToolRun validated = runTool("octoray-batch", {"validate", planPath_.string(), "--json"});
  EXPECT_EQ(validated.exitCode, 0) << validated.out;
  EXPECT_EQ(validated.json()["passed"], BatchArchive::kItems);

  // No patient name or ID in the plan, the manifest, the Slurm script or the output paths.
  const ToolRun script = runTool("octoray-batch", {"slurm", planPath_.string(), "--dry-run"});
  std::string everything = readText(planPath_) + script.out + status.out + run.out + run.err +
                           planned.out + planned.err + again.out + validated.out;
  for (const auto& e : fs::directory_iterator(planPath_.parent_path() / "plan.manifest")) everything += readText(e.path());
  for (const auto& e : fs::recursive_directory_iterator(dir_ / "work/stores")) everything += e.path().string() + "\n";
  for (const std::string& id : archive_.identifiers) {
    EXPECT_EQ(everything.find(id), std::string::npos) << "'" << id << "' leaked";
  }
}

TEST_F(BatchArchiveTest, FiltersSelectSeriesAndListTheRestWithTheReason) {
  auto plannedDescriptions = [&](std::vector<std::string> filter) {
    std::vector<std::string> args = {"plan", archive_.root.string(), "-o", planPath_.string()};
    args.insert(args.end(), filter.begin(), filter.end());
    const ToolRun r = runTool("octoray-batch", args);
    EXPECT_EQ(r.exitCode, 0) << r.err;
    std::multiset<std::string> items;
    int filtered = 0;
    const json p = plan();
    for (const auto& it : p["items"]) items.insert(it["description"].get<std::string>());
    for (const auto& s : p["skipped"]) filtered += s["reason"].get<std::string>().starts_with("filtered out") ? 1 : 0;
    EXPECT_EQ(static_cast<int>(items.size()) + filtered, BatchArchive::kItems);
    return items;
  };
  // The Philips series are from 2015-02-06, the synthetic ones from 2024-01-01; the NIfTI file
  // has no study date and no modality.
  EXPECT_EQ(plannedDescriptions({"--study-date", "20150101-20151231"}).size(), 4u);
  EXPECT_EQ(plannedDescriptions({"--study-date", "20240101-"}).size(), 3u);
  const auto brain = plannedDescriptions({"--description", "brain"});
  EXPECT_EQ(brain, (std::multiset<std::string>{"STD BRAIN 1MM, iDose", "STD BRAIN 5MM"}));
  for (const auto& d : plannedDescriptions({"--min-slices", "50"})) EXPECT_NE(d, "STD BRAIN 5MM");
  EXPECT_EQ(plannedDescriptions({"--modality", "CT"}).size(), static_cast<std::size_t>(BatchArchive::kItems));
  const ToolRun none = runTool("octoray-batch", {"plan", archive_.root.string(), "-o", planPath_.string(),
                                                 "--modality", "MR", "--description", "nothing-matches-this"});
  EXPECT_EQ(none.exitCode, 1);
  EXPECT_NE(none.err.find("nothing to build"), std::string::npos) << none.err;
  const ToolRun badDate = runTool("octoray-batch", {"plan", archive_.root.string(), "-o", planPath_.string(),
                                                    "--study-date", "2015-2016"});
  EXPECT_EQ(badDate.exitCode, 1);
  EXPECT_NE(badDate.err.find("YYYYMMDD"), std::string::npos) << badDate.err;
}

TEST_F(BatchArchiveTest, AChangedFileFailsItsItemUntilPlannedAgain) {
  ASSERT_EQ(runTool("octoray-batch", {"plan", archive_.root.string(), "-o", planPath_.string()}).exitCode, 0);
  // A slice changes after planning (one pixel value).
  const fs::path slice = archive_.root / "patient-a/ct2/CT0010.dcm";
  ASSERT_TRUE(fs::exists(slice));
  {
    std::fstream f(slice, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(-2, std::ios::end);
    f.put('\x7f');
  }
  const ToolRun run = runTool("octoray-batch", {"run", planPath_.string(), "--json"});
  EXPECT_EQ(run.exitCode, 1) << "a failed item fails the run";
  const json summary = run.json();
  EXPECT_EQ(summary["built"], BatchArchive::kItems - 1);
  ASSERT_EQ(summary["failures"].size(), 1u);
  const std::string error = summary["failures"][0]["error"];
  EXPECT_NE(error.find(slice.string() + ": changed since the plan"), std::string::npos) << error;
  EXPECT_NE(run.err.find("failed: item"), std::string::npos) << "failures are listed on stderr";

  const json status = runTool("octoray-batch", {"status", planPath_.string(), "--json"}).json();
  EXPECT_EQ(status["failed"], 1);
  EXPECT_EQ(status["done"], BatchArchive::kItems - 1);
  const ToolRun retried = runTool("octoray-batch", {"run", planPath_.string(), "--only-failed", "--json"});
  EXPECT_EQ(retried.json()["selected"], 1);
  EXPECT_EQ(retried.json()["failed"], 1);

  // Planned again: only that series is built; the others' stores match their content hash.
  ASSERT_EQ(runTool("octoray-batch", {"plan", archive_.root.string(), "-o", planPath_.string()}).exitCode, 0);
  const ToolRun rebuilt = runTool("octoray-batch", {"run", planPath_.string(), "--json"});
  ASSERT_EQ(rebuilt.exitCode, 0) << rebuilt.out;
  EXPECT_EQ(rebuilt.json()["built"], 1);
  EXPECT_EQ(rebuilt.json()["upToDate"], BatchArchive::kItems - 1);
  EXPECT_EQ(runTool("octoray-batch", {"status", planPath_.string(), "--json"}).json()["done"],
            BatchArchive::kItems);
}

TEST_F(BatchArchiveTest, RunsKilledAtRandomMomentsResumeToCompleteStores) {
  ASSERT_EQ(runTool("octoray-batch", {"plan", archive_.root.string(), "-o", planPath_.string()}).exitCode, 0);
  const json p = plan();
  const std::string tool = toolPath("octoray-batch").string();
  const unsigned seed = static_cast<unsigned>(std::random_device{}());
  std::mt19937 random(seed);
  std::uniform_int_distribution<int> delayMs(50, 1500);
  SCOPED_TRACE("kill delays from seed " + std::to_string(seed));
  int killedWhileRunning = 0;
  for (int round = 0; round < 5; ++round) {
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_addopen(&actions, 1, "/dev/null", O_WRONLY, 0);
    posix_spawn_file_actions_addopen(&actions, 2, "/dev/null", O_WRONLY, 0);
    std::vector<std::string> args = {tool, "run", planPath_.string(), "--jobs", "2"};
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    pid_t pid = 0;
    ASSERT_EQ(posix_spawn(&pid, tool.c_str(), &actions, nullptr, argv.data(), environ), 0);
    posix_spawn_file_actions_destroy(&actions);
    std::this_thread::sleep_for(std::chrono::milliseconds(delayMs(random)));
    int status = 0;
    if (::waitpid(pid, &status, WNOHANG) == 0) {
      ++killedWhileRunning;
      ::kill(pid, SIGKILL);
      ::waitpid(pid, &status, 0);
    }
    // The workers notice their parent's death and remove their temporaries.
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(20);
    while (partialFiles(dir_ / "work") > 0 && std::chrono::steady_clock::now() < deadline) {
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    EXPECT_EQ(partialFiles(dir_ / "work"), 0) << "round " << round;
    // Whatever exists at an output path is a complete store.
    for (const auto& it : p["items"]) {
      if (fs::exists(it["output"].get<std::string>())) {
        EXPECT_TRUE(volume::validateStore(it["output"]).passed()) << it["output"];
      }
    }
  }
  EXPECT_GE(killedWhileRunning, 1) << "no round killed a run that was still building";
  const ToolRun finish = runTool("octoray-batch", {"run", planPath_.string(), "--json"});
  ASSERT_EQ(finish.exitCode, 0) << finish.out << finish.err;
  const json status = runTool("octoray-batch", {"status", planPath_.string(), "--json"}).json();
  EXPECT_EQ(status["done"], BatchArchive::kItems);
  EXPECT_EQ(status["pending"], 0);
  EXPECT_EQ(status["failed"], 0);
  EXPECT_EQ(runTool("octoray-batch", {"validate", planPath_.string()}).exitCode, 0);
  // The manifest agrees with the files: each item's record names a store of that size.
  for (const auto& it : p["items"]) {
    const std::string out = it["output"];
    ASSERT_TRUE(fs::exists(out));
    bool recorded = false;
    for (const auto& e : fs::directory_iterator(planPath_.parent_path() / "plan.manifest")) {
      std::ifstream in(e.path());
      for (std::string line; std::getline(in, line);) {
        const json r = json::parse(line, nullptr, false);
        if (r.is_discarded() || r["item"] != it["index"] || r["status"] != "done") continue;
        recorded = true;
        EXPECT_EQ(r["bytes"].get<uint64_t>(), fs::file_size(out)) << out;
      }
    }
    EXPECT_TRUE(recorded) << out;
  }
}

}  // namespace
}  // namespace octoray::test
