#include "octoray/batch/runner.h"

#include <fcntl.h>
#include <sched.h>
#include <spawn.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <optional>
#include <csignal>
#include <fstream>
#include <mutex>
#include <set>
#include <sstream>
#include <thread>

#include <fmt/format.h>

#include "octoray/core/error.h"
#include "octoray/dicom/dicom_series.h"
#include "octoray/dicom/dicom_volume.h"
#include "octoray/dicom/formats.h"
#include "octoray/volume/store_builder.h"
#include "octoray/volume/store_reader.h"

extern char** environ;

namespace octoray::batch {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

constexpr uint64_t kMiB = uint64_t{1} << 20;
constexpr uint64_t kMinimumBudget = 64 * kMiB;

uint64_t memAvailableBytes() {
  std::ifstream in("/proc/meminfo");
  std::string key;
  uint64_t kib = 0;
  std::string unit;
  while (in >> key >> kib >> unit) {
    if (key == "MemAvailable:") return kib * 1024;
  }
  return uint64_t{4} << 30;  // not Linux: assume a small machine
}

// The memory this process's cgroup may still use (a container's or a Slurm job's limit), or
// nothing when unlimited or unknown.
std::optional<uint64_t> cgroupRoomBytes() {
  std::ifstream maxFile("/sys/fs/cgroup/memory.max"), currentFile("/sys/fs/cgroup/memory.current");
  std::string max;
  uint64_t current = 0;
  if (!(maxFile >> max) || max == "max" || !(currentFile >> current)) return std::nullopt;
  const uint64_t limit = std::strtoull(max.c_str(), nullptr, 10);
  return limit > current ? limit - current : 0;
}

// The last lines of a worker's output: what a crash message shows.
std::string tail(const std::string& text, std::size_t lines) {
  std::vector<std::string> kept;
  std::istringstream in(text);
  std::string line;
  while (std::getline(in, line)) {
    if (line.starts_with(kRecordPrefix)) continue;
    kept.push_back(line);
    if (kept.size() > lines) kept.erase(kept.begin());
  }
  std::string out;
  for (const auto& l : kept) out += (out.empty() ? "" : " | ") + l;
  return out;
}

// Which file changed since the plan was made: the first whose contents differ from the plan's
// hash, or is gone; else the set of files the reader uses differs.
Error changedSince(const WorkItem& item) {
  const std::vector<std::string> files = item.absoluteFiles();
  for (std::size_t i = 0; i < files.size(); ++i) {
    std::error_code ec;
    if (!fs::exists(files[i], ec)) return Error(files[i], "is gone since the plan was made: make the plan again");
    if (i < item.fileHashes.size() && fileContentHash(files[i]) != item.fileHashes[i]) {
      return Error(files[i], "changed since the plan was made (its content hash differs): make the plan again");
    }
  }
  return Error(item.kind == "file" ? item.path : item.folder,
               "the files the volume is read from are not the ones planned: make the plan again");
}

std::unique_ptr<VolumeSource> openItem(const WorkItem& item) {
  if (item.kind == "file") return openVolume(item.path);
  const std::vector<std::string> files = item.absoluteFiles();
  const dicom::DicomScan scan = dicom::scanDicomFiles(files);
  // A file that no longer reads as an image is the problem to name.
  if (!scan.skipped.empty()) throw Error(scan.skipped.front().path, scan.skipped.front().reason);
  for (const dicom::DicomSeries& series : scan.series) {
    if (series.seriesUid == item.seriesUid && series.kind == dicom::SeriesKind::Volume) {
      return dicom::openDicomSeries(series, {});
    }
  }
  throw Error(files.front(), fmt::format("series {} is no longer among the item's files", item.seriesUid));
}

// A worker process: items go in on its stdin, one JSON line each; for each it prints its
// messages and then one record line. Its stdout and stderr are one pipe.
class WorkerProcess {
 public:
  struct Outcome {
    std::optional<Record> record;  // absent: the worker died before printing one
    std::string output;            // what it printed for this item besides the record
    bool broken = false;           // it printed a record that does not parse: replace it
    bool notSent = false;          // the item never reached it (it had died before)
  };
  struct Exit {
    int code = -1;
    int signal = 0;
  };

  explicit WorkerProcess(const std::vector<std::string>& argv) {
    int in[2], out[2];
    if (::pipe2(in, O_CLOEXEC) != 0) throw Error(argv.front(), std::string("pipe: ") + std::strerror(errno));
    if (::pipe2(out, O_CLOEXEC) != 0) {
      ::close(in[0]);
      ::close(in[1]);
      throw Error(argv.front(), std::string("pipe: ") + std::strerror(errno));
    }
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_adddup2(&actions, in[0], 0);
    posix_spawn_file_actions_adddup2(&actions, out[1], 1);
    posix_spawn_file_actions_adddup2(&actions, out[1], 2);
    posix_spawnattr_t attributes;
    posix_spawnattr_init(&attributes);
    sigset_t all, none;
    sigfillset(&all);
    sigemptyset(&none);
    posix_spawnattr_setsigdefault(&attributes, &all);
    posix_spawnattr_setsigmask(&attributes, &none);
    posix_spawnattr_setflags(&attributes, POSIX_SPAWN_SETSIGDEF | POSIX_SPAWN_SETSIGMASK);
    std::vector<char*> args;
    for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    const int error = posix_spawn(&pid_, args[0], &actions, &attributes, args.data(), environ);
    posix_spawn_file_actions_destroy(&actions);
    posix_spawnattr_destroy(&attributes);
    ::close(in[0]);
    ::close(out[1]);
    if (error != 0) {
      ::close(in[1]);
      ::close(out[0]);
      throw Error(argv.front(), std::string("cannot start a worker: ") + std::strerror(error));
    }
    input_ = in[1];
    output_ = ::fdopen(out[0], "r");
  }
  ~WorkerProcess() {
    closeInput();
    if (output_) std::fclose(output_);
    if (pid_ > 0) {
      ::kill(pid_, SIGTERM);
      reap();
    }
  }
  WorkerProcess(const WorkerProcess&) = delete;
  WorkerProcess& operator=(const WorkerProcess&) = delete;

  pid_t pid() const { return pid_; }

  Outcome build(const std::string& itemLine) {
    Outcome outcome;
    const std::string line = itemLine + "\n";
    std::size_t written = 0;
    while (written < line.size()) {
      const ssize_t n = ::write(input_, line.data() + written, line.size() - written);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) {  // the worker is gone: reap() says how
        outcome.notSent = written == 0;
        return outcome;
      }
      written += static_cast<std::size_t>(n);
    }
    char* text = nullptr;
    std::size_t capacity = 0;
    ssize_t length = 0;
    while ((length = ::getline(&text, &capacity, output_)) >= 0) {
      std::string got(text, static_cast<std::size_t>(length));
      if (!got.empty() && got.back() == '\n') got.pop_back();
      // The record may follow a message that did not end its line.
      const std::size_t at = got.find(kRecordPrefix);
      if (at != std::string::npos) {
        outcome.output += got.substr(0, at);
        try {
          outcome.record = Record::fromJson(json::parse(got.substr(at + std::string(kRecordPrefix).size())));
        } catch (const json::exception& e) {
          outcome.output += std::string("unreadable record: ") + e.what() + "\n";
          outcome.broken = true;
        }
        break;
      }
      outcome.output += got + "\n";
    }
    std::free(text);
    return outcome;
  }

  void closeInput() {
    if (input_ >= 0) ::close(input_);
    input_ = -1;
  }

  Exit reap() {
    Exit exit;
    if (pid_ <= 0) return exit;
    closeInput();
    int status = 0;
    while (::waitpid(pid_, &status, 0) < 0 && errno == EINTR) {
    }
    pid_ = -1;
    if (WIFEXITED(status)) exit.code = WEXITSTATUS(status);
    if (WIFSIGNALED(status)) exit.signal = WTERMSIG(status);
    return exit;
  }

 private:
  pid_t pid_ = -1;
  int input_ = -1;
  std::FILE* output_ = nullptr;
};

}  // namespace

Resources decideResources(int jobs, uint64_t budgetBytes) {
  Resources r;
  r.availableBytes = memAvailableBytes();
  if (const auto room = cgroupRoomBytes()) r.availableBytes = std::min(r.availableBytes, *room);
  const uint64_t usable = r.availableBytes / 10 * 8;
  cpu_set_t allowed;
  CPU_ZERO(&allowed);
  int cores = ::sched_getaffinity(0, sizeof allowed, &allowed) == 0
                        ? std::max(1, CPU_COUNT(&allowed))
                        : std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
  // Inside a Slurm job whose task plugin does not bind CPUs, the allocation is in the environment.
  if (const char* slurm = std::getenv("SLURM_CPUS_PER_TASK"); slurm && std::atoi(slurm) > 0) {
    cores = std::min(cores, std::atoi(slurm));
  }
  if (jobs <= 0) {
    const auto fit = static_cast<int>(usable / (budgetBytes + kWorkerOverheadBytes));
    r.jobs = std::max(1, std::min(cores, fit));
  } else {
    r.jobs = jobs;
  }
  r.memoryBudgetBytes = budgetBytes;
  r.threadsPerWorker = std::max(1, cores / r.jobs);
  const uint64_t perWorker = usable / static_cast<uint64_t>(r.jobs);
  if (perWorker < budgetBytes + kWorkerOverheadBytes) {
    if (perWorker < kMinimumBudget + kWorkerOverheadBytes) {
      throw Error("", fmt::format("{} workers do not fit in the {} MiB of memory available (each needs "
                                  "at least {} MiB): use fewer --jobs",
                                  r.jobs, r.availableBytes / kMiB,
                                  (kMinimumBudget + kWorkerOverheadBytes) / kMiB));
    }
    r.memoryBudgetBytes = perWorker - kWorkerOverheadBytes;
  }
  return r;
}

bool storeIsUpToDate(const WorkItem& item) {
  std::error_code ec;
  if (!fs::is_regular_file(item.output, ec)) return false;
  try {
    const volume::StoreReader store(item.output);
    return !store.source().contentHash.empty() && store.source().contentHash == item.contentHash;
  } catch (const std::exception&) {
    return false;  // damaged: built again
  }
}

Record buildItem(const WorkItem& item, uint64_t memoryBudgetBytes, const std::atomic<bool>* cancel) {
  Record record;
  record.item = item.index;
  record.output = item.output;
  record.contentHash = item.contentHash;
  const auto start = std::chrono::steady_clock::now();
  try {
    auto source = openItem(item);
    const VolumeInfo& info = source->info();
    const std::string hash = sourceContentHash(info.sourceFiles);
    if (hash != item.contentHash) throw changedSince(item);
    std::error_code ec;
    fs::create_directories(fs::path(item.output).parent_path(), ec);
    if (ec) throw Error(fs::path(item.output).parent_path().string(), "cannot create the folder: " + ec.message());
    // The options octoray-import uses by default, so the store is the one it would build.
    volume::BuildOptions options;
    options.memoryBudgetBytes = memoryBudgetBytes;
    options.sourceContentHash = hash;
    options.cancel = cancel;
    const volume::BuildReport report = volume::buildStore(*source, item.output, options);
    record.status = "done";
    record.bytes = report.bytesOnDisk;
    record.warnings = info.warnings;
    if (report.clampedSamples > 0) {
      record.warnings.push_back(fmt::format("{} samples outside the 16-bit range were clamped", report.clampedSamples));
    }
  } catch (const volume::BuildCancelled&) {
    throw;
  } catch (const std::exception& e) {
    record.status = "failed";
    record.error = e.what();
  }
  record.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (record.status == "done" && record.seconds > 0) {
    record.mvoxelsPerSecond = static_cast<double>(item.voxels()) / record.seconds / 1e6;
  }
  return record;
}

namespace {

// One run of a plan's items: `jobs` threads, each feeding its own worker process item after
// item; the manifest writer and the summary they share.
class PlanRun {
 public:
  PlanRun(const fs::path& planPath, const Plan& plan, const RunOptions& options)
      : plan_(plan), options_(options), items_(selectedItems(planPath, plan, options)),
        before_(readManifest(planPath, plan)), writer_(manifestFolder(planPath), writerName()),
        workerArgv_{options.workerExecutable, "worker", "--memory-budget",
                    std::to_string(std::max<uint64_t>(1, options.resources.memoryBudgetBytes / kMiB)), "--parent",
                    std::to_string(::getpid()), "--threads", std::to_string(options.resources.threadsPerWorker)} {
    summary_.selected = static_cast<int64_t>(items_.size());
    summary_.manifest = writer_.path();
    for (int64_t i : items_) voxelsTotal_ += plan.items[static_cast<std::size_t>(i)].voxels();
  }

  RunSummary run() {
    const auto start = std::chrono::steady_clock::now();
    std::vector<std::thread> threads;
    const int jobs = std::max(1, std::min<int>(options_.resources.jobs, static_cast<int>(items_.size())));
    for (int t = 0; t < jobs; ++t) threads.emplace_back([this] { work(); });
    std::atomic<bool> allDone{false};
    std::thread watcher([&] { forwardCancel(allDone); });
    for (auto& t : threads) t.join();
    allDone = true;
    watcher.join();
    if (firstError_) std::rethrow_exception(firstError_);
    summary_.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::sort(summary_.failures.begin(), summary_.failures.end(),
              [](const Record& a, const Record& b) { return a.item < b.item; });
    return summary_;
  }

 private:
  static std::vector<int64_t> selectedItems(const fs::path& planPath, const Plan& plan, const RunOptions& options) {
    std::vector<int64_t> items = options.items;
    if (items.empty()) {
      for (const auto& it : plan.items) items.push_back(it.index);
    }
    for (int64_t i : items) {
      if (i < 0 || i >= static_cast<int64_t>(plan.items.size())) {
        throw Error(planPath.string(), fmt::format("item {} is not in the plan (0..{})", i, plan.items.size() - 1));
      }
    }
    return items;
  }

  bool cancelled() const { return options_.cancel && options_.cancel->load(); }

  // Records an item's outcome: the manifest, the summary, the callbacks.
  void finish(const Record& r, int64_t voxels, bool built) {
    std::lock_guard lock(mutex_);
    writer_.append(r);
    if (r.status == "failed") {
      ++summary_.failed;
      summary_.failures.push_back(r);
    } else if (built) {
      ++summary_.built;
      summary_.voxelsBuilt += voxels;
    } else {
      ++summary_.upToDate;
    }
    voxelsDone_ += voxels;
    if (options_.itemFinished) options_.itemFinished(r);
    if (options_.progress) options_.progress(voxelsDone_, voxelsTotal_);
  }

  static Record failure(const WorkItem& item, const std::string& error) {
    Record r;
    r.item = item.index;
    r.status = "failed";
    r.contentHash = item.contentHash;
    r.output = item.output;
    r.error = error;
    return r;
  }

  void countInterrupted() {
    std::lock_guard lock(mutex_);
    ++summary_.interrupted;
  }

  // True when the item's store is there and current: counted as up to date, and recorded when
  // a run that was killed built it without recording it.
  bool alreadyBuilt(const WorkItem& item) {
    if (!storeIsUpToDate(item)) return false;
    const auto known = before_.latest.find(item.index);
    if (known != before_.latest.end() && known->second.status == "done") {
      std::lock_guard lock(mutex_);
      ++summary_.upToDate;
      voxelsDone_ += item.voxels();
      if (options_.progress) options_.progress(voxelsDone_, voxelsTotal_);
      return true;
    }
    Record r;
    r.item = item.index;
    r.status = "done";
    r.contentHash = item.contentHash;
    r.output = item.output;
    std::error_code sizeError;
    r.bytes = fs::file_size(item.output, sizeError);
    r.note = "found complete";
    finish(r, item.voxels(), false);
    return true;
  }

  void startWorker(std::unique_ptr<WorkerProcess>& worker) {
    worker = std::make_unique<WorkerProcess>(workerArgv_);
    std::lock_guard lock(childrenMutex_);
    children_.insert(worker->pid());
    if (cancelled()) ::kill(worker->pid(), SIGTERM);
  }

  WorkerProcess::Exit dropWorker(std::unique_ptr<WorkerProcess>& worker) {
    {
      std::lock_guard lock(childrenMutex_);
      children_.erase(worker->pid());
    }
    const WorkerProcess::Exit exit = worker->reap();
    worker.reset();
    return exit;
  }

  // Builds one item on the thread's worker (started, or replaced after a crash, as needed).
  void build(std::unique_ptr<WorkerProcess>& worker, const WorkItem& item) {
    if (!worker) {
      try {
        startWorker(worker);
      } catch (const Error& e) {
        finish(failure(item, e.what()), item.voxels(), false);
        return;
      }
    }
    WorkerProcess::Outcome outcome = worker->build(dumpJson(toJson(item)));
    if (!outcome.record && outcome.notSent) {
      // The worker had died before this item reached it (not this item's fault): once more on
      // a fresh one.
      dropWorker(worker);
      startWorker(worker);
      outcome = worker->build(dumpJson(toJson(item)));
    }
    if (outcome.record) {
      finish(*outcome.record, item.voxels(), outcome.record->status == "done");
      return;
    }
    // The worker died (cancelled, or crashed on this item), or printed a record that does not
    // parse: it is replaced.
    if (outcome.broken) ::kill(worker->pid(), SIGKILL);
    const WorkerProcess::Exit exit = dropWorker(worker);
    if (cancelled()) {
      countInterrupted();
      return;
    }
    const std::string how = exit.signal != 0
                                ? fmt::format("killed by signal {} ({})", exit.signal, strsignal(exit.signal))
                                : fmt::format("exited with status {}", exit.code);
    std::string error =
        fmt::format("{}: the worker {} without a result", item.kind == "file" ? item.path : item.folder, how);
    const std::string last = tail(outcome.output, 5);
    if (!last.empty()) error += ": " + last;
    finish(failure(item, error), item.voxels(), false);
  }

  // One thread: one worker process kept for item after item (starting one loads every library
  // and its GDCM vetters: 0.3-0.5 s of CPU).
  void workLoop() {
    std::unique_ptr<WorkerProcess> worker;
    while (true) {
      const std::size_t k = next_.fetch_add(1);
      if (k >= items_.size() || abandon_.load()) break;
      const WorkItem& item = plan_.items[static_cast<std::size_t>(items_[k])];
      if (cancelled()) {
        countInterrupted();
      } else if (!alreadyBuilt(item)) {
        build(worker, item);
      }
    }
    if (worker) {
      worker->closeInput();
      dropWorker(worker);
    }
  }

  // What stops the whole run (the manifest cannot be written, ...) is thrown again after every
  // thread has stopped; the other threads stop starting items.
  void work() {
    try {
      workLoop();
    } catch (...) {
      std::lock_guard lock(mutex_);
      if (!firstError_) firstError_ = std::current_exception();
      abandon_ = true;
    }
  }

  // A cancelled run passes SIGTERM on to its workers (Ctrl-C reaches them anyway, through the
  // terminal's process group; `kill PID` and Slurm's scancel of this process do not).
  void forwardCancel(const std::atomic<bool>& allDone) {
    bool forwarded = false;
    while (!allDone.load()) {
      if (!forwarded && cancelled()) {
        std::lock_guard lock(childrenMutex_);
        for (pid_t pid : children_) ::kill(pid, SIGTERM);
        forwarded = true;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
  }

  const Plan& plan_;
  const RunOptions& options_;
  const std::vector<int64_t> items_;
  const ManifestState before_;
  ManifestWriter writer_;
  const std::vector<std::string> workerArgv_;
  std::mutex mutex_;  // writer_, summary_, voxelsDone_, firstError_, the callbacks
  RunSummary summary_;
  int64_t voxelsTotal_ = 0, voxelsDone_ = 0;
  std::atomic<std::size_t> next_{0};
  std::atomic<bool> abandon_{false};
  std::exception_ptr firstError_;
  std::mutex childrenMutex_;
  std::set<pid_t> children_;
};

}  // namespace

RunSummary runPlan(const fs::path& planPath, const Plan& plan, const RunOptions& options) {
  // A worker whose stdin closes early must not kill the run with SIGPIPE.
  std::signal(SIGPIPE, SIG_IGN);
  return PlanRun(planPath, plan, options).run();
}

}  // namespace octoray::batch
