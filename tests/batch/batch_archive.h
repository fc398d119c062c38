#pragma once
// The test archive of tests/batch: every series of ../shared's Philips set (with its DICOMDIR,
// localisers and secondary captures), synthetic series of two made-up patients (one tilted with
// uneven gaps and a localiser), a NIfTI file, and a folder of broken files. What the tests
// expect of it is spelled out here, next to how it is made.

#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace octoray::test {

struct BatchArchive {
  std::filesystem::path root;
  // Volumetric series and volume files: what gets a store.
  static constexpr int kItems = 8;
  // Patient names and IDs present in the files, none of which may reach a plan, a manifest,
  // a script or an output path.
  std::vector<std::string> identifiers = {"DOE^JANE", "DOE", "JANE", "ROE^RICHARD", "RICHARD",
                                          "PAT-A-001", "PAT-B-002", "PLASTIC", "HEAD"};
};

// Writes the archive into `root` with the built tools (octoray-sample-series, octoray-import).
BatchArchive makeBatchArchive(const std::filesystem::path& root);

// Runs a built octoray tool, returning (exit status, stdout); stderr is appended to `err`.
struct ToolRun {
  int exitCode = -1;
  std::string out, err;
  nlohmann::json json() const;  // stdout parsed (test fails on bad JSON)
};
ToolRun runTool(const std::string& tool, const std::vector<std::string>& args);

std::string readText(const std::filesystem::path& path);

}  // namespace octoray::test
