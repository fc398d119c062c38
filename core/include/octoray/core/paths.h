#pragma once
// Where octoray keeps what it can rebuild: imported stores (the viewer) and series retrieved
// from a PACS (octoray-pacs, octoray-import URL, the viewer's PACS panel).

#include <filesystem>

namespace octoray {

// $OCTORAY_CACHE, else $XDG_CACHE_HOME/octoray, else ~/.cache/octoray, else a folder in the
// system's temporary directory.
std::filesystem::path userCacheDir();

}  // namespace octoray
