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

// The folders freshTempDir made for the running test, and for its suite's set-up
// (SetUpTestSuite: no test is running yet).
struct MadeFolders {
  std::mutex mutex;
  std::vector<std::filesystem::path> test;
  std::vector<std::filesystem::path> suite;
};

MadeFolders& madeFolders() {
  static MadeFolders folders;
  return folders;
}

// Removes `folders` when `passed`; otherwise keeps them and names them, so a failure's
// output can be read. Either way the list is emptied for the next test or suite.
void settle(std::vector<std::filesystem::path>& folders, bool passed) {
  std::vector<std::filesystem::path> taken;
  {
    std::lock_guard lock(madeFolders().mutex);
    taken.swap(folders);
  }
  for (const auto& folder : taken) {
    if (!passed) {
      std::cerr << "kept for inspection: " << folder.string() << "\n";
      continue;
    }
    std::error_code ignored;  // a folder the test removed itself is not an error
    std::filesystem::remove_all(folder, ignored);
  }
}

// gtest calls OnTestEnd after the test object (and every server or file it held) is gone,
// and OnTestSuiteEnd after TearDownTestSuite.
class RemoveFoldersOfPassedTests : public ::testing::EmptyTestEventListener {
  void OnTestEnd(const ::testing::TestInfo& info) override {
    settle(madeFolders().test, !info.result()->Failed());
  }
  void OnTestSuiteEnd(const ::testing::TestSuite& suite) override {
    settle(madeFolders().suite, !suite.Failed());
  }
};

}  // namespace

void removeTempDirsOfPassedTests() {
  if (const char* keep = std::getenv("OCTORAY_KEEP_TEST_TMP"); keep && *keep) return;
  ::testing::UnitTest::GetInstance()->listeners().Append(new RemoveFoldersOfPassedTests);
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
  (info ? madeFolders().test : madeFolders().suite).push_back(dir);
  return dir;
}

std::filesystem::path toolPath(const std::string& name) {
  return std::filesystem::path(OCTORAY_BINARY_DIR) / "bin" / name;
}

}  // namespace octoray::test
