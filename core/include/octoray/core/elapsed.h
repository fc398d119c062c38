#pragma once
// Wall-clock time since a moment, as every tool and module reports it (milliseconds).

#include <chrono>

namespace octoray {

inline double millisecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace octoray
