#pragma once
// Small helpers the application's files share.
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>

namespace octoray::viewer {

inline double secondsSince(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

// $OCTORAY_CONFIG, else $XDG_CONFIG_HOME/octoray, else ~/.config/octoray (the recent-files list).
inline std::filesystem::path configDir() {
  if (const char* env = std::getenv("OCTORAY_CONFIG"); env && *env) return env;
  if (const char* xdg = std::getenv("XDG_CONFIG_HOME"); xdg && *xdg) return std::filesystem::path(xdg) / "octoray";
  if (const char* home = std::getenv("HOME"); home && *home) return std::filesystem::path(home) / ".config" / "octoray";
  return std::filesystem::temp_directory_path() / "octoray-config";
}

inline double residentMib() {
  std::ifstream in("/proc/self/statm");
  long pages = 0, resident = 0;
  in >> pages >> resident;
  return static_cast<double>(resident) * 4096.0 / (1024.0 * 1024.0);
}

}  // namespace octoray::viewer
