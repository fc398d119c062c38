#include "octoray/batch/manifest.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <fstream>

#include <fmt/format.h>

#include "octoray/core/error.h"

namespace octoray::batch {

namespace fs = std::filesystem;
using nlohmann::json;

json Record::toJson() const {
  json j = {{"item", item}, {"status", status}, {"contentHash", contentHash}, {"output", output},
            {"seconds", seconds}, {"mvoxelsPerSecond", mvoxelsPerSecond}, {"bytes", bytes},
            {"peakRssMiB", peakRssMiB}, {"warnings", warnings}, {"worker", worker},
            {"finished", finished}};
  if (!error.empty()) j["error"] = error;
  if (!note.empty()) j["note"] = note;
  return j;
}

Record Record::fromJson(const json& j) {
  Record r;
  r.item = j.at("item").get<int64_t>();
  r.status = j.at("status").get<std::string>();
  r.contentHash = j.at("contentHash").get<std::string>();
  r.output = j.at("output").get<std::string>();
  r.seconds = j.value("seconds", 0.0);
  r.mvoxelsPerSecond = j.value("mvoxelsPerSecond", 0.0);
  r.bytes = j.value("bytes", uint64_t{0});
  r.peakRssMiB = j.value("peakRssMiB", 0.0);
  r.warnings = j.value("warnings", std::vector<std::string>{});
  r.error = j.value("error", "");
  r.note = j.value("note", "");
  r.worker = j.value("worker", "");
  r.finished = j.at("finished").get<std::string>();
  if (r.status != "done" && r.status != "failed") {
    throw json::other_error::create(501, "unknown status " + r.status, &j);
  }
  return r;
}

fs::path manifestFolder(const fs::path& planPath) {
  fs::path folder = planPath;
  if (folder.extension() == ".json") folder.replace_extension();
  folder += ".manifest";
  return folder;
}

std::string writerName() {
  char host[256] = {};
  ::gethostname(host, sizeof host - 1);
  auto env = [](const char* name) {
    const char* v = std::getenv(name);
    return std::string(v ? v : "");
  };
  // Unique per process even when Slurm runs several (srun -n), requeues a task, or a
  // container reuses PIDs: host and pid are always part of the name.
  std::string slurm;
  if (!env("SLURM_ARRAY_JOB_ID").empty() && !env("SLURM_ARRAY_TASK_ID").empty()) {
    slurm = fmt::format("slurm-{}_{}-", env("SLURM_ARRAY_JOB_ID"), env("SLURM_ARRAY_TASK_ID"));
  } else if (!env("SLURM_JOB_ID").empty()) {
    slurm = fmt::format("slurm-{}-", env("SLURM_JOB_ID"));
  }
  if (!slurm.empty() && !env("SLURM_RESTART_COUNT").empty()) slurm += "r" + env("SLURM_RESTART_COUNT") + "-";
  std::string name = (slurm.empty() ? "local-" : slurm) + fmt::format("{}-{}", host, ::getpid());
  for (char& c : name) {
    if (c == '/' || c == ' ') c = '_';
  }
  return name;
}

std::string isoTimeNow() {
  const auto now = std::chrono::system_clock::now();
  const auto ms = std::chrono::duration_cast<std::chrono::milliseconds>(now.time_since_epoch()).count() % 1000;
  const std::time_t t = std::chrono::system_clock::to_time_t(now);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char text[32];
  std::strftime(text, sizeof text, "%Y-%m-%dT%H:%M:%S", &tm);
  return fmt::format("{}.{:03}Z", text, ms);
}

ManifestWriter::ManifestWriter(const fs::path& folder, const std::string& name) : name_(name) {
  std::error_code ec;
  fs::create_directories(folder, ec);
  if (ec) throw Error(folder.string(), "cannot create the manifest folder: " + ec.message());
  path_ = folder / (name + ".jsonl");
  fd_ = ::open(path_.c_str(), O_RDWR | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
  if (fd_ < 0) throw Error(path_.string(), std::string("cannot open the manifest: ") + std::strerror(errno));
  // A line cut by a kill stays cut: the next record starts on a line of its own.
  const off_t size = ::lseek(fd_, 0, SEEK_END);
  char last = '\n';
  if (size > 0 && ::pread(fd_, &last, 1, size - 1) == 1 && last != '\n') {
    if (::write(fd_, "\n", 1) != 1) throw Error(path_.string(), "cannot append to the manifest");
  }
}

ManifestWriter::~ManifestWriter() {
  if (fd_ >= 0) ::close(fd_);
}

void ManifestWriter::append(Record record) {
  record.worker = name_;
  record.finished = isoTimeNow();
  const std::string line = dumpJson(record.toJson()) + "\n";
  // One write of the whole line: O_APPEND puts it at the end in one piece; a kill can only cut
  // the last line, which readers then ignore.
  const ssize_t n = ::write(fd_, line.data(), line.size());
  if (n != static_cast<ssize_t>(line.size()) || ::fdatasync(fd_) != 0) {
    throw Error(path_.string(), std::string("cannot append to the manifest: ") +
                                    (n < 0 ? std::strerror(errno) : "short write"));
  }
}

ManifestState readManifest(const fs::path& planPath, const Plan& plan) {
  ManifestState state;
  const fs::path folder = manifestFolder(planPath);
  std::error_code ec;
  if (!fs::is_directory(folder, ec)) return state;
  std::vector<fs::path> files;
  for (const auto& entry : fs::directory_iterator(folder, ec)) {
    if (entry.path().extension() == ".jsonl") files.push_back(entry.path());
  }
  std::sort(files.begin(), files.end());
  for (const auto& file : files) {
    ++state.files;
    std::ifstream in(file);
    std::string line;
    while (std::getline(in, line)) {
      if (line.empty()) continue;
      ++state.records;
      Record r;
      try {
        r = Record::fromJson(json::parse(line));
      } catch (const json::exception&) {
        ++state.tornLines;
        continue;
      }
      if (r.item < 0 || r.item >= static_cast<int64_t>(plan.items.size()) ||
          r.contentHash != plan.items[static_cast<std::size_t>(r.item)].contentHash ||
          r.output != plan.items[static_cast<std::size_t>(r.item)].output) {
        ++state.staleRecords;
        continue;
      }
      auto [it, inserted] = state.latest.try_emplace(r.item, r);
      if (!inserted && r.finished >= it->second.finished) it->second = r;
    }
  }
  return state;
}

}  // namespace octoray::batch
