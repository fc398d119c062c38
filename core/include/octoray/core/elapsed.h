#pragma once
// Time elapsed since a moment of the steady clock, in milliseconds: how the modules and tools
// report durations.

#include <chrono>

namespace octoray {

inline double millisecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace octoray
