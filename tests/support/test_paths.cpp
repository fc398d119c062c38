#include "test_paths.h"

#include <gtest/gtest.h>

#include <unistd.h>

#include <cstdlib>
#include <iostream>
#include <mutex>
#include <system_error>
#include <vector>

namespace octoray::test {

namespace {

// The folders freshTempDir made in this process, and how many of them the running test made
// (from `testFirst` on).
struct MadeFolders {
  std::mutex mutex;
  std::vector<std::filesystem::path> all;
  std::size_t testFirst = 0;
};

MadeFolders& madeFolders() {
  static MadeFolders folders;
  return folders;
}

// Removes the process's folders at its end when every test passed. A test binary run whole
// (the ThreadSanitizer stage, a developer) shares a store one test builds with the tests after
// it (a function-local static), so no folder goes before the last test; under ctest each
// process runs one test. When a test fails, the folders it made are named at once and every
// folder is kept, since the failed test may have read another's.
class RemoveFoldersOfPassedRuns : public ::testing::EmptyTestEventListener {
  void OnTestStart(const ::testing::TestInfo&) override {
    std::lock_guard lock(madeFolders().mutex);
    madeFolders().testFirst = madeFolders().all.size();
  }
  void OnTestEnd(const ::testing::TestInfo& info) override {
    if (!info.result()->Failed()) return;
    std::lock_guard lock(madeFolders().mutex);
    const auto& all = madeFolders().all;
    for (std::size_t i = madeFolders().testFirst; i < all.size(); ++i) {
      std::cerr << "kept for inspection: " << all[i].string() << "\n";
    }
  }
  void OnTestProgramEnd(const ::testing::UnitTest& unit) override {
    std::lock_guard lock(madeFolders().mutex);
    auto& all = madeFolders().all;
    if (!unit.Passed()) {
      if (!all.empty()) {
        std::cerr << "kept the " << all.size() << " temporary folder(s) of this run under "
                  << "test-tmp/\n";
      }
      return;
    }
    for (const auto& folder : all) {
      std::error_code ignored;  // a folder a test removed itself is not an error
      std::filesystem::remove_all(folder, ignored);
    }
    all.clear();
  }
};

}  // namespace

void removeTempDirsOfPassedRuns() {
  if (const char* keep = std::getenv("OCTORAY_KEEP_TEST_TMP"); keep && *keep) return;
  ::testing::UnitTest::GetInstance()->listeners().Append(new RemoveFoldersOfPassedRuns);
}

std::filesystem::path sharedDir() {
  if (const char* env = std::getenv("OCTORAY_SHARED"); env && *env) return env;
  return OCTORAY_SHARED_DIR;
}

std::filesystem::path philipsDir() { return sharedDir() / "data/dicom/dcm_qa_ct/Philips"; }

std::filesystem::path pydicomTestFiles() {
  return "/usr/lib/python3/dist-packages/pydicom/data/test_files";
}

std::filesystem::path freshTempDir(const std::string& name) {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  std::string unique = name;
  if (info) {
    unique = std::string(info->test_suite_name()) + "." + info->name() + "." + name;
  } else {
    // Suite-level set-up: ctest runs every test of a suite in its own process, concurrently.
    unique = name + "." + std::to_string(::getpid());
  }
  auto dir = std::filesystem::path(OCTORAY_BINARY_DIR) / "test-tmp" / unique;
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  std::lock_guard lock(madeFolders().mutex);
  madeFolders().all.push_back(dir);
  return dir;
}

std::filesystem::path toolPath(const std::string& name) {
  return std::filesystem::path(OCTORAY_BINARY_DIR) / "bin" / name;
}

}  // namespace octoray::test
