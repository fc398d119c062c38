#include "test_paths.h"

#include <gtest/gtest.h>

#include <unistd.h>

#include <cstdlib>

namespace octoray::test {

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
  return dir;
}

std::filesystem::path toolPath(const std::string& name) {
  return std::filesystem::path(OCTORAY_BINARY_DIR) / "bin" / name;
}

}  // namespace octoray::test
