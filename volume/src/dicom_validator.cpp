// Validation of a DICOM folder: what was skipped, and for every volumetric series whether its
// slices form a clean regular stack (no duplicates, no gaps, even spacing, one part per UID).
#include <algorithm>
#include <map>

#include <fmt/format.h>

#include "octoray/dicom/dicom_series.h"
#include "octoray/dicom/dicom_volume.h"
#include "octoray/core/error.h"
#include "octoray/volume/store_validator.h"

namespace octoray::volume {
namespace {

constexpr std::size_t kMaxFailures = 20;

CheckResult makeCheck(std::string name) {
  CheckResult r;
  r.name = std::move(name);
  return r;
}

void addFailure(CheckResult& r, std::string message) {
  ++r.failedCount;
  r.status = CheckStatus::Failed;
  if (r.failures.size() < kMaxFailures) r.failures.push_back({-1, std::move(message)});
}

std::string seriesName(const dicom::DicomSeries& s) {
  return fmt::format("series {} '{}' ({})", s.seriesNumber, s.description, s.seriesUid);
}

// Files skipped while scanning: DICOMDIR files are expected there; anything else is a file
// that should have been an image and could not be read. DICOMDIR entries that name missing
// files, or a DICOMDIR that does not parse, fail too.
CheckResult checkFiles(const dicom::DicomScan& scan) {
  CheckResult r = makeCheck("dicom-files");
  r.checked = static_cast<int64_t>(scan.filesExamined);
  int64_t directories = 0;
  for (const dicom::SkippedFile& f : scan.skipped) {
    if (f.reason.find("DICOMDIR") != std::string::npos) {
      ++directories;
      continue;
    }
    addFailure(r, fmt::format("{}: skipped: {}", f.path, f.reason));
  }
  for (const std::string& w : scan.warnings) addFailure(r, w);
  if (directories > 0)
    r.notes.push_back(fmt::format("{} DICOMDIR file(s), not images", directories));
  return r;
}

}  // namespace

ValidationReport validateDicomFolder(const std::string& path, const ValidationProgress& progress) {
  ValidationReport report;
  report.path = path;
  report.kind = "dicom";
  dicom::DicomScan scan;
  try {
    dicom::ScanOptions options;
    if (progress) {
      options.progress = [&](std::size_t done, std::size_t total) {
        progress(static_cast<int64_t>(done), static_cast<int64_t>(total));
      };
    }
    scan = dicom::scanDicom(path, options);
  } catch (const std::exception& e) {
    CheckResult files = makeCheck("dicom-files");
    addFailure(files, e.what());
    report.checks.push_back(std::move(files));
    for (const char* name :
         {"dicom-duplicates", "dicom-missing", "dicom-spacing", "dicom-series"}) {
      CheckResult r = makeCheck(name);
      r.status = CheckStatus::NotRun;
      r.notes.push_back("the path cannot be scanned");
      report.checks.push_back(std::move(r));
    }
    return report;
  }

  CheckResult duplicates = makeCheck("dicom-duplicates"), missing = makeCheck("dicom-missing"),
              spacing = makeCheck("dicom-spacing"), series = makeCheck("dicom-series");
  // A UID split into parts matters only when a part is a volume: screenshots of different
  // sizes under one UID are ordinary.
  std::map<std::string, int> partsPerUid;
  std::map<std::string, bool> uidHasVolume;
  for (const dicom::DicomSeries& s : scan.series) {
    ++partsPerUid[s.seriesUid];
    uidHasVolume[s.seriesUid] = uidHasVolume[s.seriesUid] || s.kind == dicom::SeriesKind::Volume;
  }
  bool anyVolume = false;
  for (const dicom::DicomSeries& s : scan.series) {
    ++series.checked;
    if (partsPerUid[s.seriesUid] > 1 && uidHasVolume[s.seriesUid]) {
      addFailure(series, fmt::format("{}: one UID split into {} parts; this part has {} "
                                     "frame(s): {}",
                                     seriesName(s), partsPerUid[s.seriesUid], s.frames.size(),
                                     s.kindReason));
    }
    if (s.kind != dicom::SeriesKind::Volume) {
      series.notes.push_back(fmt::format("{}: {} ({} frame(s)): {}", seriesName(s),
                                         dicom::toString(s.kind), s.frames.size(), s.kindReason));
      continue;
    }
    anyVolume = true;
    SeriesSummary summary;
    summary.seriesUid = s.seriesUid;
    summary.seriesNumber = s.seriesNumber;
    summary.description = s.description;
    summary.frames = static_cast<int64_t>(s.frames.size());
    ++duplicates.checked;
    ++missing.checked;
    ++spacing.checked;
    try {
      const dicom::StackGeometry g = dicom::resolveStack(s);
      summary.slices = static_cast<int64_t>(g.slices.size());
      summary.duplicates = static_cast<int64_t>(g.duplicates.size());
      summary.missingSlices = g.missingSlices;
      summary.minGapMm = g.minGapMm;
      summary.maxGapMm = g.maxGapMm;
      summary.medianGapMm = g.medianGapMm;
      summary.uniform = g.uniform;
      summary.tiltDegrees = g.tiltDegrees;
      if (!g.duplicates.empty()) {
        addFailure(duplicates,
                   fmt::format("{}: {} frame(s) share another's slice position, e.g. {}",
                               seriesName(s), g.duplicates.size(), g.duplicates.front().path));
      }
      if (g.missingSlices > 0) {
        addFailure(missing, fmt::format("{}: {} slice(s) missing (gaps up to {:.3f} mm, usual "
                                        "{:.3f} mm)",
                                        seriesName(s), g.missingSlices, g.maxGapMm, g.medianGapMm));
      }
      if (!g.uniform) {
        addFailure(spacing, fmt::format("{}: slice gaps vary from {:.3f} to {:.3f} mm (median "
                                        "{:.3f}): the volume is resampled",
                                        seriesName(s), g.minGapMm, g.maxGapMm, g.medianGapMm));
      }
      spacing.notes.push_back(fmt::format(
          "{}: {} slices, gap min {:.3f} / median {:.3f} / max "
          "{:.3f} mm, tilt {:.2f} degrees",
          seriesName(s), g.slices.size(), g.minGapMm, g.medianGapMm, g.maxGapMm, g.tiltDegrees));
    } catch (const std::exception& e) {
      summary.error = e.what();
      addFailure(series, fmt::format("{}: cannot form a volume: {}", seriesName(s), e.what()));
    }
    report.series.push_back(std::move(summary));
  }
  if (!anyVolume) addFailure(series, "no volumetric series found");

  report.checks.push_back(checkFiles(scan));
  for (CheckResult* r : {&duplicates, &missing, &spacing, &series}) {
    report.checks.push_back(std::move(*r));
  }
  return report;
}

}  // namespace octoray::volume
