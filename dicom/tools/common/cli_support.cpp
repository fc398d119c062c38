#include "cli_support.h"

#include <unistd.h>

#include <algorithm>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <limits>
#include <new>
#include <system_error>
#include <thread>
#include <vector>

#include <fmt/format.h>
#include <log4cplus/config.hxx>

#include "octoray/core/error.h"

namespace octoray::cli {

namespace {

int runBody(const char* toolName, const std::function<int()>& body) {
  try {
    return body();
  } catch (const Error& e) {
    fmt::print(stderr, "{}: {}\n", toolName, e.what());
  } catch (const std::bad_alloc&) {
    fmt::print(stderr, "{}: out of memory\n", toolName);
  } catch (const std::exception& e) {
    fmt::print(stderr, "{}: {}\n", toolName, e.what());
  }
  return 1;
}

}  // namespace

int runTool(const char* toolName, const std::function<int()>& body) {
  WorkerThreadsJoinedAtExit joined;
  return runBody(toolName, body);
}

WorkerThreadsJoinedAtExit::WorkerThreadsJoinedAtExit()
    : scheduler_(tbb::attach{}) {}

WorkerThreadsJoinedAtExit::~WorkerThreadsJoinedAtExit() {
  // Fails (and returns false) only when another handle or a running parallel algorithm still
  // holds the scheduler; exit then tears the threads down as before.
  (void)tbb::finalize(scheduler_, std::nothrow);
}

namespace {

// The threads of this process other than the calling one, by kernel thread id.
std::vector<long> otherThreads() {
  std::vector<long> ids;
  std::error_code error;
  for (const auto& entry : std::filesystem::directory_iterator("/proc/self/task", error)) {
    const long id = std::strtol(entry.path().filename().c_str(), nullptr, 10);
    if (id > 0 && id != static_cast<long>(gettid())) ids.push_back(id);
  }
  return ids;
}

// log4cplus (OpenVDB's logging library) starts a pool of four threads when it loads, before
// main, so they exist in every program linked to OpenVDB, one that only printed --help
// included, and they are the only threads here while this file's statics are built. The exit
// handler registered then runs before the handlers registered earlier: the static destructors
// of log4cplus itself, which would otherwise tear the pool down, and LeakSanitizer's exit-time
// check, registered when the sanitizer started. deinitialize() stops the pool and closes
// log4cplus's appenders (nothing of ours logs through it; OpenVDB logs only while it reads or
// writes a file), but the pool's workers detach themselves on their way out, so the handler
// then waits for those threads to be gone: a few microseconds, bounded at a quarter of a
// second should a thread started before main be another library's that does not end.
const std::vector<long> threadsBeforeMain = otherThreads();

void joinLog4cplusPool() {
  log4cplus::deinitialize();
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(250);
  for (const long id : threadsBeforeMain) {
    const std::filesystem::path task = fmt::format("/proc/self/task/{}", id);
    std::error_code error;
    while (std::filesystem::exists(task, error) && std::chrono::steady_clock::now() < deadline) {
      std::this_thread::sleep_for(std::chrono::microseconds(200));
    }
  }
}

[[maybe_unused]] const int log4cplusPoolJoinedAtExit = std::atexit(joinLog4cplusPool);

}  // namespace

std::optional<double> parseFiniteNumber(const std::string& text) {
  char* stop = nullptr;
  const double value = std::strtod(text.c_str(), &stop);
  if (text.empty() || stop != text.c_str() + text.size() || !std::isfinite(value)) {
    return std::nullopt;
  }
  return value;
}

namespace {

std::array<double, 3> parseThree(const std::string& text, char separator, const char* option) {
  std::array<double, 3> values{};
  std::size_t begin = 0;
  for (std::size_t n = 0; n < 3; ++n) {
    const std::size_t end = text.find(separator, begin);
    if ((n < 2) == (end == std::string::npos)) {
      throw Error("", fmt::format("{} \"{}\": expected three values separated by '{}'", option,
                                  text, separator));
    }
    const std::string part = text.substr(begin, end == std::string::npos ? end : end - begin);
    const std::optional<double> v = parseFiniteNumber(part);
    if (!v || *v <= 0) {
      throw Error("", fmt::format("{} \"{}\": \"{}\" is not a positive number", option, text,
                                  part));
    }
    values[n] = *v;
    begin = end + 1;
  }
  return values;
}

}  // namespace

std::array<int64_t, 3> parseDims(const std::string& text, const char* option) {
  const std::array<double, 3> v = parseThree(text, 'x', option);
  std::array<int64_t, 3> dims{};
  for (std::size_t a = 0; a < 3; ++a) {
    if (v[a] != std::floor(v[a]) || v[a] > 9.0e15) {
      throw Error("", fmt::format("{} \"{}\": sizes must be whole numbers", option, text));
    }
    dims[a] = static_cast<int64_t>(v[a]);
  }
  return dims;
}

std::array<double, 3> parseTriple(const std::string& text, const char* option) {
  return parseThree(text, ',', option);
}

std::array<int, 2> parseImageSize(const std::string& text, const char* option, int minWidth,
                                  int minHeight, int largest) {
  const std::size_t x = text.find('x');
  std::array<int, 2> size{};
  const std::array<std::string, 2> parts = {text.substr(0, x),
                                            x == std::string::npos ? "" : text.substr(x + 1)};
  const std::array<int, 2> least = {minWidth, minHeight};
  for (std::size_t n = 0; n < 2; ++n) {
    const char* first = parts[n].data();
    const char* last = first + parts[n].size();
    const auto [stop, error] = std::from_chars(first, last, size[n]);
    if (parts[n].empty() || error != std::errc() || stop != last || size[n] < least[n] ||
        size[n] > largest) {
      throw Error("", fmt::format("{} \"{}\": expected WxH, from {}x{} to {}x{}", option, text,
                                  minWidth, minHeight, largest, largest));
    }
  }
  return size;
}

ProgressBar::ProgressBar(std::string label)
    : label_(std::move(label)),
      active_(isatty(STDOUT_FILENO) && isatty(STDERR_FILENO)),
      start_(std::chrono::steady_clock::now()),
      lastDraw_(start_) {}

double medianOfSteadyFrames(const std::vector<double>& framesMs) {
  if (framesMs.empty()) return std::numeric_limits<double>::quiet_NaN();
  std::vector<double> v(framesMs.size() > 1 ? framesMs.begin() + 1 : framesMs.begin(), framesMs.end());
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 == 1 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

const char* steadyFramesDescription(std::size_t frames) {
  return frames > 1 ? "frames after the first" : "the only frame";
}

ProgressBar::~ProgressBar() { finish(); }

void ProgressBar::update(std::size_t done, std::size_t total) {
  if (!active_ || finished_ || total == 0) return;
  const auto now = std::chrono::steady_clock::now();
  if (done < total && now - lastDraw_ < std::chrono::milliseconds(100)) return;
  lastDraw_ = now;
  const double seconds = std::chrono::duration<double>(now - start_).count();
  const double fraction = static_cast<double>(done) / static_cast<double>(total);
  constexpr int kWidth = 30;
  const int filled = static_cast<int>(fraction * kWidth);
  const double rate = seconds > 0 ? static_cast<double>(done) / seconds : 0;
  const double eta = rate > 0 ? static_cast<double>(total - done) / rate : 0;
  fmt::print(stderr, "\r{} [{:=<{}}{: <{}}] {}/{} {:.0f}/s ETA {:.0f}s ", label_, "", filled, "",
             kWidth - filled, done, total, rate, eta);
  std::fflush(stderr);
}

void ProgressBar::finish() {
  if (!active_ || finished_) return;
  finished_ = true;
  fmt::print(stderr, "\r\033[K");
  std::fflush(stderr);
}

}  // namespace octoray::cli
