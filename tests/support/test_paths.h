#pragma once
// Where tests find real data. ../shared sits beside the project root in CI and in
// developers' checkouts; users who clone the project alone do not have it, so tests that
// need it skip with a message (OCTORAY_REQUIRE_PATH) instead of failing.

#include <filesystem>
#include <string>

namespace octoray::test {

// ../shared (or $OCTORAY_SHARED when set).
std::filesystem::path sharedDir();
// ../shared/data/dicom/dcm_qa_ct/Philips
std::filesystem::path philipsDir();
// Debian python3-pydicom's test files folder.
std::filesystem::path pydicomTestFiles();
// A fresh, empty temporary folder unique to the running test (or, made in SetUpTestSuite, to
// the suite and the process), under the build tree's test-tmp/. Once
// removeTempDirsOfPassedRuns() is installed, removed at the end of the test program when
// every test in it passed; kept when one failed, and a failed test's own folders are named
// on stderr.
std::filesystem::path freshTempDir(const std::string& name);
// Installs the listener that removes a passed run's folders: every suite's main() does, so a
// full ctest run (one process per test) does not leave gigabytes of stores and archives
// behind (3.2 GB under ASan before 2026-12-06). OCTORAY_KEEP_TEST_TMP=1 keeps them all.
void removeTempDirsOfPassedRuns();
// The built tool `name` (e.g. "octoray-import") in the build tree's bin folder.
std::filesystem::path toolPath(const std::string& name);

}  // namespace octoray::test

// Skips the current test with a message when `path` does not exist.
#define OCTORAY_REQUIRE_PATH(path)                                                         \
  do {                                                                                     \
    if (!std::filesystem::exists(path)) {                                                  \
      GTEST_SKIP() << "skipped: " << (path).string()                                       \
                   << " is absent (real test data lives in ../shared beside the project)"; \
    }                                                                                      \
  } while (0)
