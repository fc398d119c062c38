#pragma once
// The manifest of a batch import: what happened to each item, as JSON Lines in a folder beside
// the plan (PLAN.json -> PLAN.manifest/). Every writer (one `octoray-batch run` process, one
// Slurm array task) appends to a file of its own, one line per item with a single write() and
// an fsync, so no two processes ever write one file, on one machine or on a cluster's shared
// filesystem. Readers merge the files: an item's state is its latest record whose content hash
// is the plan's. A line cut short by a kill is ignored (and counted).

#include <cstdint>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "octoray/batch/plan.h"

namespace octoray::batch {

struct Record {
  int64_t item = 0;
  std::string status;       // "done" (built, or found built) or "failed"
  std::string contentHash;  // of the item's files when the record was written
  std::string output;
  double seconds = 0;       // wall time of the build
  double mvoxelsPerSecond = 0;
  uint64_t bytes = 0;       // store size on disk
  double peakRssMiB = 0;    // of the worker process that built it
  std::vector<std::string> warnings;
  std::string error;        // failed: the message, naming the file
  std::string note;         // e.g. "found complete" for a store built by a killed run
  std::string worker;       // the manifest file's writer (host and pid, or Slurm job and task)
  std::string finished;     // ISO 8601 UTC with milliseconds

  nlohmann::json toJson() const;
  static Record fromJson(const nlohmann::json& j);
};

// PLAN.json -> PLAN.manifest
std::filesystem::path manifestFolder(const std::filesystem::path& planPath);

// This process's writer name: "slurm-JOB_TASK" inside a Slurm array task ("slurm-JOB" in a
// plain job), else "local-HOST-PID".
std::string writerName();

class ManifestWriter {
 public:
  // Creates the folder and opens (appending) FOLDER/NAME.jsonl.
  ManifestWriter(const std::filesystem::path& folder, const std::string& name);
  ~ManifestWriter();
  ManifestWriter(const ManifestWriter&) = delete;
  ManifestWriter& operator=(const ManifestWriter&) = delete;

  // Stamps `record` (worker, finished) and appends it durably. Throws octoray::Error when the
  // disk refuses.
  void append(Record record);
  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
  std::string name_;
  int fd_ = -1;
};

struct ManifestState {
  std::map<int64_t, Record> latest;  // per item: the latest record that matches the plan
  int64_t records = 0;               // lines read
  int64_t tornLines = 0;             // lines that do not parse (a writer killed mid-line)
  int64_t staleRecords = 0;          // for another content hash, or an item not in the plan
  int64_t files = 0;
};

// Reads every *.jsonl in the plan's manifest folder (none yet: an empty state).
ManifestState readManifest(const std::filesystem::path& planPath, const Plan& plan);

std::string isoTimeNow();  // UTC, milliseconds

}  // namespace octoray::batch
