#pragma once
// What every octoray command-line tool shares: the error policy at main (one clear message,
// non-zero exit, never a crash) and a progress bar drawn only when a person is watching.

#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <tbb/global_control.h>

namespace octoray::cli {

// Runs `body`, turning octoray::Error and any other exception into "<tool>: <message>" on
// stderr and exit status 1. Returns body's exit status otherwise.
int runTool(const char* toolName, const std::function<int()>& body);

// Waits, when it goes out of scope, for TBB's worker threads to end. Left to themselves they are
// torn down by TBB's static destructors while LeakSanitizer's exit-time check is stopping every
// thread. runTool holds one; a main() that does not use runTool (the viewer's,
// the tests') holds its own. The other library threads every program has, log4cplus's pool
// that OpenVDB brings, are joined by an exit handler of cli_support.cpp.
class WorkerThreadsJoinedAtExit {
 public:
  WorkerThreadsJoinedAtExit();
  ~WorkerThreadsJoinedAtExit();
  WorkerThreadsJoinedAtExit(const WorkerThreadsJoinedAtExit&) = delete;
  WorkerThreadsJoinedAtExit& operator=(const WorkerThreadsJoinedAtExit&) = delete;

 private:
  tbb::task_scheduler_handle scheduler_;
};

// The value of `text` when all of it is one finite number ("2.5", "1e-3"); nullopt for empty
// text, trailing characters ("2mm"), inf and nan. Options' checks (cli_checks.h) and the
// parsers below share it.
std::optional<double> parseFiniteNumber(const std::string& text);

// "512x512x140": three positive integers separated by 'x'. Throws octoray::Error naming
// `option` otherwise.
std::array<int64_t, 3> parseDims(const std::string& text, const char* option);
// "0.5,0.5,1.25": three positive finite numbers separated by ','.
std::array<double, 3> parseTriple(const std::string& text, const char* option);
// "512x384": an image's width and height, whole numbers from minWidth and minHeight up to
// `largest`. Throws octoray::Error naming `option` otherwise (numbers too large for an int
// included: they do not wrap).
std::array<int, 2> parseImageSize(const std::string& text, const char* option, int minWidth,
                                  int minHeight, int largest);

// The timing loops' median: of the frames after the first (which uploads data and compiles
// shaders), or of the only frame; and the words that say which. NaN for no frames.
double medianOfSteadyFrames(const std::vector<double>& framesMs);
const char* steadyFramesDescription(std::size_t frames);

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
