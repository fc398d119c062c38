#pragma once
// Validation of an octree store file and of a DICOM folder, as a list of named checks.
//
// Store checks, in order: header (opens: magic, version, checksums of header, node table and
// provenance, file size), geometry (dims, affine, spacing, brick layout), checksums (every
// brick reads and decompresses), ranges (node [min,max] bounds its samples and children),
// borders (replicated samples equal the samples they copy), filter (inner nodes are exactly
// the builder's 2x box filter of their children) and constants (constant nodes have
// min == max). The store is streamed node by node through a small brick cache: memory is
// bounded by the cache budget, not by the store size.
//
// DICOM checks: dicom-files, dicom-duplicates, dicom-missing, dicom-spacing, dicom-series.

#include <cstdint>
#include <functional>
#include <string>
#include <string_view>
#include <vector>

namespace octoray::volume {

enum class CheckStatus { Passed, Failed, NotRun };
const char* toString(CheckStatus status);

struct CheckFailure {
  int64_t nodeId = -1;  // the node concerned, or -1 when the failure is not about one node
  std::string message;
};

struct CheckResult {
  std::string name;
  CheckStatus status = CheckStatus::Passed;
  int64_t checked = 0;                 // items examined (nodes, files or series)
  int64_t failedCount = 0;             // items that failed; `failures` holds the first few
  std::vector<CheckFailure> failures;  // lowest node ids first for store checks
  std::vector<std::string> notes;      // facts worth showing that are not failures

  bool passed() const { return status == CheckStatus::Passed; }
};

// What validateDicomFolder found about one volumetric series.
struct SeriesSummary {
  std::string seriesUid;
  int seriesNumber = 0;
  std::string description;
  int64_t frames = 0;
  int64_t slices = 0;  // unique positions after duplicates are dropped
  int64_t duplicates = 0;
  int missingSlices = 0;
  double minGapMm = 0, maxGapMm = 0, medianGapMm = 0;
  bool uniform = true;
  double tiltDegrees = 0;
  std::string error;  // why the frames cannot form a volume; empty when they can
};

struct ValidationReport {
  std::string path;
  std::string kind;  // "store" or "dicom"
  std::vector<CheckResult> checks;
  std::vector<SeriesSummary> series;  // DICOM only

  // True when every check ran and passed.
  bool passed() const;
  // The check called `name`, or nullptr.
  const CheckResult* find(std::string_view name) const;
};

// Called with (items done, items total) as validation advances, from any thread but never
// from two at once.
using ValidationProgress = std::function<void(int64_t done, int64_t total)>;

struct StoreValidationOptions {
  uint64_t cacheBudgetBytes = uint64_t{256} << 20;  // decompressed bricks kept for reuse
  int maxFailuresPerCheck = 8;                      // failures kept in each CheckResult
  ValidationProgress progress;
};

// Validates the store at `path`. Never throws for a bad file: every problem, including a
// file that does not open, is a failed check in the report.
ValidationReport validateStore(const std::string& path, const StoreValidationOptions& options = {});

// Scans `path` (a folder, a DICOMDIR or one DICOM file) and checks every volumetric series.
// Never throws for bad input: an unreadable path fails `dicom-files`.
ValidationReport validateDicomFolder(const std::string& path,
                                     const ValidationProgress& progress = {});

}  // namespace octoray::volume
