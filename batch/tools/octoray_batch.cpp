// octoray-batch: a whole archive into stores (docs/batch.md).
//   plan ARCHIVE... -o PLAN.json   one work item per volumetric series or volume file
//   run PLAN.json                  build the items (parallel workers, resumable)
//   status PLAN.json               what the manifest says: counts, failures, throughput
//   validate PLAN.json             octoray-validate's store checks on every output
//   slurm PLAN.json                the same run as a Slurm job array
// (`worker` is what `run` starts for each item; it reads the item on stdin.)

#include <sys/prctl.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <tbb/global_control.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <atomic>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <iterator>
#include <mutex>
#include <thread>

#include <fmt/format.h>

#include "cli_checks.h"
#include "cli_support.h"
#include "octoray/batch/manifest.h"
#include "octoray/batch/plan.h"
#include "octoray/batch/runner.h"
#include "octoray/batch/slurm.h"
#include "octoray/core/atomic_file.h"
#include "octoray/core/error.h"
#include "octoray/volume/store_builder.h"
#include "octoray/volume/store_reader.h"
#include "octoray/volume/store_validator.h"
#include "octoray/batch/process.h"

namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using namespace octoray;
using namespace octoray::batch;

constexpr uint64_t kMiB = uint64_t{1} << 20;

std::atomic<bool> gStop{false};
std::atomic<int> gStopSignal{0};
extern "C" void onStopSignal(int sig) {
  gStopSignal.store(sig);
  gStop.store(true);
}

void catchStopSignals() {
  std::signal(SIGINT, onStopSignal);
  std::signal(SIGTERM, onStopSignal);
}

std::string selfExecutable() {
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  if (ec) throw Error("/proc/self/exe", "cannot find this program's path: " + ec.message());
  return self.string();
}

bool onTerminal() { return ::isatty(STDOUT_FILENO) && ::isatty(STDERR_FILENO); }

// ---- plan ----------------------------------------------------------------------------------

struct PlanArgs {
  std::vector<std::string> archives;
  std::string plan, outDir, outputTemplate = kDefaultOutputTemplate, idSalt;
  std::vector<std::string> modalities;
  int64_t minSlices = 0;
  std::string studyDate, description;
  bool json = false;
};

int planCommand(const PlanArgs& a) {
  PlanOptions options;
  const fs::path planPath = fs::absolute(a.plan);
  std::error_code ec;
  fs::create_directories(planPath.parent_path(), ec);
  if (ec) throw Error(planPath.parent_path().string(), "cannot create the folder: " + ec.message());
  options.outDir = a.outDir.empty() ? (planPath.parent_path() / "stores").string() : a.outDir;
  options.outputTemplate = a.outputTemplate;
  options.idSalt = a.idSalt;
  options.modalities = a.modalities;
  options.minSlices = a.minSlices;
  if (!a.studyDate.empty()) {
    const auto dash = a.studyDate.find('-');
    if (dash == std::string::npos) throw Error("", fmt::format("--study-date '{}': give FROM-TO (YYYYMMDD-YYYYMMDD, either may be empty)", a.studyDate));
    options.studyDateFrom = a.studyDate.substr(0, dash);
    options.studyDateTo = a.studyDate.substr(dash + 1);
  }
  options.descriptionRegex = a.description;
  cli::ProgressBar bar("planning");
  std::mutex mutex;
  options.progress = [&](const char*, std::size_t done, std::size_t total) {
    std::lock_guard lock(mutex);
    bar.update(done, total);
  };
  const Plan plan = makePlan(a.archives, options);
  bar.finish();
  writePlan(plan, planPath);
  if (a.json) {
    std::cout << dumpJson(json{{"tool", "octoray-batch"}, {"command", "plan"}, {"plan", planPath.string()},
                      {"items", plan.items.size()}, {"totalVoxels", plan.totalVoxels()},
                      {"skipped", plan.skipped.size()}, {"unreadableFiles", plan.unreadableFiles.size()},
                      {"warnings", plan.warnings}}
                     , 2)
              << "\n";
    return 0;
  }
  uint64_t bytes = 0;
  for (const auto& it : plan.items) bytes += it.bytes;
  fmt::print("wrote {}: {} items ({:.1f} Mvoxels, {:.1f} MiB of source files), stores under {}\n",
             planPath.string(), plan.items.size(), static_cast<double>(plan.totalVoxels()) / 1e6,
             static_cast<double>(bytes) / kMiB, plan.outDir);
  if (!plan.skipped.empty()) {
    fmt::print("{} series or files not built:\n", plan.skipped.size());
    for (const auto& s : plan.skipped) {
      fmt::print("  {}{}: {}\n", s.path, s.seriesUid.empty() ? "" : fmt::format(" (series {})", s.seriesNumber), s.reason);
    }
  }
  if (!plan.unreadableFiles.empty()) {
    fmt::print("{} files are no image (listed in the plan's \"unreadableFiles\")\n", plan.unreadableFiles.size());
  }
  for (const auto& w : plan.warnings) fmt::print("warning: {}\n", w);
  if (a.idSalt.empty() && a.outputTemplate.find("{PatientID-hash}") != std::string::npos) {
    fmt::print("note: no --id-salt: folder names hash patient IDs with a public key, so IDs can be "
               "recovered by hashing guesses; give a private salt for data leaving the site\n");
  }
  return 0;
}

// ---- item selection --------------------------------------------------------------------------

std::vector<int64_t> parseItemList(const std::string& text, const char* option) {
  std::vector<int64_t> items;
  std::size_t start = 0;
  while (start <= text.size()) {
    const std::size_t comma = std::min(text.find(',', start), text.size());
    const std::string part = text.substr(start, comma - start);
    std::size_t used = 0;
    long long v = -1;
    try {
      v = std::stoll(part, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (part.empty() || used != part.size() || v < 0) {
      throw Error("", fmt::format("{} '{}': give item numbers separated by commas", option, text));
    }
    items.push_back(v);
    start = comma + 1;
  }
  return items;
}

struct Selection {
  std::optional<int64_t> index;
  std::string range, items;
  bool onlyFailed = false;
};

std::vector<int64_t> selectItems(const Selection& s, const Plan& plan, const ManifestState& state) {
  std::vector<int64_t> out;
  if (s.index) {
    out.push_back(*s.index);
  } else if (!s.range.empty()) {
    const auto colon = s.range.find(':');
    std::vector<int64_t> ends;
    try {
      if (colon == std::string::npos) throw std::invalid_argument("no colon");
      ends = {std::stoll(s.range.substr(0, colon)), std::stoll(s.range.substr(colon + 1))};
    } catch (const std::exception&) {
      throw Error("", fmt::format("--range '{}': give A:B (items A to B-1)", s.range));
    }
    const auto count = static_cast<int64_t>(plan.items.size());
    if (ends[0] < 0 || ends[1] > count || ends[0] >= ends[1]) {
      throw Error("", fmt::format("--range {}: the plan has items 0..{}", s.range, count - 1));
    }
    for (int64_t i = ends[0]; i < ends[1]; ++i) out.push_back(i);
  } else if (!s.items.empty()) {
    out = parseItemList(s.items, "--items");
  } else {
    for (const auto& it : plan.items) out.push_back(it.index);
  }
  for (int64_t i : out) {
    if (i < 0 || i >= static_cast<int64_t>(plan.items.size())) {
      throw Error("", fmt::format("item {} is not in the plan (0..{})", i, plan.items.size() - 1));
    }
  }
  if (s.onlyFailed) {
    std::erase_if(out, [&](int64_t i) {
      const auto r = state.latest.find(i);
      return r == state.latest.end() || r->second.status != "failed";
    });
  }
  return out;
}

// ---- run -----------------------------------------------------------------------------------

struct RunArgs {
  std::string plan;
  int jobs = 0;
  uint64_t memoryBudgetMiB = 1024;
  Selection selection;
  bool json = false;
};

int runCommand(const RunArgs& a) {
  const fs::path planPath = fs::absolute(a.plan);
  const Plan plan = readPlan(planPath);
  const std::vector<int64_t> items = selectItems(a.selection, plan, readManifest(planPath, plan));
  RunOptions options;
  options.items = items;
  options.resources = decideResources(a.jobs, a.memoryBudgetMiB * kMiB);
  options.workerExecutable = selfExecutable();
  options.cancel = &gStop;
  catchStopSignals();
  const bool terminal = onTerminal();
  cli::ProgressBar bar("importing");
  std::size_t finished = 0;
  options.progress = [&](int64_t done, int64_t total) {
    bar.update(static_cast<std::size_t>(done), static_cast<std::size_t>(total));
  };
  options.itemFinished = [&](const Record& r) {
    ++finished;
    if (terminal || a.json) return;  // the bar, or the summary, says it
    const WorkItem& it = plan.items[static_cast<std::size_t>(r.item)];
    if (r.status == "failed") {
      fmt::print("[{}/{}] item {} failed: {}\n", finished, items.size(), r.item, r.error);
    } else {
      fmt::print("[{}/{}] item {} {} {:.2f} s {:.1f} Mvoxels/s -> {}\n", finished, items.size(), r.item,
                 r.note.empty() ? "built" : r.note, r.seconds, r.mvoxelsPerSecond, it.output);
    }
    std::fflush(stdout);
  };
  if (!a.json && !items.empty()) {
    fmt::print("{} items, {} worker{} with {} thread{} and a {} MiB build budget each ({} MiB available)\n",
               items.size(), options.resources.jobs, options.resources.jobs == 1 ? "" : "s",
               options.resources.threadsPerWorker, options.resources.threadsPerWorker == 1 ? "" : "s",
               options.resources.memoryBudgetBytes / kMiB, options.resources.availableBytes / kMiB);
    std::fflush(stdout);
  }
  const RunSummary s = runPlan(planPath, plan, options);
  bar.finish();
  const double mvox = s.seconds > 0 ? static_cast<double>(s.voxelsBuilt) / s.seconds / 1e6 : 0;
  if (a.json) {
    json failures = json::array();
    for (const auto& r : s.failures) failures.push_back(r.toJson());
    std::cout << dumpJson(json{{"tool", "octoray-batch"}, {"command", "run"}, {"plan", planPath.string()},
                      {"selected", s.selected}, {"built", s.built}, {"upToDate", s.upToDate},
                      {"failed", s.failed}, {"interrupted", s.interrupted},
                      {"seconds", s.seconds}, {"voxelsBuilt", s.voxelsBuilt},
                      {"mvoxelsPerSecond", mvox}, {"jobs", options.resources.jobs},
                      {"threadsPerWorker", options.resources.threadsPerWorker},
                      {"memoryBudgetMiB", options.resources.memoryBudgetBytes / kMiB},
                      {"manifest", s.manifest.string()}, {"failures", failures}}
                     , 2)
              << "\n";
  } else {
    fmt::print("{} built, {} already up to date, {} failed{} in {:.2f} s ({:.1f} Mvoxels/s)\n", s.built,
               s.upToDate, s.failed, s.interrupted ? fmt::format(", {} not finished (interrupted)", s.interrupted) : "",
               s.seconds, mvox);
  }
  for (const auto& r : s.failures) fmt::print(stderr, "failed: item {}: {}\n", r.item, r.error);
  if (gStop.load()) {
    fmt::print(stderr, "octoray-batch: interrupted; run again to finish the remaining items\n");
    return 128 + (gStopSignal.load() != 0 ? gStopSignal.load() : SIGINT);
  }
  return s.failed > 0 ? 1 : 0;
}

// ---- worker --------------------------------------------------------------------------------

// Peak memory of this process since the last reset (Linux: VmHWM; "5" to clear_refs resets it).
void resetPeakMemory() { std::ofstream("/proc/self/clear_refs") << "5"; }
double peakMemoryMiB() {
  std::ifstream status("/proc/self/status");
  for (std::string line; std::getline(status, line);) {
    if (line.starts_with("VmHWM:")) return std::stod(line.substr(6)) / 1024.0;  // kB
  }
  return 0;
}

// Builds the items read on stdin, one JSON line each, printing one record line per item;
// ends at end of input. `run` keeps one worker per job slot for all its items.
int workerCommand(uint64_t memoryBudgetMiB, int64_t parent) {
  // Stop (and remove the temporary store) when the run that started us dies, even by SIGKILL.
  ::prctl(PR_SET_PDEATHSIG, SIGTERM);
  catchStopSignals();
  // A run killed while we write must not kill us before the temporary store is removed.
  std::signal(SIGPIPE, SIG_IGN);
  if (parent > 0 && ::getppid() != static_cast<pid_t>(parent)) return 128 + SIGTERM;
  for (std::string line; std::getline(std::cin, line);) {
    if (line.empty()) continue;
    const json j = json::parse(line, nullptr, false);
    if (j.is_discarded()) throw Error("<stdin>", "the work item is not JSON");
    const WorkItem item = itemFromJson(j, "<stdin>");
    resetPeakMemory();
    try {
      Record r = buildItem(item, memoryBudgetMiB * kMiB, &gStop);
      r.peakRssMiB = peakMemoryMiB();
      std::fflush(stderr);
      std::cout << "\n" << kRecordPrefix << dumpJson(r.toJson()) << std::endl;
    } catch (const volume::BuildCancelled&) {
      return 128 + (gStopSignal.load() != 0 ? gStopSignal.load() : SIGTERM);
    }
    if (gStop.load()) return 128 + (gStopSignal.load() != 0 ? gStopSignal.load() : SIGTERM);
  }
  return 0;
}

// ---- status --------------------------------------------------------------------------------

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
}

int statusCommand(const std::string& planArg, bool asJson) {
  const fs::path planPath = fs::absolute(planArg);
  const Plan plan = readPlan(planPath);
  const ManifestState state = readManifest(planPath, plan);
  int64_t done = 0, failed = 0, pending = 0, voxels = 0;
  uint64_t bytes = 0;
  double seconds = 0;
  std::vector<double> rates, peaks;
  json failures = json::array();
  for (const auto& it : plan.items) {
    const auto r = state.latest.find(it.index);
    if (r == state.latest.end()) {
      ++pending;
    } else if (r->second.status == "failed") {
      ++failed;
      failures.push_back({{"item", it.index}, {"output", it.output}, {"error", r->second.error}});
    } else {
      ++done;
      bytes += r->second.bytes;
      if (r->second.seconds > 0) {
        voxels += it.voxels();
        seconds += r->second.seconds;
        rates.push_back(r->second.mvoxelsPerSecond);
        peaks.push_back(r->second.peakRssMiB);
      }
    }
  }
  const double rate = seconds > 0 ? static_cast<double>(voxels) / seconds / 1e6 : 0;
  if (asJson) {
    std::cout << dumpJson(json{{"tool", "octoray-batch"}, {"command", "status"}, {"plan", planPath.string()},
                      {"items", plan.items.size()}, {"done", done}, {"failed", failed},
                      {"pending", pending}, {"bytesOnDisk", bytes},
                      {"mvoxelsPerSecondPerWorker", rate}, {"medianPeakRssMiB", median(peaks)},
                      {"manifestFiles", state.files}, {"records", state.records},
                      {"tornLines", state.tornLines}, {"staleRecords", state.staleRecords},
                      {"failures", failures}}
                     , 2)
              << "\n";
    return 0;
  }
  fmt::print("{}: {} items, {:.1f} Mvoxels\n", planPath.string(), plan.items.size(),
             static_cast<double>(plan.totalVoxels()) / 1e6);
  fmt::print("  done     {}\n  failed   {}\n  pending  {}\n", done, failed, pending);
  if (!rates.empty()) {
    fmt::print("built: {:.1f} MiB on disk, {:.1f} Mvoxels/s per worker (median item {:.1f}), median peak "
               "memory {:.0f} MiB\n",
               static_cast<double>(bytes) / kMiB, rate, median(rates), median(peaks));
  }
  fmt::print("manifest: {} file(s), {} records", state.files, state.records);
  if (state.tornLines) fmt::print(", {} cut-off line(s) ignored", state.tornLines);
  if (state.staleRecords) fmt::print(", {} record(s) of an earlier plan ignored", state.staleRecords);
  fmt::print("\n");
  for (const auto& f : failures) {
    fmt::print("failed: item {}: {}\n", f["item"].get<int64_t>(), f["error"].get<std::string>());
  }
  return 0;
}

// ---- validate ------------------------------------------------------------------------------

int validateCommand(const std::string& planArg, int jobs, bool asJson) {
  const fs::path planPath = fs::absolute(planArg);
  const Plan plan = readPlan(planPath);
  struct Outcome {
    std::string problem;  // empty: passed
    bool missing = false;
  };
  std::vector<Outcome> outcomes(plan.items.size());
  std::atomic<std::size_t> next{0}, checked{0};
  cli::ProgressBar bar("validating");
  std::mutex barMutex;
  auto work = [&] {
    for (std::size_t i = next++; i < plan.items.size(); i = next++) {
      const WorkItem& it = plan.items[i];
      Outcome& o = outcomes[i];
      std::error_code ec;
      if (!fs::exists(it.output, ec)) {
        o.missing = true;
        o.problem = "not built";
      } else {
        const volume::ValidationReport report = volume::validateStore(it.output);
        for (const auto& check : report.checks) {
          if (check.passed()) continue;
          o.problem = fmt::format("{}: {}", check.name,
                                  check.failures.empty() ? std::string(volume::toString(check.status))
                                                         : check.failures.front().message);
          break;
        }
        if (o.problem.empty() && !storeIsUpToDate(it)) {
          o.problem = "the store does not record the plan's content hash (built from other files)";
        }
      }
      std::lock_guard lock(barMutex);
      bar.update(++checked, plan.items.size());
    }
  };
  const int threads = jobs > 0 ? jobs : std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
  std::vector<std::thread> pool;
  for (int t = 0; t < threads; ++t) pool.emplace_back(work);
  for (auto& t : pool) t.join();
  bar.finish();
  int64_t passed = 0, failed = 0, missing = 0;
  json problems = json::array();
  for (std::size_t i = 0; i < outcomes.size(); ++i) {
    if (outcomes[i].problem.empty()) {
      ++passed;
      continue;
    }
    (outcomes[i].missing ? missing : failed)++;
    problems.push_back({{"item", i}, {"output", plan.items[i].output}, {"problem", outcomes[i].problem}});
  }
  if (asJson) {
    std::cout << dumpJson(json{{"tool", "octoray-batch"}, {"command", "validate"}, {"plan", planPath.string()},
                      {"items", plan.items.size()}, {"passed", passed}, {"failed", failed},
                      {"notBuilt", missing}, {"problems", problems}}
                     , 2)
              << "\n";
  } else {
    fmt::print("{} of {} stores passed every check; {} failed, {} not built\n", passed, plan.items.size(),
               failed, missing);
    for (const auto& p : problems) {
      fmt::print("item {}: {}: {}\n", p["item"].get<std::size_t>(), p["output"].get<std::string>(),
                 p["problem"].get<std::string>());
    }
  }
  return failed + missing > 0 ? 1 : 0;
}

// ---- slurm ---------------------------------------------------------------------------------

struct SlurmArgs {
  std::string plan;
  SlurmOptions options;
  uint64_t memoryBudgetMiB = 1024;
  bool onlyFailed = false, dryRun = false, json = false;
};

int slurmCommand(SlurmArgs a) {
  const fs::path planPath = fs::absolute(a.plan);
  const Plan plan = readPlan(planPath);
  const ManifestState state = readManifest(planPath, plan);
  std::vector<int64_t> items;
  std::vector<double> rates;
  for (const auto& it : plan.items) {
    const auto r = state.latest.find(it.index);
    std::string status = r == state.latest.end() ? "pending" : r->second.status;
    if (status == "done" && !storeIsUpToDate(it)) status = "pending";  // removed or replaced since
    if (status == "done" && r->second.mvoxelsPerSecond > 0) rates.push_back(r->second.mvoxelsPerSecond);
    if (a.onlyFailed ? status == "failed" : status != "done") items.push_back(it.index);
  }
  if (items.empty()) {
    fmt::print("{}: nothing to submit ({})\n", planPath.string(),
               a.onlyFailed ? "no item has failed" : "every item is done");
    return 0;
  }
  if (!rates.empty()) a.options.mvoxelsPerSecond = median(rates);
  a.options.memoryBudgetBytes = a.memoryBudgetMiB * kMiB;
  a.options.executable = selfExecutable();
  fs::path folder = planPath;
  folder.replace_extension();
  folder += ".slurm";
  const fs::path logs = folder / "logs";
  const auto groups = groupItems(plan, items, a.options);
  const std::string script = sbatchScript(planPath, groups, a.options, logs);
  if (a.dryRun) {
    std::cout << script;
    return 0;
  }
  std::error_code ec;
  fs::create_directories(logs, ec);
  if (ec) throw Error(logs.string(), "cannot create the folder: " + ec.message());
  std::string stamp = isoTimeNow();  // 2026-12-02T21:53:00.377Z -> 20261202T215300377Z
  std::erase_if(stamp, [](char c) { return c == '-' || c == ':' || c == '.'; });
  const fs::path scriptPath = folder / fmt::format("job-{}.sbatch", stamp);
  writeFileAtomically(scriptPath, script);
  const detail::ProcessResult result = detail::runProcess({"sbatch", "--parsable", scriptPath.string()}, "");
  std::string out = result.output;
  while (!out.empty() && (out.back() == '\n' || out.back() == '\r')) out.pop_back();
  if (result.exitCode != 0) {
    throw Error(scriptPath.string(), fmt::format("sbatch refused the job ({}): {}",
                                                 result.signal ? fmt::format("signal {}", result.signal)
                                                               : fmt::format("status {}", result.exitCode),
                                                 out));
  }
  // --parsable prints "JOBID" or "JOBID;CLUSTER"; sbatch may print warnings on lines before it.
  const std::string last = out.substr(out.find_last_of('\n') == std::string::npos ? 0 : out.find_last_of('\n') + 1);
  const std::string jobId = last.substr(0, last.find(';'));
  if (a.json) {
    std::cout << dumpJson(json{{"tool", "octoray-batch"}, {"command", "slurm"}, {"plan", planPath.string()},
                      {"jobId", jobId}, {"script", scriptPath.string()}, {"items", items.size()},
                      {"arrayTasks", groups.size()}, {"logs", logs.string()}}
                     , 2)
              << "\n";
  } else {
    fmt::print("submitted job {}: {} items in {} array tasks ({})\n", jobId, items.size(), groups.size(),
               scriptPath.string());
    fmt::print("follow it with: octoray-batch status {}\n", planPath.string());
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"octoray-batch: import a whole archive into octoray stores, on one machine or a Slurm cluster"};
  app.require_subcommand(1);

  PlanArgs planArgs;
  auto* plan = app.add_subcommand("plan", "Scan archives and write the plan: one work item per volumetric series");
  plan->add_option("archive", planArgs.archives, "Folders, DICOMDIRs, DICOM or volume files")->required();
  plan->add_option("-o,--output", planArgs.plan, "The plan to write (JSON)")->required();
  plan->add_option("--out-dir", planArgs.outDir, "Where the stores go (default: stores/ beside the plan)");
  plan->add_option("--template", planArgs.outputTemplate, "Store path under --out-dir, from the fields "
                   "{PatientID-hash} {PatientID} {PatientName} {StudyInstanceUID} {StudyDate} "
                   "{SeriesInstanceUID} {SeriesNumber} {SeriesDescription} {Modality} {Index} {FileName}")
      ->capture_default_str();
  plan->add_option("--id-salt", planArgs.idSalt, "Key of the patient-ID hash (keep it private)");
  plan->add_option("--modality", planArgs.modalities, "Only these modalities (repeatable), e.g. CT");
  plan->add_option("--min-slices", planArgs.minSlices, "Only series with at least N slices")->check(octoray::cli::kNonNegative);
  plan->add_option("--study-date", planArgs.studyDate, "Only studies in FROM-TO (YYYYMMDD-YYYYMMDD; either may be empty)");
  plan->add_option("--description", planArgs.description, "Only series whose description matches this regex (case-insensitive)");
  plan->add_flag("--json", planArgs.json, "Machine-readable summary");

  RunArgs runArgs;
  auto* run = app.add_subcommand("run", "Build the plan's items (skips stores already built; resumable)");
  run->add_option("plan", runArgs.plan, "The plan")->required();
  run->add_option("--jobs,-j", runArgs.jobs, "Parallel workers (default: from cores and memory)")->check(octoray::cli::kNonNegative);
  run->add_option("--memory-budget", runArgs.memoryBudgetMiB, "Build memory budget per worker in MiB")
      ->check(CLI::Range(64, 1 << 20))->capture_default_str();
  auto* index = run->add_option("--index", runArgs.selection.index, "Only item I")->check(octoray::cli::kNonNegative);
  auto* range = run->add_option("--range", runArgs.selection.range, "Only items A to B-1 (A:B)");
  auto* list = run->add_option("--items", runArgs.selection.items, "Only these items (I,J,K)");
  index->excludes(range)->excludes(list);
  range->excludes(list);
  run->add_flag("--only-failed", runArgs.selection.onlyFailed, "Only items whose last record failed");
  run->add_flag("--json", runArgs.json, "Machine-readable summary");

  std::string statusPlan;
  bool statusJson = false;
  auto* status = app.add_subcommand("status", "Counts, failures and throughput from the manifest");
  status->add_option("plan", statusPlan, "The plan")->required();
  status->add_flag("--json", statusJson, "Machine-readable output");

  std::string validatePlan;
  int validateJobs = 0;
  bool validateJson = false;
  auto* validate = app.add_subcommand("validate", "Check every output store (octoray-validate's store checks)");
  validate->add_option("plan", validatePlan, "The plan")->required();
  validate->add_option("--jobs,-j", validateJobs, "Stores checked at once (default: cores)")->check(octoray::cli::kNonNegative);
  validate->add_flag("--json", validateJson, "Machine-readable output");

  SlurmArgs slurmArgs;
  auto* slurm = app.add_subcommand("slurm", "Submit the plan's unfinished items as a Slurm job array");
  slurm->add_option("plan", slurmArgs.plan, "The plan")->required();
  slurm->add_option("--partition", slurmArgs.options.partition, "Slurm partition (default: the cluster's)");
  slurm->add_option("--time", slurmArgs.options.timeLimit, "Time limit per array task")->capture_default_str();
  slurm->add_option("--mem", slurmArgs.options.memory, "Memory per array task (default: budget + overhead)");
  slurm->add_option("--cpus-per-task", slurmArgs.options.cpusPerTask, "CPUs per array task")
      ->check(octoray::cli::kPositive)->capture_default_str();
  slurm->add_option("--array-parallel", slurmArgs.options.arrayParallel, "At most K array tasks at once")
      ->check(octoray::cli::kNonNegative);
  slurm->add_option("--min-task-seconds", slurmArgs.options.minTaskSeconds, "Estimated work per array task")
      ->check(octoray::cli::kNonNegative)->capture_default_str();
  slurm->add_option("--memory-budget", slurmArgs.memoryBudgetMiB, "Build memory budget per task in MiB")
      ->check(CLI::Range(64, 1 << 20))->capture_default_str();
  slurm->add_option("--job-name", slurmArgs.options.jobName, "Slurm job name")->capture_default_str();
  slurm->add_flag("--only-failed", slurmArgs.onlyFailed, "Submit only the items whose last record failed");
  slurm->add_flag("--dry-run", slurmArgs.dryRun, "Print the sbatch script instead of submitting it");
  slurm->add_flag("--json", slurmArgs.json, "Machine-readable output");

  uint64_t workerBudgetMiB = 1024;
  int64_t workerParent = 0;
  int workerThreads = 0;
  auto* worker = app.add_subcommand("worker", "(internal) build the items read on stdin, one JSON line each");
  worker->group("");
  worker->add_option("--memory-budget", workerBudgetMiB, "MiB")->check(CLI::Range(1, 1 << 20));
  worker->add_option("--parent", workerParent, "pid of the run that started this worker");
  worker->add_option("--threads", workerThreads, "threads of this worker's pool (0: all CPUs)");

  app.footer(
      "Examples:\n"
      "  octoray-batch plan /archive -o ct.json --modality CT --min-slices 20  # what would be built\n"
      "  octoray-batch run ct.json                 # build (again: only what is missing)\n"
      "  octoray-batch status ct.json              # counts, failures, throughput\n"
      "  octoray-batch validate ct.json            # check every store\n"
      "  octoray-batch slurm ct.json --partition short --array-parallel 50   # on a cluster\n"
      "  octoray-batch slurm ct.json --only-failed # resubmit what failed\n");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : 2;
  }
  return cli::runTool("octoray-batch", [&] {
    if (*plan) return planCommand(planArgs);
    if (*run) return runCommand(runArgs);
    if (*status) return statusCommand(statusPlan, statusJson);
    if (*validate) return validateCommand(validatePlan, validateJobs, validateJson);
    if (*slurm) return slurmCommand(slurmArgs);
    // The thread pool's size for the whole worker (decoding, hashing, building).
    std::optional<tbb::global_control> threads;
    if (workerThreads > 0) {
      threads.emplace(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(workerThreads));
    }
    return workerCommand(workerBudgetMiB, workerParent);
  });
}
