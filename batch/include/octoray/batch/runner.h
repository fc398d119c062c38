#pragma once
// Running a plan: items are built by worker processes (octoray-batch itself, `worker`, reading
// items on its stdin, one JSON line each, and printing a record line for each), so a crash in
// a decoder fails one item, not the run: the worker is replaced. One worker per job slot serves
// item after item (starting one loads every library and its GDCM vetters). N workers run at
// once, each within a memory budget that N of them fit in, each with CPUs / N threads. A store is written through a temporary and renamed (volume/'s
// builder), so it is complete or absent; an item whose store exists and records the plan's
// content hash is not built again, so a killed run resumes where it stopped. Workers stop (and
// remove their temporaries) when the run is killed: they ask Linux for SIGTERM when their parent
// dies.

#include <atomic>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "octoray/batch/manifest.h"
#include "octoray/batch/plan.h"

namespace octoray::batch {

// Per-worker memory on top of the build budget (decoders, header scan, the process itself),
// measured: docs/batch.md.
inline constexpr uint64_t kWorkerOverheadBytes = uint64_t{384} << 20;

struct Resources {
  int jobs = 1;
  uint64_t memoryBudgetBytes = uint64_t{1} << 30;  // per worker (BuildOptions::memoryBudgetBytes)
  uint64_t availableBytes = 0;                     // MemAvailable when decided
  int threadsPerWorker = 1;  // the CPUs this process may use (its affinity) / jobs, at least 1
};

// Workers and their budget: `jobs` 0 picks min(CPUs, what fits in 80 % of the available
// memory at `budget` each); a given `jobs` lowers the budget when needed, down to 64 MiB. Each
// worker's thread pool gets CPUs / jobs threads (CPUs: those this process may run on, e.g. a
// Slurm task's allocation), so N workers do not oversubscribe the machine. Throws
// octoray::Error when `jobs` workers cannot fit.
Resources decideResources(int jobs, uint64_t budgetBytes);

struct RunOptions {
  std::vector<int64_t> items;  // which items, in this order; empty: all
  Resources resources;
  std::string workerExecutable;  // the octoray-batch binary (EXE worker --memory-budget MIB ...)
  // (voxels done, voxels total) as items finish; from any thread, never two at once.
  std::function<void(int64_t, int64_t)> progress;
  // (record) after each item's record is appended; from any thread, never two at once.
  std::function<void(const Record&)> itemFinished;
  const std::atomic<bool>* cancel = nullptr;  // stop starting items; workers get SIGTERM
};

struct RunSummary {
  int64_t selected = 0;
  int64_t built = 0;
  int64_t upToDate = 0;     // store present with the plan's content hash: nothing to do
  int64_t failed = 0;
  int64_t interrupted = 0;  // not finished because the run was cancelled
  int64_t voxelsBuilt = 0;
  double seconds = 0;
  std::vector<Record> failures;
  std::filesystem::path manifest;
};

// Runs `options.items` of the plan read from `planPath`; records go to this process's manifest
// file. Throws octoray::Error only for what stops the whole run (manifest not writable, bad
// item index); item failures are in the summary.
RunSummary runPlan(const std::filesystem::path& planPath, const Plan& plan, const RunOptions& options);

// True when the item's store exists, opens, and its provenance records the item's content hash.
bool storeIsUpToDate(const WorkItem& item);

// The worker's part: builds one item in this process (what `octoray-batch worker` does with
// each item it reads on stdin). Never throws for the item's own problems: they are the failed record.
// BuildCancelled passes through when `cancel` is set.
Record buildItem(const WorkItem& item, uint64_t memoryBudgetBytes, const std::atomic<bool>* cancel);

// The line a worker prints its record on (the rest of its output is kept for messages).
inline constexpr const char* kRecordPrefix = "octoray-batch-record: ";

}  // namespace octoray::batch
