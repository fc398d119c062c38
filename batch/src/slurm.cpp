#include "octoray/batch/slurm.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>

#include "octoray/batch/runner.h"
#include "octoray/core/error.h"

namespace octoray::batch {

namespace {

// Quoted for bash: '...' with every ' as '\''.
std::string shellQuote(const std::string& s) {
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

// Slurm option values come from the command line: refuse what would break the #SBATCH line.
void checkValue(const std::string& value, const char* option) {
  for (char c : value) {
    if (c == '\n' || c == '\r' || c == ' ' || c == '\t' || c == '#') {
      throw Error("", fmt::format("{} '{}' must be one word", option, value));
    }
  }
}

}  // namespace

std::vector<std::vector<int64_t>> groupItems(const Plan& plan, const std::vector<int64_t>& items,
                                             const SlurmOptions& options) {
  const double rate = std::max(options.mvoxelsPerSecond, 1e-3) * 1e6;
  auto seconds = [&](int64_t i) {
    // One second of start-up per item (scan, hash, open) on top of the voxel rate.
    return 1.0 + static_cast<double>(plan.items[static_cast<std::size_t>(i)].voxels()) / rate;
  };
  double total = 0;
  for (int64_t i : items) total += seconds(i);
  // Enough work per task, and no more tasks than Slurm's array allows.
  const double target = std::max(options.minTaskSeconds, total / std::max(1, options.maxArrayTasks));
  std::vector<std::vector<int64_t>> groups;
  double inGroup = 0;
  for (int64_t i : items) {
    if (groups.empty() || inGroup >= target) {
      groups.emplace_back();
      inGroup = 0;
    }
    groups.back().push_back(i);
    inGroup += seconds(i);
  }
  return groups;
}

std::string sbatchScript(const std::filesystem::path& planPath,
                         const std::vector<std::vector<int64_t>>& groups,
                         const SlurmOptions& options, const std::filesystem::path& logs) {
  if (groups.empty()) throw Error(planPath.string(), "no items to submit");
  checkValue(options.partition, "--partition");
  checkValue(options.timeLimit, "--time");
  checkValue(options.memory, "--mem");
  checkValue(options.jobName, "--job-name");
  // #SBATCH lines are not shell: the log path cannot be quoted, and '%' is Slurm's pattern.
  for (const auto& [path, what] : {std::pair{planPath.string(), "the plan's path"},
                                   std::pair{logs.string(), "the log folder's path"}}) {
    if (path.find_first_of(" \t\n\r%#") != std::string::npos) {
      throw Error(path, fmt::format("{} holds a space, '%' or '#', which an sbatch script cannot carry: "
                                    "move the plan to a plainer path", what));
    }
  }
  const uint64_t mib = uint64_t{1} << 20;
  const std::string memory =
      options.memory.empty()
          ? fmt::format("{}M", (options.memoryBudgetBytes + kWorkerOverheadBytes) / mib + 256)
          : options.memory;
  std::size_t items = 0;
  for (const auto& g : groups) items += g.size();
  std::string s = "#!/bin/bash\n";
  s += fmt::format("# octoray-batch: {} items of {} in {} array tasks.\n", items,
                   planPath.string(), groups.size());
  s += "# Task N imports the items of group N; each task appends to its own manifest file\n";
  s += "# (PLAN.manifest/slurm-JOB_TASK.jsonl). Progress: octoray-batch status PLAN\n";
  s += fmt::format("#SBATCH --job-name={}\n", options.jobName);
  s += fmt::format("#SBATCH --array=0-{}{}\n", groups.size() - 1,
                   options.arrayParallel > 0 ? fmt::format("%{}", options.arrayParallel) : "");
  if (!options.partition.empty()) s += fmt::format("#SBATCH --partition={}\n", options.partition);
  s += fmt::format("#SBATCH --time={}\n", options.timeLimit);
  s += fmt::format("#SBATCH --mem={}\n", memory);
  s += fmt::format("#SBATCH --cpus-per-task={}\n", options.cpusPerTask);
  s += "#SBATCH --ntasks=1\n";
  s += fmt::format("#SBATCH --output={}\n", (logs / "%A_%a.log").string());
  s += "set -euo pipefail\n";
  s += "groups=(\n";
  for (const auto& g : groups) {
    std::string list;
    for (int64_t i : g) list += (list.empty() ? "" : ",") + std::to_string(i);
    s += "  " + list + "\n";
  }
  s += ")\n";
  s += fmt::format("exec {} run {} --items \"${{groups[$SLURM_ARRAY_TASK_ID]}}\" --jobs 1 --memory-budget {}\n",
                   shellQuote(options.executable), shellQuote(planPath.string()),
                   std::max<uint64_t>(64, options.memoryBudgetBytes / mib));
  return s;
}

}  // namespace octoray::batch
