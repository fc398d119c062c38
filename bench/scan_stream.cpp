// scan-stream: ingest throughput of a DICOM folder. Times, N times each, (1) the baseline of
// reading every file's bytes with std::ifstream, (2) scanDicom on the folder, and (3) opening
// the default series and streaming it through readSlab in slabs of S slices; prints medians
// and the ratios to the baseline, and the peak resident memory while streaming. Files are in
// the page cache after the first baseline run, so every phase measures warm-cache work.

#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "cli_checks.h"
#include "octoray/dicom/dicom_series.h"
#include "octoray/dicom/dicom_volume.h"
#include "octoray/core/error.h"

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

namespace {

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

// Seconds of each of `repeats` runs of `work`.
std::vector<double> timeRuns(int repeats, const std::function<void()>& work) {
  std::vector<double> seconds;
  for (int r = 0; r < repeats; ++r) {
    const auto start = Clock::now();
    work();
    seconds.push_back(std::chrono::duration<double>(Clock::now() - start).count());
  }
  return seconds;
}

// A "VmXXX:  1234 kB" line of /proc/self/status, in KiB (0 where unavailable).
int64_t procStatusKiB(const std::string& key) {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind(key + ":", 0) == 0) return std::stoll(line.substr(key.size() + 1));
  }
  return 0;
}

// Resets VmHWM to the current RSS (Linux >= 4.0), so the next peak is this phase's own.
bool resetPeakRss() {
  std::ofstream clear("/proc/self/clear_refs");
  clear << "5";
  return static_cast<bool>(clear);
}

int64_t maxRssKiB() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss;  // KiB on Linux
}

uint64_t readAllBytes(const std::vector<fs::path>& files, std::vector<char>& buffer) {
  uint64_t total = 0;
  for (const fs::path& f : files) {
    std::ifstream in(f, std::ios::binary);
    while (in.read(buffer.data(), static_cast<std::streamsize>(buffer.size())) || in.gcount()) {
      total += static_cast<uint64_t>(in.gcount());
    }
  }
  return total;
}

int run(const std::string& folder, int repeats, int64_t slabSlices, bool json) {
  std::vector<fs::path> files;
  uint64_t folderBytes = 0;
  for (const auto& entry : fs::recursive_directory_iterator(folder)) {
    if (!entry.is_regular_file()) continue;
    files.push_back(entry.path());
    folderBytes += entry.file_size();
  }
  if (files.empty()) throw octoray::Error(folder, "no files to scan");

  // Baseline: the bytes of every file through std::ifstream, 1 MiB at a time.
  std::vector<char> buffer(1 << 20);
  uint64_t bytesRead = 0;
  const auto baseline = timeRuns(repeats, [&] { bytesRead = readAllBytes(files, buffer); });

  octoray::dicom::DicomScan scan;
  const auto scanning = timeRuns(repeats, [&] { scan = octoray::dicom::scanDicom(folder); });
  if (!scan.skipped.empty() && scan.series.empty()) {
    std::cerr << "first skipped file: " << scan.skipped.front().path << ": "
              << scan.skipped.front().reason << "\n";
  }
  const std::size_t seriesIndex = octoray::dicom::defaultSeriesIndex(scan, folder);
  const octoray::dicom::DicomSeries& series = scan.series[seriesIndex];
  uint64_t seriesBytes = 0;
  for (const auto& frame : series.frames) seriesBytes += fs::file_size(frame.path);

  // Streaming: open (resolve the stack) and read every slab; one slab buffer is reused.
  const int64_t rssBeforeKiB = procStatusKiB("VmRSS");
  const bool peakReset = resetPeakRss();
  octoray::VolumeInfo info;
  std::vector<float> slab;
  double checksum = 0;  // keeps the reads observable
  const auto streaming = timeRuns(repeats, [&] {
    auto source = octoray::dicom::openDicomSeries(series);
    info = source->info();
    slab.resize(static_cast<std::size_t>(slabSlices * info.sliceSamples()));
    for (int64_t k = 0; k < info.dims[2]; k += slabSlices) {
      const int64_t count = std::min(slabSlices, info.dims[2] - k);
      source->readSlab(k, count,
                       std::span<float>(slab.data(), static_cast<std::size_t>(count *
                                                                              info.sliceSamples())));
      checksum += slab[0];
    }
  });
  const int64_t hwmKiB = procStatusKiB("VmHWM");
  const int64_t maxRss = maxRssKiB();

  const double mb = 1e6;
  const double tBase = median(baseline), tScan = median(scanning), tStream = median(streaming);
  const double slices = static_cast<double>(info.dims[2]);
  const double pixelBytes = 2.0 * static_cast<double>(info.sampleCount());
  nlohmann::json out = {
      {"folder", folder},
      {"repeats", repeats},
      {"files", files.size()},
      {"folder_bytes", folderBytes},
      {"baseline_ifstream", {{"median_s", tBase},
                             {"files_per_s", files.size() / tBase},
                             {"mb_per_s", bytesRead / mb / tBase}}},
      {"scan", {{"median_s", tScan},
                {"files_per_s", scan.filesExamined / tScan},
                {"file_mb_per_s", folderBytes / mb / tScan},
                {"time_vs_baseline", tScan / tBase}}},
      {"stream", {{"series", series.description},
                  {"dims", info.dims},
                  {"slab_slices", slabSlices},
                  {"median_s", tStream},
                  {"slices_per_s", slices / tStream},
                  {"pixel_mb_per_s", pixelBytes / mb / tStream},
                  {"file_mb_per_s", seriesBytes / mb / tStream},
                  {"time_vs_baseline_of_series_bytes",
                   tStream / (tBase * static_cast<double>(seriesBytes) / folderBytes)},
                  {"rss_before_kib", rssBeforeKiB},
                  {"peak_rss_vmhwm_kib", hwmKiB},
                  {"peak_rss_vmhwm_is_streaming_only", peakReset},
                  {"peak_rss_ru_maxrss_kib", maxRss},
                  {"slab_buffer_kib", slab.size() * sizeof(float) / 1024},
                  {"checksum", checksum}}},
  };
  if (json) {
    std::cout << out.dump(2) << "\n";
    return 0;
  }
  std::cout << fmt::format("folder {}: {} files, {:.1f} MB; {} runs each, medians\n", folder,
                           files.size(), folderBytes / mb, repeats);
  std::cout << fmt::format("  baseline ifstream read: {:8.4f} s  {:8.0f} files/s  {:8.1f} MB/s\n",
                           tBase, files.size() / tBase, bytesRead / mb / tBase);
  std::cout << fmt::format("  scanDicom:              {:8.4f} s  {:8.0f} files/s  {:8.1f} MB/s "
                           "(file bytes)  {:.1f}x baseline time\n",
                           tScan, scan.filesExamined / tScan, folderBytes / mb / tScan,
                           tScan / tBase);
  std::cout << fmt::format("  stream {}x{}x{} in slabs of {}: {:8.4f} s  {:8.1f} slices/s  "
                           "{:8.1f} MB/s pixels (2 B/sample)  {:8.1f} MB/s file bytes  {:.1f}x "
                           "baseline time for the same bytes\n",
                           info.dims[0], info.dims[1], info.dims[2], slabSlices, tStream,
                           slices / tStream, pixelBytes / mb / tStream,
                           seriesBytes / mb / tStream,
                           tStream / (tBase * static_cast<double>(seriesBytes) / folderBytes));
  std::cout << fmt::format("  memory: RSS before streaming {:.1f} MiB; peak while streaming "
                           "VmHWM {:.1f} MiB{}; ru_maxrss (whole run) {:.1f} MiB; slab buffer "
                           "{:.1f} MiB; whole volume as float would be {:.1f} MiB\n",
                           rssBeforeKiB / 1024.0, hwmKiB / 1024.0,
                           peakReset ? "" : " (not reset: whole run)", maxRss / 1024.0,
                           slab.size() * sizeof(float) / 1048576.0,
                           4.0 * static_cast<double>(info.sampleCount()) / 1048576.0);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Scan a DICOM folder and stream its default series through readSlab; medians"};
  std::string folder = "../shared/data/dicom/dcm_qa_ct/Philips/S21570/S2020";
  int repeats = 5;
  int64_t slabSlices = 8;
  bool json = false;
  app.add_option("folder", folder, "DICOM folder to scan and stream")->capture_default_str();
  app.add_option("-n,--repeats", repeats, "runs of each phase")
      ->capture_default_str()
      ->check(octoray::cli::kPositive);
  app.add_option("--slab", slabSlices, "slices per readSlab call")
      ->capture_default_str()
      ->check(octoray::cli::kPositive);
  app.add_flag("--json", json, "print the results as JSON");
  CLI11_PARSE(app, argc, argv);
  try {
    return run(folder, repeats, slabSlices, json);
  } catch (const octoray::Error& e) {
    std::cerr << e.what() << "\n";
    return 1;
  } catch (const std::exception& e) {
    std::cerr << folder << ": " << e.what() << "\n";
    return 1;
  }
}
