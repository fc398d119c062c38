#include "octoray/core/paths.h"

#include <cstdlib>

namespace octoray {

std::filesystem::path userCacheDir() {
  namespace fs = std::filesystem;
  if (const char* env = std::getenv("OCTORAY_CACHE"); env && *env) return env;
  if (const char* xdg = std::getenv("XDG_CACHE_HOME"); xdg && *xdg) return fs::path(xdg) / "octoray";
  if (const char* home = std::getenv("HOME"); home && *home) return fs::path(home) / ".cache" / "octoray";
  return fs::temp_directory_path() / "octoray-cache";
}

}  // namespace octoray
