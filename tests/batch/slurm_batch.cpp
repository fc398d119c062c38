// octoray-batch on a real Slurm: a one-node cluster (munged, slurmctld, slurmd) started by the
// test with its own config, state and ports under the build tree (slurm_cluster.sh), the test
// archive submitted as a job array with `octoray-batch slurm`, and the stores and the merged
// per-task manifests checked as on one machine. Skips where Slurm is not installed or the test
// does not run as root (slurmd needs root).

#include <gtest/gtest.h>

#include <chrono>
#include <cstdlib>
#include <sstream>
#include <thread>

#include <fmt/format.h>

#include "batch_archive.h"
#include "run_process.h"
#include "test_paths.h"

namespace octoray::test {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

class SlurmCluster {
 public:
  // Returns false (and the reason) when Slurm cannot be started here: the test skips.
  bool start(const fs::path& dir, std::string& why) {
    dir_ = dir;
    const ProcessResult r = runProcess({"/bin/bash", OCTORAY_SLURM_CLUSTER_SCRIPT, "start", dir.string()});
    if (r.exitCode == 77) {
      why = r.err;
      return false;
    }
    started_ = true;
    EXPECT_EQ(r.exitCode, 0) << r.err;
    const std::string prefix = "export SLURM_CONF=";
    const auto at = r.out.find(prefix);
    if (r.exitCode != 0 || at == std::string::npos) {
      why = "the cluster did not start: " + r.err;
      ADD_FAILURE() << why;
      return false;
    }
    std::string conf = r.out.substr(at + prefix.size());
    conf = conf.substr(0, conf.find('\n'));
    ::setenv("SLURM_CONF", conf.c_str(), 1);
    return true;
  }
  ~SlurmCluster() {
    if (started_) {
      const ProcessResult r = runProcess({"/bin/bash", OCTORAY_SLURM_CLUSTER_SCRIPT, "stop", dir_.string()});
      EXPECT_EQ(r.exitCode, 0) << r.err;
    }
  }

 private:
  fs::path dir_;
  bool started_ = false;
};

// True once `squeue` no longer lists the job.
bool jobFinished(const std::string& jobId) {
  const ProcessResult r = runProcess({"/usr/bin/squeue", "-h", "-j", jobId});
  return r.exitCode != 0 || r.out.find_first_not_of(" \n") == std::string::npos;
}

// The reason squeue gives for a task Slurm will never run again by itself (it failed to launch
// and was requeued held, or the node was drained), or "" while every task is pending or running.
std::string jobStuck(const std::string& jobId) {
  const ProcessResult r = runProcess({"/usr/bin/squeue", "-h", "-j", jobId, "-o", "%i %T %r"});
  std::istringstream lines(r.out);
  for (std::string line; std::getline(lines, line);) {
    if (line.find("held") != std::string::npos || line.find("HOLD") != std::string::npos ||
        line.find("Drain") != std::string::npos || line.find("Down") != std::string::npos) {
      return line;
    }
  }
  return "";
}

std::string tailOf(const fs::path& path, std::size_t bytes = 3000) {
  if (!fs::exists(path)) return "(no " + path.string() + ")";
  const std::string text = readText(path);
  return text.size() > bytes ? text.substr(text.size() - bytes) : text;
}

TEST(BatchSlurm, JobArrayBuildsTheArchive) {
  OCTORAY_REQUIRE_PATH(philipsDir());
  const fs::path dir = freshTempDir("slurm");
  SlurmCluster cluster;
  std::string why;
  if (!cluster.start(dir / "cluster", why)) {
    if (!HasFailure()) GTEST_SKIP() << "skipped: " << why;
    return;
  }
  const BatchArchive archive = makeBatchArchive(dir / "archive");
  const fs::path planPath = dir / "shared/plan.json";
  ASSERT_EQ(runTool("octoray-batch", {"plan", archive.root.string(), "-o", planPath.string()}).exitCode, 0);

  // One item per task at most (tiny series), two tasks at a time on the two-CPU node.
  const ToolRun submitted = runTool("octoray-batch", {"slurm", planPath.string(), "--min-task-seconds", "2",
                                                      "--cpus-per-task", "1", "--time", "00:10:00", "--json"});
  ASSERT_EQ(submitted.exitCode, 0) << submitted.out << submitted.err;
  const json job = submitted.json();
  const std::string jobId = job["jobId"];
  const int tasks = job["arrayTasks"];
  EXPECT_GE(tasks, 3) << "the archive is split over several array tasks";
  EXPECT_EQ(job["items"], BatchArchive::kItems);

  const auto deadline = std::chrono::steady_clock::now() + std::chrono::minutes(8);
  std::string stuck;
  while (!jobFinished(jobId) && std::chrono::steady_clock::now() < deadline) {
    if (!(stuck = jobStuck(jobId)).empty()) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(500));
  }
  ASSERT_EQ(stuck, "") << "a task of job " << jobId << " will not run; slurmd's log:\n"
                       << tailOf(dir / "cluster/log/slurmd.log");
  ASSERT_TRUE(jobFinished(jobId)) << "job " << jobId << " did not finish in 8 minutes; slurmd's log:\n"
                                  << tailOf(dir / "cluster/log/slurmd.log");

  // Each task wrote its own manifest file; status merges them.
  int taskManifests = 0;
  for (const auto& e : fs::directory_iterator(dir / "shared/plan.manifest")) {
    if (e.path().filename().string().starts_with("slurm-" + jobId + "_")) ++taskManifests;
  }
  EXPECT_EQ(taskManifests, tasks);
  const ToolRun status = runTool("octoray-batch", {"status", planPath.string(), "--json"});
  std::string logs;
  for (const auto& e : fs::directory_iterator(dir / "shared/plan.slurm/logs")) logs += readText(e.path());
  EXPECT_EQ(status.json()["done"], BatchArchive::kItems) << status.out << "\ntask logs:\n" << logs;
  EXPECT_EQ(status.json()["failed"], 0);
  EXPECT_EQ(status.json()["tornLines"], 0);
  const ToolRun validated = runTool("octoray-batch", {"validate", planPath.string(), "--json"});
  EXPECT_EQ(validated.exitCode, 0) << validated.out;
  EXPECT_EQ(validated.json()["passed"], BatchArchive::kItems);

  // The stores the tasks built are the ones octoray-import builds.
  const json plan = json::parse(readText(planPath));
  for (const auto& it : plan["items"]) {
    const fs::path reference = dir / fmt::format("reference-{}.octoray", it["index"].get<int>());
    const ToolRun imported =
        it["kind"] == "dicom"
            ? runTool("octoray-import", {archive.root.string(), "--series", it["seriesUid"], "-o", reference.string()})
            : runTool("octoray-import", {it["path"], "-o", reference.string()});
    ASSERT_EQ(imported.exitCode, 0) << imported.err;
    EXPECT_EQ(readText(it["output"].get<std::string>()), readText(reference)) << it["output"];
  }

  // Nothing left to submit, and no patient name in the script the cluster ran.
  const ToolRun again = runTool("octoray-batch", {"slurm", planPath.string()});
  EXPECT_EQ(again.exitCode, 0);
  EXPECT_NE(again.out.find("nothing to submit"), std::string::npos) << again.out;
  std::string scripts;
  for (const auto& e : fs::directory_iterator(dir / "shared/plan.slurm")) {
    if (e.is_regular_file()) scripts += readText(e.path());
  }
  EXPECT_NE(scripts.find("--array=0-"), std::string::npos);
  for (const auto& e : fs::directory_iterator(dir / "shared/plan.manifest")) scripts += readText(e.path());
  scripts += logs;
  for (const std::string& id : archive.identifiers) {
    EXPECT_EQ(scripts.find(id), std::string::npos) << "'" << id << "' in the script, a manifest or a log";
  }
}

}  // namespace
}  // namespace octoray::test
