#pragma once
// What tests/dicom/unit_bad_input.cpp and unit_bad_input_dicom_parsing.cpp share: every call
// runs under a deadline and must end in one octoray::Error, with nothing else on stderr; and the
// DICOM helpers (an element rewritten with GDCM, a scan that skips exactly one file, hand-made
// little-endian data sets).

#include <gdcmReader.h>
#include <gdcmWriter.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <future>
#include <string>
#include <thread>
#include <vector>

#include <fmt/format.h>
#include <fmt/ranges.h>

#include "octoray/core/error.h"
#include "octoray/dicom/dicom_series.h"

namespace octoray::bad_input_test {

using namespace std::chrono_literals;

inline constexpr auto kDeadline = 5s;

// Runs `call` on its own thread and returns the message of the octoray::Error it throws
// ("" when it returns normally). Past the deadline the call is taken to hang: the thread
// cannot be stopped (and may be eating memory), so the failure is reported and the suite ends.
template <typename F>
inline std::string errorOf(F&& call, const std::string& what, std::chrono::seconds deadline = kDeadline) {
  std::packaged_task<std::string()> task([call = std::forward<F>(call)]() mutable {
    try {
      call();
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string();
  });
  auto result = task.get_future();
  std::thread(std::move(task)).detach();
  if (result.wait_for(deadline) != std::future_status::ready) {
    // On stdout: stderr may be captured by the caller at this point.
    std::printf("FAILED: %s did not finish within %lld s (hang regressed)\n", what.c_str(),
                static_cast<long long>(deadline.count()));
    std::fflush(stdout);
    std::_Exit(1);
  }
  return result.get();
}

// Expects `call` to throw an octoray::Error mentioning every one of `mentions`, in time, and
// to print nothing itself (libraries' own reports, object dumps) on stderr.
template <typename F>
inline void expectCleanError(F&& call, const std::vector<std::string>& mentions, const std::string& what) {
  testing::internal::CaptureStderr();
  const std::string message = errorOf(std::forward<F>(call), what);
  const std::string printed = testing::internal::GetCapturedStderr();
  ASSERT_FALSE(message.empty()) << what << ": no octoray::Error thrown";
  for (const auto& mention : mentions) {
    EXPECT_NE(message.find(mention), std::string::npos)
        << what << ": '" << message << "' does not mention '" << mention << "'";
  }
  EXPECT_EQ(printed, "") << what << ": printed on stderr besides the error";
}

// Sets one element of a DICOM file to a string value (padded to even length).
inline void rewriteElement(const std::filesystem::path& path, const gdcm::Tag& tag, const gdcm::VR& vr,
                    std::string text) {
  gdcm::Reader reader;
  reader.SetFileName(path.c_str());
  ASSERT_TRUE(reader.Read()) << path;
  gdcm::DataElement element(tag);
  element.SetVR(vr);
  if (text.size() % 2) text += ' ';
  element.SetByteValue(text.data(), static_cast<uint32_t>(text.size()));
  reader.GetFile().GetDataSet().Replace(element);
  gdcm::Writer writer;
  writer.SetFileName(path.c_str());
  writer.SetFile(reader.GetFile());
  ASSERT_TRUE(writer.Write()) << path;
}

// Scans `dir` and checks that the scan ends without an error, skips exactly `damaged`, by name,
// with a reason that contains `reasonPart`, and keeps the rest as one series of `framesLeft`
// frames. Callers wrap it in ASSERT_NO_FATAL_FAILURE when they go on to use `*scanOut`.
inline void expectOnlySkipped(const std::filesystem::path& dir, const std::filesystem::path& damaged, const std::string& reasonPart,
                       std::size_t framesLeft, dicom::DicomScan* scanOut = nullptr) {
  dicom::DicomScan scan;
  EXPECT_EQ(errorOf([&] { scan = dicom::scanDicom(dir); }, "scanDicom"), "");
  ASSERT_EQ(scan.skipped.size(), 1u);
  EXPECT_EQ(scan.skipped[0].path, damaged.string());
  EXPECT_NE(scan.skipped[0].reason.find(reasonPart), std::string::npos) << scan.skipped[0].reason;
  ASSERT_EQ(scan.series.size(), 1u);
  EXPECT_EQ(scan.series[0].frames.size(), framesLeft);
  if (scanOut) *scanOut = std::move(scan);
}

// Little-endian bytes of a 16- and a 32-bit value, and of a tag, for hand-made data sets.
inline std::string le16(uint16_t v) { return std::string{char(v & 0xff), char(v >> 8)}; }
inline std::string le32(uint32_t v) { return le16(uint16_t(v & 0xffff)) + le16(uint16_t(v >> 16)); }
inline std::string tag(uint16_t group, uint16_t element) { return le16(group) + le16(element); }

// Scans the DICOMDIR in `media` and checks that its records are given up with a warning naming
// `reason` ("DICOMDIR could not be parsed: ..."), and that the folder search then finds its one
// image, IMG1.
inline void expectDicomdirSearchedInstead(const std::filesystem::path& media, const std::string& reason) {
  dicom::DicomScan scan;
  EXPECT_EQ(errorOf([&] { scan = dicom::scanDicom(media / "DICOMDIR"); }, "scanDicom"), "");
  const auto& warnings = scan.warnings;
  const bool named = std::any_of(warnings.begin(), warnings.end(), [&](const std::string& w) {
    return w.find("DICOMDIR could not be parsed") != std::string::npos &&
           w.find(reason) != std::string::npos;
  });
  EXPECT_TRUE(named) << fmt::format("{}", fmt::join(warnings, "\n"));
  ASSERT_EQ(scan.series.size(), 1u);  // IMG1, found by the search
  ASSERT_EQ(scan.series[0].frames.size(), 1u);
  EXPECT_EQ(scan.series[0].frames[0].path, (media / "IMG1").string());
}

// Scans `dir` and checks that no file is skipped and that it holds one series of `frames` frames.
inline void expectNothingSkipped(const std::filesystem::path& dir, std::size_t frames) {
  dicom::DicomScan scan;
  EXPECT_EQ(errorOf([&] { scan = dicom::scanDicom(dir); }, "scanDicom"), "");
  for (const auto& skipped : scan.skipped) {
    ADD_FAILURE() << skipped.path << ": " << skipped.reason;
  }
  ASSERT_EQ(scan.series.size(), 1u);
  EXPECT_EQ(scan.series[0].frames.size(), frames);
}

}  // namespace octoray::bad_input_test
