// octoray-validate: checks an octree store file (every brick, border, filtered level and
// range) or a DICOM folder (skipped files, duplicates, missing slices, spacing, mixed series).
// Exit status: 0 when every check passes, 1 when any fails, 2 on usage errors.
#include <CLI/CLI.hpp>

#include <filesystem>
#include <nlohmann/json.hpp>

#include <fmt/format.h>

#include "cli_checks.h"
#include "cli_support.h"
#include "octoray/dicom/dicom_series.h"
#include "octoray/volume/store_reader.h"
#include "octoray/volume/store_validator.h"

namespace {

namespace fs = std::filesystem;
using octoray::volume::CheckResult;
using octoray::volume::ValidationReport;

// A folder, a DICOMDIR or a DICOM Part 10 file ("DICM" after the 128-byte preamble) is DICOM;
// anything else is validated as a store, so a damaged store is reported as one.
bool isDicomInput(const fs::path& path) {
  std::error_code ec;
  if (fs::is_directory(path, ec)) return true;
  if (octoray::volume::isStoreFile(path)) return false;
  std::string name = path.filename().string();
  std::transform(name.begin(), name.end(), name.begin(),
                 [](unsigned char c) { return std::toupper(c); });
  return name == "DICOMDIR" || octoray::dicom::isDicomPart10(path);
}

nlohmann::json toJson(const ValidationReport& report) {
  nlohmann::json checks = nlohmann::json::array();
  for (const CheckResult& c : report.checks) {
    nlohmann::json failures = nlohmann::json::array();
    for (const auto& f : c.failures) {
      nlohmann::json item = {{"message", f.message}};
      if (f.nodeId >= 0) item["node"] = f.nodeId;
      failures.push_back(std::move(item));
    }
    checks.push_back({{"name", c.name},
                      {"status", c.status == octoray::volume::CheckStatus::Passed   ? "pass"
                                 : c.status == octoray::volume::CheckStatus::Failed ? "fail"
                                                                                    : "not-run"},
                      {"checked", c.checked},
                      {"failed", c.failedCount},
                      {"failures", std::move(failures)},
                      {"notes", c.notes}});
  }
  nlohmann::json j = {{"path", report.path},
                      {"kind", report.kind},
                      {"passed", report.passed()},
                      {"checks", std::move(checks)}};
  if (report.kind == "dicom") {
    nlohmann::json series = nlohmann::json::array();
    for (const auto& s : report.series) {
      nlohmann::json item = {
          {"seriesUid", s.seriesUid},
          {"seriesNumber", s.seriesNumber},
          {"description", s.description},
          {"frames", s.frames},
          {"slices", s.slices},
          {"duplicates", s.duplicates},
          {"missingSlices", s.missingSlices},
          {"gapMm", {{"min", s.minGapMm}, {"median", s.medianGapMm}, {"max", s.maxGapMm}}},
          {"uniform", s.uniform},
          {"tiltDegrees", s.tiltDegrees}};
      if (!s.error.empty()) item["error"] = s.error;
      series.push_back(std::move(item));
    }
    j["series"] = std::move(series);
  }
  return j;
}

void printTable(const ValidationReport& report) {
  fmt::print("{} ({})\n", report.path, report.kind);
  for (const CheckResult& c : report.checks) {
    fmt::print("  {:<7} {:<17} {:>8} checked {:>6} failed\n", toString(c.status), c.name, c.checked,
               c.failedCount);
    for (const auto& f : c.failures) {
      if (f.nodeId >= 0) {
        fmt::print("          node {}: {}\n", f.nodeId, f.message);
      } else {
        fmt::print("          {}\n", f.message);
      }
    }
    if (c.failedCount > static_cast<int64_t>(c.failures.size())) {
      fmt::print("          ... and {} more\n",
                 c.failedCount - static_cast<int64_t>(c.failures.size()));
    }
    for (const auto& note : c.notes) fmt::print("          note: {}\n", note);
  }
  fmt::print("{}\n", report.passed() ? "all checks passed" : "VALIDATION FAILED");
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "Validates an octoray store file (header, geometry, brick checksums, ranges, "
      "borders, filtered levels, constant nodes) or a DICOM folder / DICOMDIR "
      "(skipped files, duplicates, missing slices, spacing, mixed series). Exit status "
      "0: all checks pass; 1: a check fails; 2: usage error."};
  app.footer(
      "Examples:\n"
      "  octoray-validate head.octoray          # every check of the store; exit 1 on a failure\n"
      "  octoray-validate /media/usb/DICOM --json > report.json\n");
  std::string path;
  bool json = false;
  uint64_t cacheMiB = 256;
  app.add_option("path", path, "store file, DICOM folder or DICOMDIR")->required();
  app.add_flag("--json", json, "print the report as JSON (docs/validate-json.md)");
  app.add_option("--cache-mib", cacheMiB, "decompressed bricks kept in memory (MiB)")
      ->capture_default_str()
      ->check(octoray::cli::kPositive);
  try {
    app.parse(argc, argv);
  } catch (const CLI::Success& e) {
    return app.exit(e);  // --help
  } catch (const CLI::ParseError& e) {
    fmt::print(stderr, "octoray-validate: {}\nRun with --help for more information.\n", e.what());
    return 2;
  }
  std::error_code ec;
  if (!fs::exists(path, ec)) {
    fmt::print(stderr, "octoray-validate: {}: no such file or folder\n", path);
    return 2;
  }

  return octoray::cli::runTool("octoray-validate", [&] {
    ValidationReport report;
    {
      octoray::cli::ProgressBar progress(isDicomInput(path) ? "scanning" : "validating");
      const auto onProgress = [&](int64_t done, int64_t total) {
        progress.update(static_cast<std::size_t>(done), static_cast<std::size_t>(total));
      };
      if (isDicomInput(path)) {
        report = octoray::volume::validateDicomFolder(path, onProgress);
      } else {
        octoray::volume::StoreValidationOptions options;
        options.cacheBudgetBytes = cacheMiB << 20;
        options.progress = onProgress;
        report = octoray::volume::validateStore(path, options);
      }
    }
    if (json) {
      fmt::print("{}\n", toJson(report).dump(2, ' ', false, nlohmann::json::error_handler_t::replace));
    } else {
      printTable(report);
    }
    return report.passed() ? 0 : 1;
  });
}
