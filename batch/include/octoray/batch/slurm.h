#pragma once
// A plan as a Slurm job array: items grouped so that each array task is at least a minute of
// work (a task per small series would spend more time being scheduled than importing), and an
// sbatch script whose task N runs `octoray-batch run PLAN --items <group N> --jobs 1`. The tasks
// write their own manifest files (writerName(): slurm-JOB_TASK), which `status` merges.

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "octoray/batch/plan.h"

namespace octoray::batch {

struct SlurmOptions {
  std::string partition;          // empty: the cluster's default partition
  std::string timeLimit = "04:00:00";  // per array task
  std::string memory;             // per task, sbatch's --mem (e.g. "2G"); empty: budget + overhead
  uint64_t memoryBudgetBytes = uint64_t{1} << 30;  // the build's, per task
  int cpusPerTask = 2;
  int arrayParallel = 0;          // at most K tasks at once (%K); 0: no limit
  double minTaskSeconds = 60;     // a task gets items until their estimate reaches this
  double mvoxelsPerSecond = 40;   // the estimate's rate (the manifest's median when known)
  int maxArrayTasks = 1000;       // Slurm's default MaxArraySize is 1001
  std::string jobName = "octoray-batch";
  std::string executable;         // absolute path of octoray-batch
};

// Consecutive groups of `items` (plan order), each estimated at >= minTaskSeconds (the last may
// be less), at most maxArrayTasks groups.
std::vector<std::vector<int64_t>> groupItems(const Plan& plan, const std::vector<int64_t>& items,
                                             const SlurmOptions& options);

// The sbatch script for `groups` of the plan at `planPath` (absolute). Logs go to
// LOGS/%A_%a.log.
std::string sbatchScript(const std::filesystem::path& planPath,
                         const std::vector<std::vector<int64_t>>& groups,
                         const SlurmOptions& options, const std::filesystem::path& logs);

}  // namespace octoray::batch
