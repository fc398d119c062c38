#pragma once
// What every octoray command-line tool shares: the error policy at main (one clear message,
// non-zero exit, never a crash) and a progress bar drawn only when a person is watching.

#include <chrono>
#include <cstddef>
#include <functional>
#include <string>

namespace octoray::cli {

// Runs `body`, turning octoray::Error and any other exception into "<tool>: <message>" on
// stderr and exit status 1. Returns body's exit status otherwise.
int runTool(const char* toolName, const std::function<int()>& body);

// A one-line progress bar with rate and ETA on stderr, active only when stdout and stderr are
// terminals (scripts and tests see clean output).
class ProgressBar {
 public:
  explicit ProgressBar(std::string label);
  ~ProgressBar();
  void update(std::size_t done, std::size_t total);
  void finish();

 private:
  std::string label_;
  bool active_;
  bool finished_ = false;
  std::chrono::steady_clock::time_point start_;
  std::chrono::steady_clock::time_point lastDraw_;
};

}  // namespace octoray::cli
