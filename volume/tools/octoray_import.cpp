// octoray-import: DICOM folders, DICOMDIRs and other volume files in, resolved volumes out.
//   --list PATH               the series table
//   --inspect PATH            resolved geometry, value range and every warning of one volume
//   --export OUT.nii[.gz] PATH  the resolved volume as NIfTI (shear kept in the sform)
//   --export OUT.vdb PATH       the resolved volume as a sparse OpenVDB grid (--vdb-threshold)
//   PATH -o OUT.octoray       the brick octree store (volume/)
// PATH may be a DICOMweb series URL (https://HOST/dicom-web/studies/S/series/R): the series is
// retrieved into the user cache folder first (pacs/, resumable; --credentials, --ca-file).
// --json output follows docs/import-json.md (schema version 1).

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <sys/resource.h>

#include <atomic>
#include <csignal>
#include <cmath>
#include <filesystem>
#include <iostream>
#include <limits>
#include <optional>
#include <vector>

#include <fmt/format.h>

#include "cli_checks.h"
#include "cli_support.h"
#include "octoray/dicom/dicom_series.h"
#include "octoray/dicom/dicom_volume.h"
#include "octoray/core/error.h"
#include "octoray/core/text.h"
#include "octoray/core/paths.h"
#include "octoray/dicom/formats.h"
#include "octoray/dicom/nifti_export.h"
#include "octoray/dicom/vdb.h"
#include "octoray/pacs/connection.h"
#include "octoray/pacs/dicomweb.h"
#include "octoray/volume/store_builder.h"
#include "octoray/volume/store_reader.h"

namespace {

using nlohmann::json;
using namespace octoray;

constexpr int kJsonSchemaVersion = 1;

struct Arguments {
  std::string path;
  bool list = false;
  bool inspect = false;
  std::string exportPath;
  std::optional<double> vdbThresholdHu;  // set only with --vdb-threshold
  std::string credentialsFile, caFile;    // a DICOMweb URL as PATH
  bool json = false;
  std::string series;
  double sliceSpacingMm = 0;
  std::string rawDims, rawType = "int16", rawSpacing, tiffSpacing;
  bool rawBigEndian = false;
  uint64_t rawHeaderBytes = 0;
  // Store build (-o)
  std::string storePath;
  int brickSize = 32;
  int border = 1;
  bool gradients = false;
  std::string codec = "lz4";
  std::string storeFormat = "auto";
  uint64_t memoryBudgetMiB = 1024;
};

// SIGINT/SIGTERM stop a build between slabs; the temporary file is removed, OUT untouched.
// The exit status is 128 + the signal's number, the shell's convention (130 for SIGINT, 143 for
// SIGTERM).
std::atomic<bool> gStop{false};
std::atomic<int> gStopSignal{0};
extern "C" void onStopSignal(int sig) {
  gStopSignal.store(sig);
  gStop.store(true);
}

double peakRssMiB() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return static_cast<double>(usage.ru_maxrss) / 1024.0;  // ru_maxrss is in KiB on Linux
}

OpenOptions openOptions(const Arguments& a) {
  OpenOptions o;
  o.series = a.series;
  o.stack.sliceSpacingMm = a.sliceSpacingMm;
  if (!a.rawDims.empty()) {
    o.raw = true;
    o.rawOptions.dims = cli::parseDims(a.rawDims, "--raw-dims");
    o.rawOptions.sampleType = parseSampleType(a.rawType);
    o.rawOptions.bigEndian = a.rawBigEndian;
    o.rawOptions.headerBytes = a.rawHeaderBytes;
    if (!a.rawSpacing.empty()) {
      const auto s = cli::parseTriple(a.rawSpacing, "--raw-spacing");
      o.rawOptions.spacingMm = {s[0], s[1], s[2]};
    }
  }
  if (!a.tiffSpacing.empty()) {
    const auto s = cli::parseTriple(a.tiffSpacing, "--tiff-spacing");
    o.tiffSpacingMm = {s[0], s[1], s[2]};
  }
  return o;
}

json seriesJson(const dicom::DicomSeries& s, std::size_t index, bool isDefault) {
  json j = {{"index", index},
            {"seriesUid", s.seriesUid},
            {"seriesNumber", s.seriesNumber},
            {"modality", s.modality},
            {"description", s.description},
            {"kind", dicom::toString(s.kind)},
            {"kindReason", s.kindReason},
            {"columns", s.columns},
            {"rows", s.rows},
            {"images", s.frames.size()},
            {"multiFrame", s.multiFrame},
            {"default", isDefault}};
  if (s.hasGeometry) j["pixelSpacingMm"] = {s.columnSpacingMm, s.rowSpacingMm};
  // A stack geometry means something only for series that form volumes.
  if (s.hasGeometry && (s.kind == dicom::SeriesKind::Volume || s.kind == dicom::SeriesKind::Derived)) {
    try {
      const dicom::StackGeometry g = dicom::resolveStack(s);
      j["slices"] = g.outputSlices;
      j["sliceSpacingMm"] = g.outputSpacingMm;
      j["tiltDegrees"] = g.tiltDegrees;
      j["uniformSpacing"] = g.uniform;
    } catch (const Error& e) {
      j["geometryError"] = e.what();
    }
  }
  return j;
}

json listJson(const std::string& path, const dicom::DicomScan& scan) {
  std::optional<std::size_t> chosen;
  try {
    chosen = dicom::defaultSeriesIndex(scan, path);
  } catch (const Error&) {
  }
  json j = {{"tool", "octoray-import"}, {"schemaVersion", kJsonSchemaVersion}, {"path", path},
            {"filesExamined", scan.filesExamined}};
  j["series"] = json::array();
  for (std::size_t i = 0; i < scan.series.size(); ++i) {
    j["series"].push_back(seriesJson(scan.series[i], i, chosen == i));
  }
  j["skipped"] = json::array();
  for (const auto& s : scan.skipped) j["skipped"].push_back({{"path", s.path}, {"reason", s.reason}});
  j["warnings"] = scan.warnings;
  return j;
}

void printList(const json& j) {
  fmt::print("{} files examined in {}\n\n", j["filesExamined"].get<std::size_t>(),
             j["path"].get<std::string>());
  fmt::print("{:>3} {:>6} {:<4} {:<18} {:>9} {:>6} {:>13} {:>8}  {}\n", "#", "series", "mod",
             "kind", "size", "images", "spacing mm", "tilt", "description");
  for (const auto& s : j["series"]) {
    std::string spacing = "-", tilt = "-";
    if (s.contains("pixelSpacingMm")) {
      spacing = fmt::format("{:.3f}", s["pixelSpacingMm"][0].get<double>());
      if (s.contains("sliceSpacingMm")) {
        spacing += fmt::format("/{:.2f}", s["sliceSpacingMm"].get<double>());
        tilt = fmt::format("{:.2f}", s["tiltDegrees"].get<double>());
      }
    }
    fmt::print("{:>3} {:>6} {:<4} {:<18} {:>9} {:>6} {:>13} {:>8}  {}{}\n",
               s["index"].get<std::size_t>(), s["seriesNumber"].get<int>(),
               s["modality"].get<std::string>(), s["kind"].get<std::string>(),
               fmt::format("{}x{}", s["columns"].get<int>(), s["rows"].get<int>()),
               s["images"].get<std::size_t>(), spacing, tilt, s["description"].get<std::string>(),
               s["default"].get<bool>() ? "  [default]" : "");
  }
  if (!j["skipped"].empty()) {
    fmt::print("\n{} file(s) skipped:\n", j["skipped"].size());
    for (const auto& s : j["skipped"]) {
      fmt::print("  {}: {}\n", s["path"].get<std::string>(), s["reason"].get<std::string>());
    }
  }
  for (const auto& w : j["warnings"]) fmt::print("warning: {}\n", w.get<std::string>());
}

bool isDicomInput(const std::string& path, const Arguments& a) {
  if (!a.rawDims.empty()) return false;
  namespace fs = std::filesystem;
  std::error_code ec;
  if (fs::is_directory(path, ec)) {
    for (const auto& e : fs::recursive_directory_iterator(path, ec)) {
      const auto ext = e.path().extension().string();
      if (ext == ".tif" || ext == ".tiff" || ext == ".TIF" || ext == ".TIFF") return false;
    }
    return true;
  }
  const std::string name = fs::path(path).filename().string();
  for (const char* ext :
       {".nrrd", ".nhdr", ".mhd", ".mha", ".nii", ".nii.gz", ".tif", ".tiff", ".vdb"}) {
    const std::string e = ext;
    if (name.size() >= e.size() && name.compare(name.size() - e.size(), e.size(), e) == 0) {
      return false;
    }
  }
  return true;
}

// Opens the volume named by the arguments; for DICOM also returns the scan for reporting.
std::unique_ptr<VolumeSource> openInput(const Arguments& a, std::optional<dicom::DicomScan>& scan,
                                        std::optional<std::size_t>& seriesIndex) {
  if (!isDicomInput(a.path, a)) return openVolume(a.path, openOptions(a));
  cli::ProgressBar bar("scanning");
  dicom::ScanOptions options;
  options.progress = [&](std::size_t done, std::size_t total) { bar.update(done, total); };
  scan = dicom::scanDicom(a.path, options);
  bar.finish();
  seriesIndex = a.series.empty() ? dicom::defaultSeriesIndex(*scan, a.path)
                                 : dicom::findSeries(*scan, a.series, a.path);
  dicom::StackOptions stack;
  stack.sliceSpacingMm = a.sliceSpacingMm;
  return dicom::openDicomSeries(scan->series[*seriesIndex], stack);
}

// The source's warnings and, for a DICOM series, every file of the scan left out of the volume
// (split off into another part, or unreadable), by name.
std::vector<std::string> allWarnings(const VolumeInfo& info, const std::optional<dicom::DicomScan>& scan,
                                     const std::optional<std::size_t>& index) {
  std::vector<std::string> warnings = info.warnings;
  if (scan && index) {
    for (auto& w : dicom::filesLeftOut(*scan, *index)) warnings.push_back(std::move(w));
  }
  return warnings;
}

json inspectJson(const Arguments& a) {
  std::optional<dicom::DicomScan> scan;
  std::optional<std::size_t> index;
  auto source = openInput(a, scan, index);
  const VolumeInfo& info = source->info();

  // The value range needs every sample: stream the volume slab by slab.
  constexpr int64_t kSlab = 8;
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  std::size_t nonFinite = 0;
  std::vector<float> slab;
  cli::ProgressBar bar("reading");
  for (int64_t z = 0; z < info.dims[2]; z += kSlab) {
    const int64_t count = std::min(kSlab, info.dims[2] - z);
    slab.resize(static_cast<std::size_t>(info.sliceSamples() * count));
    source->readSlab(z, count, slab);
    for (float v : slab) {
      if (!std::isfinite(v)) {
        ++nonFinite;
        continue;
      }
      lo = std::min(lo, static_cast<double>(v));
      hi = std::max(hi, static_cast<double>(v));
    }
    bar.update(static_cast<std::size_t>(z + count), static_cast<std::size_t>(info.dims[2]));
  }
  bar.finish();

  json j = {{"tool", "octoray-import"}, {"schemaVersion", kJsonSchemaVersion}, {"path", a.path},
            {"format", info.format}, {"modality", info.modality},
            {"description", info.description}, {"seriesUid", info.seriesUid},
            {"dimensions", info.dims}};
  const Vec3 spacing = info.spacingMm();
  j["spacingMm"] = {spacing.x, spacing.y, spacing.z};
  json affine = json::array();
  for (const auto& row : info.patientFromIndex.m) affine.push_back(row);
  j["patientFromIndex"] = affine;
  j["tiltDegrees"] = info.tiltDegrees;
  j["resampled"] = info.resampled;
  j["unit"] = info.unit;
  j["integerValues"] = info.integerValues;
  j["windows"] = json::array();
  for (const SourceWindow& w : info.windows) {
    j["windows"].push_back({{"center", w.center}, {"width", w.width}, {"explanation", w.explanation},
                            {"function", w.function}});
  }
  j["valueRange"] = std::isfinite(lo) ? json{{"min", lo}, {"max", hi}} : json(nullptr);
  j["nonFiniteSamples"] = nonFinite;
  j["warnings"] = allWarnings(info, scan, index);
  j["skipped"] = json::array();
  if (scan) {
    j["series"] = seriesJson(scan->series[*index], *index, true);
    for (const auto& w : scan->warnings) j["warnings"].push_back(w);
    for (const auto& s : scan->skipped) {
      j["skipped"].push_back({{"path", s.path}, {"reason", s.reason}});
    }
  }
  return j;
}

void printInspect(const json& j) {
  fmt::print("{} ({})\n", j["path"].get<std::string>(), j["format"].get<std::string>());
  if (j.contains("series")) {
    const auto& s = j["series"];
    fmt::print("series #{} {} \"{}\" {}\n", s["index"].get<std::size_t>(),
               s["modality"].get<std::string>(), s["description"].get<std::string>(),
               s["seriesUid"].get<std::string>());
  }
  const auto& d = j["dimensions"];
  const auto& sp = j["spacingMm"];
  fmt::print("dimensions   {} x {} x {}\n", d[0].get<int64_t>(), d[1].get<int64_t>(),
             d[2].get<int64_t>());
  fmt::print("spacing mm   {:.6g} x {:.6g} x {:.6g}\n", sp[0].get<double>(), sp[1].get<double>(),
             sp[2].get<double>());
  fmt::print("tilt         {:.3f} degrees{}\n", j["tiltDegrees"].get<double>(),
             j["resampled"].get<bool>() ? " (slices resampled to uniform spacing)" : "");
  fmt::print("patientFromIndex (LPS mm):\n");
  for (const auto& row : j["patientFromIndex"]) {
    fmt::print("  [{:12.6f} {:12.6f} {:12.6f} {:12.6f}]\n", row[0].get<double>(),
               row[1].get<double>(), row[2].get<double>(), row[3].get<double>());
  }
  if (!j["valueRange"].is_null()) {
    fmt::print("values       {} .. {} {}\n", j["valueRange"]["min"].get<double>(),
               j["valueRange"]["max"].get<double>(), j["unit"].get<std::string>());
  }
  if (const auto nonFinite = j["nonFiniteSamples"].get<int64_t>(); nonFinite > 0) {
    fmt::print("not finite   {} samples (NaN or infinite: a store cannot be built from them)\n",
               nonFinite);
  }
  for (const auto& w : j["windows"]) {
    fmt::print("window       W {} / L {}{}{}\n", w["width"].get<double>(), w["center"].get<double>(),
               w["explanation"].get<std::string>().empty() ? "" : " (" + w["explanation"].get<std::string>() + ")",
               w["function"].get<std::string>().empty() ? "" : ", " + w["function"].get<std::string>());
  }
  for (const auto& w : j["warnings"]) fmt::print("warning: {}\n", w.get<std::string>());
  for (const auto& s : j["skipped"]) {
    fmt::print("skipped: {}: {}\n", s["path"].get<std::string>(), s["reason"].get<std::string>());
  }
}

int buildStoreFile(const Arguments& a) {
  std::optional<dicom::DicomScan> scan;
  std::optional<std::size_t> index;
  auto source = openInput(a, scan, index);
  const VolumeInfo& info = source->info();

  volume::BuildOptions options;
  options.brickSize = a.brickSize;
  options.border = a.border;
  options.gradients = a.gradients;
  options.codec = a.codec == "zstd" ? volume::Codec::Zstd
                  : a.codec == "none" ? volume::Codec::None : volume::Codec::Lz4;
  options.format = a.storeFormat == "uint16"    ? volume::BuildOptions::Format::UInt16
                   : a.storeFormat == "float32" ? volume::BuildOptions::Format::Float32
                                                : volume::BuildOptions::Format::Auto;
  options.memoryBudgetBytes = a.memoryBudgetMiB << 20;
  if (!info.sourceFiles.empty()) options.sourceContentHash = sourceContentHash(info.sourceFiles);
  options.cancel = &gStop;
  cli::ProgressBar bar("building");
  options.progress = [&](int64_t done, int64_t total) {
    bar.update(static_cast<std::size_t>(done), static_cast<std::size_t>(total));
  };
  std::signal(SIGINT, onStopSignal);
  std::signal(SIGTERM, onStopSignal);
  volume::BuildReport report;
  try {
    report = volume::buildStore(*source, a.storePath, options);
  } catch (const volume::BuildCancelled&) {
    bar.finish();
    fmt::print(stderr, "octoray-import: interrupted; {} was not written\n", a.storePath);
    return 128 + (gStopSignal.load() != 0 ? gStopSignal.load() : SIGINT);
  }
  bar.finish();
  const double mvoxPerS = report.seconds > 0 ? report.voxels / report.seconds / 1e6 : 0;
  const double emptyFraction = report.nodes ? double(report.constantNodes) / double(report.nodes) : 0;
  if (a.json) {
    json j = {{"tool", "octoray-import"}, {"schemaVersion", kJsonSchemaVersion}, {"path", a.path},
              {"output", a.storePath}, {"dimensions", info.dims}, {"voxels", report.voxels},
              {"bricks", report.nodes}, {"levels", report.levels},
              {"constantBricks", report.constantNodes}, {"emptyFraction", emptyFraction},
              {"bytesOnDisk", report.bytesOnDisk}, {"uncompressedBytes", report.uncompressedBytes},
              {"seconds", report.seconds}, {"mvoxelsPerSecond", mvoxPerS},
              {"peakRssMiB", peakRssMiB()}, {"clampedSamples", report.clampedSamples},
              {"sampleFormat", report.sampleFormat == volume::SampleFormat::UInt16 ? "uint16" : "float32"},
              {"warnings", allWarnings(info, scan, index)}};
    std::cout << j.dump(2, ' ', false, json::error_handler_t::replace) << "\n";
  } else {
    fmt::print("wrote {}: {} x {} x {} voxels, {} bricks in {} levels ({:.1f}% constant), "
               "{:.1f} MiB on disk\n", a.storePath, info.dims[0], info.dims[1], info.dims[2],
               report.nodes, report.levels, 100 * emptyFraction, report.bytesOnDisk / 1048576.0);
    fmt::print("{:.2f} s, {:.1f} Mvoxels/s, peak RSS {:.0f} MiB\n", report.seconds, mvoxPerS,
               peakRssMiB());
    if (report.clampedSamples > 0) {
      fmt::print("warning: {} samples outside the 16-bit range were clamped\n", report.clampedSamples);
    }
    for (const auto& w : allWarnings(info, scan, index)) fmt::print("warning: {}\n", w);
  }
  return 0;
}

enum class ExportFormat { Nifti, Vdb };

// The export format from OUT's extension; a threshold without a .vdb output is a mistake.
ExportFormat exportFormat(const Arguments& a) {
  const std::string name = octoray::asciiLower(std::filesystem::path(a.exportPath).filename().string());
  const bool vdb = name.ends_with(".vdb");
  if (!vdb && !name.ends_with(".nii") && !name.ends_with(".nii.gz")) {
    throw Error(a.exportPath, "unknown export format: name the output .nii, .nii.gz or .vdb");
  }
  if (!vdb && a.vdbThresholdHu) {
    throw Error(a.exportPath, "--vdb-threshold applies only to a .vdb export");
  }
  return vdb ? ExportFormat::Vdb : ExportFormat::Nifti;
}

int exportVolume(const Arguments& a) {
  const ExportFormat format = exportFormat(a);
  std::optional<dicom::DicomScan> scan;
  std::optional<std::size_t> index;
  auto source = openInput(a, scan, index);
  cli::ProgressBar bar("exporting");
  auto progress = [&](int64_t done, int64_t total) {
    bar.update(static_cast<std::size_t>(done), static_cast<std::size_t>(total));
  };
  std::optional<VdbExportReport> vdb;
  VdbExportOptions vdbOptions;
  if (format == ExportFormat::Vdb) {
    vdbOptions.thresholdHu = a.vdbThresholdHu.value_or(vdbOptions.thresholdHu);
    vdbOptions.progress = progress;
    vdb = exportVdb(*source, a.exportPath, vdbOptions);
  } else {
    NiftiExportOptions options;
    options.progress = progress;
    exportNifti(*source, a.exportPath, options);
  }
  bar.finish();
  const VolumeInfo& info = source->info();
  if (a.json) {
    json j = {{"tool", "octoray-import"}, {"schemaVersion", kJsonSchemaVersion},
              {"path", a.path}, {"output", a.exportPath}, {"dimensions", info.dims},
              {"warnings", allWarnings(info, scan, index)}};
    if (vdb) {
      j["vdbThreshold"] = vdbOptions.thresholdHu;
      j["activeVoxels"] = vdb->activeVoxels;
      j["bytesOnDisk"] = vdb->bytesOnDisk;
    }
    j["peakRssMiB"] = peakRssMiB();
    std::cout << j.dump(2, ' ', false, json::error_handler_t::replace) << "\n";
  } else {
    fmt::print("wrote {} ({} x {} x {})\n", a.exportPath, info.dims[0], info.dims[1], info.dims[2]);
    if (vdb) {
      fmt::print("{} active voxels ({:.1f}%) at or above {} {}, {:.1f} MiB on disk\n",
                 vdb->activeVoxels, 100.0 * double(vdb->activeVoxels) / double(info.sampleCount()),
                 vdbOptions.thresholdHu, info.unit, double(vdb->bytesOnDisk) / 1048576.0);
    }
    for (const auto& w : allWarnings(info, scan, index)) fmt::print("warning: {}\n", w);
  }
  return 0;
}

// A DICOMweb series URL as PATH: the series is retrieved (resuming) into the user cache
// folder first, and PATH becomes that folder. The JSON and messages keep the URL.
void retrieveUrlInput(Arguments& a) {
  if (!pacs::isHttpUrl(a.path)) return;
  pacs::PacsOptions options;
  std::string warning;
  options.credentials = pacs::resolveCredentials(a.credentialsFile, &warning);
  if (!warning.empty()) fmt::print(stderr, "octoray-import: warning: {}\n", warning);
  options.caFile = a.caFile;
  cli::ProgressBar bar("retrieving");
  const std::filesystem::path folder = pacs::retrieveSeriesUrl(
      a.path, options, userCacheDir(),
      [&](int64_t done, int64_t total) { bar.update(static_cast<std::size_t>(done), static_cast<std::size_t>(total)); });
  bar.finish();
  a.path = folder.string();
}

int run(Arguments a) {
  retrieveUrlInput(a);
  if (volume::isStoreFile(a.path)) {
    volume::StoreReader{a.path};  // a damaged store (or not one, named so) says what is wrong
    throw Error(a.path, "is an octoray store already: octoray-view and octoray-render open it, "
                        "octoray-validate checks it");
  }
  if (a.list) {
    cli::ProgressBar bar("scanning");
    dicom::ScanOptions options;
    options.progress = [&](std::size_t done, std::size_t total) { bar.update(done, total); };
    const dicom::DicomScan scan = dicom::scanDicom(a.path, options);
    bar.finish();
    const json j = listJson(a.path, scan);
    if (a.json) {
      std::cout << j.dump(2, ' ', false, json::error_handler_t::replace) << "\n";
    } else {
      printList(j);
    }
    if (scan.series.empty()) {
      // The table (stdout) may be all a script reads; the person at the terminal gets why.
      fmt::print(stderr,
                 "octoray-import: {}: no DICOM image series found ({} files examined, {} left "
                 "out): --list lists DICOM series, --inspect reads every format\n",
                 a.path, scan.filesExamined, scan.skipped.size());
      return 1;
    }
    return 0;
  }
  if (a.inspect) {
    const json j = inspectJson(a);
    if (a.json) {
      std::cout << j.dump(2, ' ', false, json::error_handler_t::replace) << "\n";
    } else {
      printInspect(j);
    }
    return 0;
  }
  if (!a.storePath.empty()) return buildStoreFile(a);
  return exportVolume(a);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"octoray-import: read CT series and volume files into octoray"};
  Arguments a;
  auto* list = app.add_flag("--list", a.list, "Print the table of image series found under PATH");
  auto* inspect = app.add_flag("--inspect", a.inspect,
                               "Print the resolved geometry, value range and warnings");
  auto* exportOpt = app.add_option("--export", a.exportPath,
                                   "Write the resolved volume as NIfTI (.nii or .nii.gz) or as a "
                                   "sparse OpenVDB grid (.vdb)");
  auto* storeOpt = app.add_option("-o,--output", a.storePath,
                                  "Build the brick octree store OUT from PATH");
  list->excludes(inspect)->excludes(exportOpt)->excludes(storeOpt);
  inspect->excludes(exportOpt)->excludes(storeOpt);
  exportOpt->excludes(storeOpt);
  app.add_option("--brick-size", a.brickSize, "Store: samples per brick edge")
      ->check(CLI::IsMember({16, 32, 64}));
  app.add_option("--border", a.border, "Store: replicated border samples (2 for gradients)")
      ->check(CLI::IsMember({1, 2}));
  app.add_flag("--gradients", a.gradients, "Store: precompute 8-bit gradients");
  app.add_option("--codec", a.codec, "Store: payload compression")
      ->check(CLI::IsMember({"lz4", "zstd", "none"}));
  app.add_option("--store-format", a.storeFormat, "Store: sample format")
      ->check(CLI::IsMember({"auto", "uint16", "float32"}));
  app.add_option("--vdb-threshold", a.vdbThresholdHu,
                 "VDB export: samples >= HU are active voxels, the rest air (-1000); "
                 "default -900")
      ->needs(exportOpt);
  app.add_option("--memory-budget", a.memoryBudgetMiB, "Store: build memory budget in MiB")
      ->check(CLI::Range(64, 1 << 20));
  app.add_option("path", a.path, "DICOM folder, DICOMDIR, DICOM file, DICOMweb series URL, or a .nrrd/.nhdr/.mhd/"
                                 ".mha/.nii/.nii.gz/.tif/.vdb file or TIFF folder")
      ->required();
  app.add_flag("--json", a.json, "Machine-readable output (docs/import-json.md)");
  app.add_option("--series", a.series, "Series table index or SeriesInstanceUID");
  app.add_option("--slice-spacing", a.sliceSpacingMm,
                 "Output slice spacing in mm where slices must be resampled (default: smallest gap)")
      ->check(octoray::cli::kPositive);
  app.add_option("--raw-dims", a.rawDims, "Raw volume: dimensions XxYxZ");
  app.add_option("--raw-type", a.rawType, "Raw volume: sample type (uint8 int16 float32 ...)");
  app.add_flag("--raw-big-endian", a.rawBigEndian, "Raw volume: big-endian samples");
  app.add_option("--raw-spacing", a.rawSpacing, "Raw volume: spacing in mm, x,y,z");
  app.add_option("--raw-header-bytes", a.rawHeaderBytes, "Raw volume: bytes before the data")
      ->check(octoray::cli::kNonNegative);
  app.add_option("--tiff-spacing", a.tiffSpacing, "TIFF stack: spacing in mm, x,y,z");
  app.add_option("--credentials", a.credentialsFile,
                 "PATH a DICOMweb URL: file holding \"basic USER:PASSWORD\" or \"bearer TOKEN\" "
                 "(default: $OCTORAY_PACS_CREDENTIALS)");
  app.add_option("--ca-file", a.caFile, "PATH an https DICOMweb URL: PEM of a private CA to trust");
  app.footer(
      "Examples:\n"
      "  octoray-import --list scans/                         # the series found under scans/\n"
      "  octoray-import --export head.nii.gz scans/ --series 2  # series 2 of the table, NIfTI\n"
      "  octoray-import --export head.vdb --vdb-threshold -500 scans/  # >= -500 HU, OpenVDB\n"
      "  octoray-import scans/ -o head.octoray                # the store octoray-view reads\n"
      "  octoray-import https://pacs/dicom-web/studies/1.2.3/series/1.2.4 -o ct.octoray \\\n"
      "      --credentials ~/.octoray-pacs                    # retrieved into the cache first\n");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // --help exits 0; every command-line mistake exits 2 (docs/import-json.md).
    return app.exit(e) == 0 ? 0 : 2;
  }
  if (!a.list && !a.inspect && a.exportPath.empty() && a.storePath.empty()) {
    std::cerr << "octoray-import: choose one of --list, --inspect, --export OUT or -o OUT\n"
              << app.help();
    return 2;
  }
  if (!a.exportPath.empty()) {
    try {
      exportFormat(a);
    } catch (const Error& e) {
      std::cerr << "octoray-import: " << e.what() << "\n";
      return 2;
    }
  }
  return cli::runTool("octoray-import", [&] { return run(a); });
}
