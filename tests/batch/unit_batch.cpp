// octoray-batch's pieces without an archive: output names, the patient-ID hash, the manifest's
// merge rules (latest wins, cut-off lines and other plans' records ignored), the Slurm grouping
// and script, and the worker budget.

#include <gtest/gtest.h>

#include <fstream>

#include "octoray/batch/manifest.h"
#include "octoray/batch/plan.h"
#include "octoray/batch/runner.h"
#include "octoray/batch/slurm.h"
#include "octoray/core/error.h"
#include "test_paths.h"

namespace octoray::batch {
namespace {

namespace fs = std::filesystem;

TEST(BatchNames, SanitizeKeepsSafeCharactersOnly) {
  EXPECT_EQ(sanitizeComponent("STD BRAIN 1MM, iDose"), "STD_BRAIN_1MM_iDose");
  EXPECT_EQ(sanitizeComponent("../../etc/passwd"), "etc_passwd");
  EXPECT_EQ(sanitizeComponent("a/b\\c"), "a_b_c");
  EXPECT_EQ(sanitizeComponent("..."), "none");
  EXPECT_EQ(sanitizeComponent(""), "none");
  EXPECT_EQ(sanitizeComponent("Lunge\xC3\xA4 rechts"), "Lunge_rechts");
  EXPECT_EQ(sanitizeComponent(std::string(200, 'x')).size(), 64u);
}

TEST(BatchNames, TemplateExpandsFieldsAndStaysInsideTheOutputFolder) {
  auto field = [](const std::string& name) -> std::optional<std::string> {
    if (name == "PatientID-hash") return "0123abcd";
    if (name == "SeriesNumber") return "202";
    if (name == "SeriesDescription") return "STD BRAIN/1MM";
    if (name == "StudyInstanceUID") return "1.2.3";
    return std::nullopt;
  };
  EXPECT_EQ(expandTemplate(kDefaultOutputTemplate, field), "0123abcd/1.2.3/202-STD_BRAIN_1MM.octoray");
  EXPECT_EQ(expandTemplate("flat/{SeriesNumber}", field), "flat/202.octoray");
  EXPECT_THROW(expandTemplate("{Unknown}.octoray", field), Error);
  EXPECT_THROW(expandTemplate("/abs/{SeriesNumber}", field), Error);
  EXPECT_THROW(expandTemplate("../{SeriesNumber}", field), Error);
  EXPECT_THROW(expandTemplate("{SeriesNumber", field), Error);
  // A value never makes a folder or climbs out: it is one sanitised component.
  auto evil = [](const std::string&) -> std::optional<std::string> { return "../.."; };
  EXPECT_EQ(expandTemplate("{SeriesDescription}", evil), "none.octoray");
}

TEST(BatchNames, PatientIdHashIsKeyedAndStable) {
  const std::string a = patientIdHash("PLASTIC", "");
  EXPECT_EQ(a.size(), 16u);
  EXPECT_EQ(a, patientIdHash("PLASTIC", ""));
  EXPECT_NE(a, patientIdHash("PLASTIC", "site-secret"));
  EXPECT_NE(a, patientIdHash("PLASTIC2", ""));
  // HMAC-SHA256 (RFC 4231 test case 2: key "Jefe"), first 8 bytes.
  EXPECT_EQ(patientIdHash("what do ya want for nothing?", "Jefe"), "5bdcc146bf60754e");
}

Plan twoItemPlan() {
  Plan plan;
  for (int i = 0; i < 2; ++i) {
    WorkItem it;
    it.index = i;
    it.kind = "dicom";
    it.files = {"a.dcm"};
    it.fileHashes = {std::string(32, '0')};
    it.contentHash = i == 0 ? "hash0" : "hash1";
    it.output = "/out/" + std::to_string(i) + ".octoray";
    it.dims = {512, 512, 100 + i};
    plan.items.push_back(it);
  }
  return plan;
}

TEST(BatchManifest, LatestRecordWinsAndCutOffOrForeignLinesAreIgnored) {
  const fs::path dir = test::freshTempDir("manifest");
  const fs::path planPath = dir / "plan.json";
  const Plan plan = twoItemPlan();
  EXPECT_EQ(manifestFolder(planPath), dir / "plan.manifest");
  {
    ManifestWriter first(manifestFolder(planPath), "local-a");
    Record failed;
    failed.item = 0;
    failed.status = "failed";
    failed.contentHash = "hash0";
    failed.output = "/out/0.octoray";
    failed.error = "x.dcm: truncated";
    first.append(failed);
  }
  {
    ManifestWriter second(manifestFolder(planPath), "slurm-7_1");
    Record done;
    done.item = 0;
    done.status = "done";
    done.contentHash = "hash0";
    done.output = "/out/0.octoray";
    second.append(done);
    Record stale = done;
    stale.item = 1;
    stale.contentHash = "from-an-earlier-plan";
    second.append(stale);
    Record outside = done;
    outside.item = 9;
    second.append(outside);
    Record elsewhere = done;  // the plan now writes item 0 somewhere else
    elsewhere.output = "/old/0.octoray";
    second.append(elsewhere);
  }
  // A writer killed in the middle of a line.
  std::ofstream(manifestFolder(planPath) / "local-b.jsonl", std::ios::app)
      << R"({"item":1,"status":"done","contentHash":"hash1","out)";
  const ManifestState state = readManifest(planPath, plan);
  EXPECT_EQ(state.files, 3);
  EXPECT_EQ(state.records, 6);
  EXPECT_EQ(state.tornLines, 1);
  EXPECT_EQ(state.staleRecords, 3);
  ASSERT_EQ(state.latest.size(), 1u);
  EXPECT_EQ(state.latest.at(0).status, "done");
  EXPECT_EQ(state.latest.at(0).worker, "slurm-7_1");
  EXPECT_FALSE(state.latest.at(0).finished.empty());
  // A writer opening a file whose last line was cut starts its record on a new line.
  {
    ManifestWriter again(manifestFolder(planPath), "local-b");
    Record r;
    r.item = 1;
    r.status = "done";
    r.contentHash = "hash1";
    r.output = "/out/1.octoray";
    again.append(r);
  }
  const ManifestState after = readManifest(planPath, plan);
  EXPECT_EQ(after.tornLines, 1);
  EXPECT_EQ(after.latest.size(), 2u);
}

TEST(BatchManifest, ANewPlanFolderHasNoRecords) {
  const fs::path dir = test::freshTempDir("empty");
  const ManifestState state = readManifest(dir / "plan.json", twoItemPlan());
  EXPECT_EQ(state.files, 0);
  EXPECT_TRUE(state.latest.empty());
}

TEST(BatchSlurm, GroupsHoldAMinuteOfWorkAndRespectTheArrayLimit) {
  Plan plan;
  for (int i = 0; i < 100; ++i) {
    WorkItem it;
    it.index = i;
    it.dims = {512, 512, 200};  // 52 Mvoxels: 1 + 1.3 s at 40 Mvoxels/s
    plan.items.push_back(it);
  }
  std::vector<int64_t> all;
  for (int i = 0; i < 100; ++i) all.push_back(i);
  SlurmOptions options;
  const auto groups = groupItems(plan, all, options);
  // 2.31 s per item: 26 items reach 60 s.
  ASSERT_EQ(groups.size(), 4u);
  EXPECT_EQ(groups[0].size(), 26u);
  std::size_t total = 0;
  for (const auto& g : groups) total += g.size();
  EXPECT_EQ(total, 100u);
  options.minTaskSeconds = 0;
  options.maxArrayTasks = 10;
  EXPECT_LE(groupItems(plan, all, options).size(), 10u);
  options.maxArrayTasks = 1000;
  EXPECT_EQ(groupItems(plan, all, options).size(), 100u);
}

TEST(BatchSlurm, ScriptRunsEachGroupAndQuotesPaths) {
  SlurmOptions options;
  options.executable = "/opt/octoray/bin/octoray-batch";
  options.partition = "short";
  options.arrayParallel = 5;
  const std::string script =
      sbatchScript("/data/it's/plan.json", {{0, 1, 2}, {3}}, options, "/data/plan.slurm/logs");
  EXPECT_NE(script.find("#SBATCH --array=0-1%5\n"), std::string::npos) << script;
  EXPECT_NE(script.find("#SBATCH --partition=short\n"), std::string::npos);
  EXPECT_NE(script.find("#SBATCH --mem=1664M\n"), std::string::npos) << script;
  EXPECT_NE(script.find("  0,1,2\n  3\n"), std::string::npos);
  EXPECT_NE(script.find("'/data/it'\\''s/plan.json' --items \"${groups[$SLURM_ARRAY_TASK_ID]}\""),
            std::string::npos)
      << script;
  EXPECT_NE(script.find("#SBATCH --output=/data/plan.slurm/logs/%A_%a.log"), std::string::npos);
  options.partition = "short\n#SBATCH --uid=0";
  EXPECT_THROW(sbatchScript("/p.json", {{0}}, options, "/l"), Error);
  options.partition = "short";
  EXPECT_THROW(sbatchScript("/my plans/p.json", {{0}}, options, "/l"), Error);
  EXPECT_THROW(sbatchScript("/p.json", {{0}}, options, "/logs%j"), Error);
}

TEST(BatchResources, WorkersFitInMemory) {
  const Resources automatic = decideResources(0, uint64_t{1} << 30);
  EXPECT_GE(automatic.jobs, 1);
  EXPECT_LE(static_cast<uint64_t>(automatic.jobs) * (automatic.memoryBudgetBytes + kWorkerOverheadBytes),
            automatic.availableBytes);
  // Many workers get a smaller budget, never more than the machine has.
  if (automatic.availableBytes / 10 * 8 < 8 * (uint64_t{64} << 20) + 8 * kWorkerOverheadBytes) {
    GTEST_SKIP() << "skipped: less than 4 GiB available; 8 workers cannot fit here";
  }
  const Resources many = decideResources(8, uint64_t{16} << 30);
  EXPECT_EQ(many.jobs, 8);
  EXPECT_LE(8 * (many.memoryBudgetBytes + kWorkerOverheadBytes), many.availableBytes);
  EXPECT_THROW(decideResources(100000, uint64_t{1} << 30), Error);
}

}  // namespace
}  // namespace octoray::batch
