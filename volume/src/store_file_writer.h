#pragma once
// Writes a file under a temporary name in the destination folder and renames it into place
// only when commit() is called; destruction without commit() removes the temporary file.
// Stale temporaries left by killed processes (whose PID no longer exists) are removed on start.

#include <cstdint>
#include <span>
#include <string>

namespace octoray::volume::detail {

class AtomicFileWriter {
 public:
  explicit AtomicFileWriter(const std::string& finalPath);
  ~AtomicFileWriter();
  AtomicFileWriter(const AtomicFileWriter&) = delete;
  AtomicFileWriter& operator=(const AtomicFileWriter&) = delete;

  // Appends bytes at the end; returns the offset they were written at.
  uint64_t append(std::span<const uint8_t> bytes);
  void writeAt(uint64_t offset, std::span<const uint8_t> bytes);
  uint64_t size() const { return size_; }
  const std::string& tempPath() const { return tempPath_; }
  // Flushes to disk and renames over the final path.
  void commit();

 private:
  std::string finalPath_;
  std::string tempPath_;
  int fd_ = -1;
  uint64_t size_ = 0;
  bool committed_ = false;
};

}  // namespace octoray::volume::detail
