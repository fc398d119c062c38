#include "store_file_writer.h"

#include <fcntl.h>
#include <signal.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>

#include <fmt/format.h>

#include "octoray/core/error.h"

namespace octoray::volume::detail {
namespace fs = std::filesystem;
namespace {

// ".NAME.partial-HOST-": the host, so that on a filesystem shared by a cluster's nodes a build
// only ever judges its own machine's temporaries (a PID means nothing on another host).
std::string tempPrefix(const fs::path& finalPath) {
  char host[256] = {};
  ::gethostname(host, sizeof host - 1);
  std::string name = host;
  for (char& c : name) {
    if (c == '/' || c == '-') c = '_';
  }
  return "." + finalPath.filename().string() + ".partial-" + name + "-";
}

void removeStaleTemporaries(const fs::path& finalPath) {
  std::error_code ec;
  const fs::path dir = finalPath.parent_path().empty() ? fs::path(".") : finalPath.parent_path();
  const std::string prefix = tempPrefix(finalPath);
  for (const auto& entry : fs::directory_iterator(dir, ec)) {
    const std::string name = entry.path().filename().string();
    if (name.rfind(prefix, 0) != 0) continue;
    const std::string pidText = name.substr(prefix.size());
    char* end = nullptr;
    const long pid = std::strtol(pidText.c_str(), &end, 10);
    if (end == pidText.c_str() || *end != '\0' || pid <= 0) continue;
    if (::kill(static_cast<pid_t>(pid), 0) != 0 && errno == ESRCH) fs::remove(entry.path(), ec);
  }
}

}  // namespace

AtomicFileWriter::AtomicFileWriter(const std::string& finalPath) : finalPath_(finalPath) {
  const fs::path target(finalPath);
  removeStaleTemporaries(target);
  tempPath_ = (target.parent_path() / (tempPrefix(target) + std::to_string(::getpid()))).string();
  fd_ = ::open(tempPath_.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd_ < 0) {
    throw Error(finalPath, fmt::format("cannot create {}: {}", tempPath_, std::strerror(errno)));
  }
}

AtomicFileWriter::~AtomicFileWriter() {
  if (fd_ >= 0) ::close(fd_);
  if (!committed_) ::unlink(tempPath_.c_str());
}

void AtomicFileWriter::writeAt(uint64_t offset, std::span<const uint8_t> bytes) {
  const uint8_t* p = bytes.data();
  std::size_t left = bytes.size();
  while (left > 0) {
    const ssize_t n = ::pwrite(fd_, p, left, static_cast<off_t>(offset));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) throw Error(finalPath_, std::string("write failed: ") + std::strerror(errno));
    p += n;
    left -= static_cast<std::size_t>(n);
    offset += static_cast<uint64_t>(n);
  }
}

uint64_t AtomicFileWriter::append(std::span<const uint8_t> bytes) {
  const uint64_t at = size_;
  writeAt(at, bytes);
  size_ += bytes.size();
  return at;
}

void AtomicFileWriter::commit() {
  if (::fsync(fd_) != 0) throw Error(finalPath_, std::string("fsync failed: ") + std::strerror(errno));
  ::close(fd_);
  fd_ = -1;
  if (::rename(tempPath_.c_str(), finalPath_.c_str()) != 0) {
    throw Error(finalPath_, std::string("rename failed: ") + std::strerror(errno));
  }
  committed_ = true;
  // Make the rename itself durable.
  const fs::path dir = fs::path(finalPath_).parent_path();
  const int dirFd = ::open(dir.empty() ? "." : dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dirFd >= 0) {
    ::fsync(dirFd);
    ::close(dirFd);
  }
}

}  // namespace octoray::volume::detail
