#include "octoray/dicom/dicom_series.h"

#include <gdcmReader.h>

#include <tbb/parallel_for.h>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <mutex>
#include <set>
#include <tuple>

#include <fmt/format.h>
#include <fmt/ranges.h>

#include "dicom_header.h"
#include "gdcm_support.h"
#include "octoray/core/error.h"
#include "octoray/core/text.h"

namespace octoray::dicom {
namespace fs = std::filesystem;
using detail::stringValue;
using detail::stringValues;

const char* toString(SeriesKind kind) {
  switch (kind) {
    case SeriesKind::Volume: return "volume";
    case SeriesKind::Localizer: return "localizer";
    case SeriesKind::SecondaryCapture: return "secondary-capture";
    case SeriesKind::Derived: return "derived";
    case SeriesKind::NoGeometry: return "no-geometry";
  }
  return "unknown";
}

namespace {

using detail::FileHeader;
using detail::isSecondaryCapture;
using detail::kDirectorySopClass;
using detail::kMediaStorageSopClass;
using detail::readHeader;

const gdcm::Tag kDirectoryRecords(0x0004, 0x1220);
const gdcm::Tag kReferencedFileId(0x0004, 0x1500);

// Series are split where one UID mixes orientations, sizes or pixel spacings.
std::string groupKey(const FileHeader& h) {
  std::string key = h.seriesUid + fmt::format("|{}x{}", h.rows, h.columns);
  if (h.orientation) {
    for (double v : *h.orientation) key += fmt::format("|{:.4f}", v);
  } else {
    key += "|no-orientation";
  }
  if (h.pixelSpacing) key += fmt::format("|{:.5f}|{:.5f}", (*h.pixelSpacing)[0], (*h.pixelSpacing)[1]);
  // A localiser filed under the axial series' UID stays apart even in the same orientation.
  if (std::find(h.imageType.begin(), h.imageType.end(), "LOCALIZER") != h.imageType.end()) {
    key += "|localizer";
  }
  return key;
}

void classify(DicomSeries& s) {
  const auto has = [&](const char* word) {
    return std::find(s.imageType.begin(), s.imageType.end(), word) != s.imageType.end();
  };
  if (isSecondaryCapture(s.sopClassUid)) {
    s.kind = SeriesKind::SecondaryCapture;
    s.kindReason = "Secondary Capture SOP class " + s.sopClassUid;
  } else if (has("LOCALIZER")) {
    s.kind = SeriesKind::Localizer;
    s.kindReason = "ImageType contains LOCALIZER";
  } else if (!s.hasGeometry) {
    s.kind = SeriesKind::NoGeometry;
    s.kindReason = s.geometryProblem.empty()
                       ? "no ImagePositionPatient/ImageOrientationPatient/PixelSpacing per frame"
                       : s.geometryProblem;
  } else if (!s.imageType.empty() && s.imageType[0] == "DERIVED") {
    s.kind = SeriesKind::Derived;
    s.kindReason = "ImageType DERIVED";
  } else {
    s.kind = SeriesKind::Volume;
    s.kindReason = s.imageType.empty() ? "image stack" : "ImageType " + s.imageType[0];
  }
}

// Resolves a DICOMDIR ReferencedFileID (components joined by '\') under `root`; on
// case-sensitive file systems it also accepts a different letter case.
std::optional<fs::path> resolveReferencedFile(const fs::path& root,
                                              const std::vector<std::string>& components) {
  fs::path current = root;
  for (const auto& part : components) {
    fs::path exact = current / part;
    std::error_code ec;
    if (fs::exists(exact, ec)) {
      current = exact;
      continue;
    }
    bool found = false;
    if (fs::is_directory(current, ec)) {
      for (const auto& entry : fs::directory_iterator(current, ec)) {
        if (asciiLower(entry.path().filename().string()) == asciiLower(part)) {
          current = entry.path();
          found = true;
          break;
        }
      }
    }
    if (!found) return std::nullopt;
  }
  return current;
}

// Collects the files a DICOMDIR lists, following nested directory files (Philips DIRFILEs);
// records a warning for every listed file that does not exist. False (with a warning) when the
// DICOMDIR itself cannot be parsed.
bool readDirectory(const fs::path& dirFile, const fs::path& root, std::set<fs::path>& visited,
                   std::set<std::string>& listed, DicomScan& scan) {
  if (!visited.insert(fs::weakly_canonical(dirFile)).second) return true;
  // GDCM asserts (aborting the process) on some malformed files: vetted in a child first, like
  // every image header (found by fuzz_dicomdir).
  try {
    detail::vetWithGdcm(dirFile.string());
  } catch (const Error& e) {
    scan.warnings.push_back(dirFile.string() + ": DICOMDIR could not be parsed (" + e.reason() +
                            "); files are found by searching the folder instead");
    return false;
  }
  gdcm::Reader reader;
  reader.SetFileName(dirFile.c_str());
  if (!reader.Read()) {
    scan.warnings.push_back(dirFile.string() + ": DICOMDIR could not be parsed; files are found by "
                            "searching the folder instead");
    return false;
  }
  for (const gdcm::DataSet& record :
       detail::sequenceItems(reader.GetFile().GetDataSet(), kDirectoryRecords)) {
    const auto components = stringValues(record, kReferencedFileId);
    if (components.empty()) continue;
    std::string joined;
    for (const auto& c : components) joined += (joined.empty() ? "" : "/") + c;
    // A record names a file inside the DICOMDIR's folder: plain names only, and no symbolic
    // link leading out of the folder (a crafted record must not open /etc/passwd).
    const bool plainNames = std::all_of(components.begin(), components.end(), [](const std::string& c) {
      return !c.empty() && c != "." && c != ".." && c.find('/') == std::string::npos &&
             c.find('\\') == std::string::npos;
    });
    if (!plainNames) {
      scan.warnings.push_back(fmt::format("{}: record '{}' points outside the DICOMDIR's folder; ignored",
                                          dirFile.string(), joined));
      continue;
    }
    const auto file = resolveReferencedFile(root, components);
    if (file) {
      const std::string inside = fs::weakly_canonical(root).string() + "/";
      if (!fs::weakly_canonical(*file).string().starts_with(inside)) {
        scan.warnings.push_back(fmt::format("{}: record '{}' leads outside the DICOMDIR's folder (a link); "
                                            "ignored", dirFile.string(), joined));
        continue;
      }
    }
    if (!file) {
      scan.warnings.push_back(fmt::format("{}: lists {} which does not exist", dirFile.string(),
                                          (root / joined).string()));
      continue;
    }
    gdcm::Reader probe;
    probe.SetFileName(file->c_str());
    bool vetted = true;
    try {
      detail::vetWithGdcm(file->string());
    } catch (const Error&) {
      vetted = false;  // listed as a file: reading its header reports what is wrong with it
    }
    const bool isDirectory =
        vetted && probe.ReadUpToTag(gdcm::Tag(0x0008, 0x0005), std::set<gdcm::Tag>{}) &&
        stringValue(probe.GetFile().GetHeader(), kMediaStorageSopClass) == kDirectorySopClass;
    if (isDirectory) {
      readDirectory(*file, root, visited, listed, scan);
    } else {
      listed.insert(fs::weakly_canonical(*file).string());
    }
  }
  return true;
}

bool isDicomDirName(const fs::path& p) { return asciiLower(p.filename().string()) == "dicomdir"; }

// Reads the headers of `files` (sorted) and groups them into scan.series.
void readSeries(const std::vector<std::string>& files, const ScanOptions& options, DicomScan& scan) {
  // Headers are read in parallel; results keep the sorted file order.
  std::vector<std::optional<FileHeader>> headers(files.size());
  std::vector<std::string> failures(files.size());
  std::mutex progressMutex;
  std::size_t done = 0;
  tbb::parallel_for(std::size_t{0}, files.size(), [&](std::size_t i) {
    try {
      headers[i] = readHeader(files[i]);
    } catch (const Error& e) {
      failures[i] = e.reason();
    } catch (const std::exception& e) {
      failures[i] = std::string("unreadable: ") + e.what();
    }
    if (options.progress) {
      std::lock_guard lock(progressMutex);
      options.progress(++done, files.size());
    }
  });
  scan.filesExamined = files.size();

  std::map<std::string, DicomSeries> groups;
  std::vector<std::string> order;
  // The windows each series' frames name, by what they name: the most frames' choice wins, the
  // first named on a tie (a scanner may write each slice's own, or none on some slices).
  struct WindowChoice {
    std::size_t frames = 0;
    std::size_t first = 0;  // the order in which the choices were first seen
    std::vector<SourceWindow> windows;
  };
  std::map<std::string, std::map<std::string, WindowChoice>> windowChoices;
  for (std::size_t i = 0; i < files.size(); ++i) {
    if (!headers[i]) {
      scan.skipped.push_back({files[i], failures[i]});
      continue;
    }
    FileHeader& h = *headers[i];
    const std::string key = groupKey(h);
    auto [it, inserted] = groups.try_emplace(key);
    DicomSeries& s = it->second;
    if (inserted) {
      order.push_back(key);
      s.seriesUid = h.seriesUid;
      s.seriesNumber = h.seriesNumber;
      s.modality = h.modality;
      s.description = h.description;
      s.sopClassUid = h.sopClass;
      s.imageType = h.imageType;
      s.multiFrame = h.multiFrame;
      s.rows = h.rows;
      s.columns = h.columns;
      s.bitsAllocated = h.bitsAllocated;
      s.bitsStored = h.bitsStored;
      s.pixelSigned = h.pixelSigned;
      s.photometric = h.photometric;
      s.hasGeometry = h.orientation.has_value() && h.pixelSpacing.has_value();
      s.geometryProblem = h.geometryProblem;
      if (s.hasGeometry) {
        const auto& o = *h.orientation;
        s.rowDirection = {o[0], o[1], o[2]};
        s.columnDirection = {o[3], o[4], o[5]};
        s.rowSpacingMm = (*h.pixelSpacing)[0];
        s.columnSpacingMm = (*h.pixelSpacing)[1];
      }
    }
    s.multiFrame = s.multiFrame || h.multiFrame;
    for (const std::vector<SourceWindow>& windows : h.frameWindows) {
      std::string named;
      for (const SourceWindow& w : windows) named += fmt::format("{}|{}|{}|{}\\", w.center, w.width, w.explanation, w.function);
      auto& choices = windowChoices[key];
      auto [choice, first] = choices.try_emplace(named);
      if (first) {
        choice->second.first = choices.size();
        choice->second.windows = windows;
      }
      ++choice->second.frames;
    }
    if (!h.windowProblem.empty() && s.windowWarning.empty()) {
      s.windowWarning = h.path + ": " + h.windowProblem;
    }
    for (auto& frame : h.frames) s.frames.push_back(std::move(frame));
  }
  for (auto& [key, choices] : windowChoices) {
    const WindowChoice* best = nullptr;
    for (const auto& [named, choice] : choices) {
      if (!best || choice.frames > best->frames ||
          (choice.frames == best->frames && choice.first < best->first)) {
        best = &choice;
      }
    }
    if (best) groups[key].windows = best->windows;
  }

  // Number the parts of a UID that had to be split, so the table tells them apart.
  std::map<std::string, int> partsPerUid;
  for (const auto& key : order) ++partsPerUid[groups[key].seriesUid];
  std::map<std::string, int> partSeen;
  for (const auto& key : order) {
    DicomSeries& s = groups[key];
    classify(s);
    if (partsPerUid[s.seriesUid] > 1) {
      s.kindReason += fmt::format("; part {} of {} of a series mixing orientations or sizes",
                                  ++partSeen[s.seriesUid], partsPerUid[s.seriesUid]);
    }
    scan.series.push_back(std::move(s));
  }
  std::stable_sort(scan.series.begin(), scan.series.end(),
                   [](const DicomSeries& a, const DicomSeries& b) {
                     return std::tie(a.seriesNumber, a.seriesUid) <
                            std::tie(b.seriesNumber, b.seriesUid);
                   });
}

}  // namespace

bool isDicomPart10(const fs::path& file) {
  std::ifstream in(file, std::ios::binary);
  char preamble[132] = {};
  return in.read(preamble, sizeof preamble) && std::memcmp(preamble + 128, "DICM", 4) == 0;
}

DicomScan scanDicom(const fs::path& path, const ScanOptions& options) {
  detail::quietGdcm();
  DicomScan scan;
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Error(path.string(), "no such file or folder");

  std::vector<std::string> files;
  std::set<std::string> listed;
  std::set<fs::path> visited;
  // Every file below `folder`; DICOMDIRs met on the way are read for the files they list.
  auto searchFolder = [&](const fs::path& folder) {
    fs::recursive_directory_iterator it(folder, fs::directory_options::skip_permission_denied, ec);
    if (ec) throw Error(folder.string(), "folder cannot be read: " + ec.message());
    for (; it != fs::recursive_directory_iterator(); it.increment(ec)) {
      if (ec) break;
      // Hidden files (.DS_Store, a retrieval's temporaries and its completion record) are
      // not part of an exam.
      if (it->path().filename().string().starts_with(".")) continue;
      if (!it->is_regular_file(ec)) continue;
      if (isDicomDirName(it->path())) {
        readDirectory(it->path(), it->path().parent_path(), visited, listed, scan);
      }
      files.push_back(it->path().string());
    }
    std::sort(files.begin(), files.end());
  };
  if (fs::is_directory(path, ec)) {
    searchFolder(path);
  } else if (isDicomDirName(path)) {
    if (readDirectory(path, path.parent_path(), visited, listed, scan)) {
      files.assign(listed.begin(), listed.end());
    } else {
      searchFolder(path.has_parent_path() ? path.parent_path() : fs::path("."));  // as warned
    }
  } else {
    files.push_back(path.string());
  }
  readSeries(files, options, scan);
  return scan;
}

DicomScan scanDicomFiles(std::vector<std::string> files, const ScanOptions& options) {
  detail::quietGdcm();
  std::sort(files.begin(), files.end());
  files.erase(std::unique(files.begin(), files.end()), files.end());
  DicomScan scan;
  readSeries(files, options, scan);
  return scan;
}

std::size_t defaultSeriesIndex(const DicomScan& scan, const std::string& path) {
  std::optional<std::size_t> best;
  const auto rank = [](const DicomSeries& s) {
    // Prefer original volumes, then derived stacks; then the most frames.
    const int kindRank = s.kind == SeriesKind::Volume ? 2 : (s.kind == SeriesKind::Derived ? 1 : 0);
    return std::pair{kindRank, s.frames.size()};
  };
  for (std::size_t i = 0; i < scan.series.size(); ++i) {
    const auto& s = scan.series[i];
    if (s.kind != SeriesKind::Volume && s.kind != SeriesKind::Derived) continue;
    if (!best || rank(s) > rank(scan.series[*best])) best = i;
  }
  if (!best) {
    // Why, from the first series or the first file left out: one file given by name says
    // only this.
    std::string why;
    if (!scan.series.empty()) {
      why = fmt::format(": series {} is {} ({})", 1, toString(scan.series.front().kind),
                        scan.series.front().kindReason);
    } else if (!scan.skipped.empty()) {
      why = fmt::format(": {}: {}",
                        std::filesystem::path(scan.skipped.front().path).filename().string(),
                        scan.skipped.front().reason);
    }
    throw Error(path,
                fmt::format("no volumetric image series found ({} series, {} files skipped){}",
                            scan.series.size(), scan.skipped.size(), why));
  }
  return *best;
}

std::vector<std::string> filesLeftOut(const DicomScan& scan, std::size_t chosen) {
  std::vector<std::string> warnings;
  const DicomSeries& mine = scan.series.at(chosen);
  auto names = [](const std::vector<std::string>& files) {
    std::string out;
    for (std::size_t i = 0; i < files.size() && i < 5; ++i) out += (i ? ", " : "") + files[i];
    if (files.size() > 5) out += fmt::format(" and {} more", files.size() - 5);
    return out;
  };
  for (std::size_t i = 0; i < scan.series.size(); ++i) {
    const DicomSeries& other = scan.series[i];
    if (i == chosen || other.seriesUid != mine.seriesUid) continue;
    std::vector<std::string> files;
    for (const auto& f : other.frames) {
      if (files.empty() || files.back() != f.path) files.push_back(f.path);
    }
    warnings.push_back(fmt::format("{} image(s) of this series are not in the volume: they differ in "
                                   "orientation, size or spacing (series table #{}): {}",
                                   other.frames.size(), i, names(files)));
  }
  std::vector<std::string> unreadable;
  for (const auto& s : scan.skipped) {
    if (s.reason.find("DICOMDIR") != std::string::npos) continue;  // directories are not images
    unreadable.push_back(fmt::format("{} ({})", s.path, s.reason));
  }
  if (!unreadable.empty()) {
    warnings.push_back(fmt::format("{} file(s) could not be read; if they are slices of this series, the "
                                   "volume lacks them: {}",
                                   unreadable.size(), names(unreadable)));
  }
  return warnings;
}

std::size_t findSeries(const DicomScan& scan, const std::string& indexOrUid,
                       const std::string& path) {
  const bool numeric = !indexOrUid.empty() &&
                       std::all_of(indexOrUid.begin(), indexOrUid.end(), ::isdigit) &&
                       indexOrUid.size() < 6;
  if (numeric) {
    const std::size_t index = std::stoul(indexOrUid);
    if (index < scan.series.size()) return index;
    throw Error(path, fmt::format("series index {} out of range (0..{})", index,
                                  scan.series.empty() ? 0 : scan.series.size() - 1));
  }
  std::optional<std::size_t> found;
  for (std::size_t i = 0; i < scan.series.size(); ++i) {
    if (scan.series[i].seriesUid != indexOrUid) continue;
    // Of a split UID, take its largest part.
    if (!found || scan.series[i].frames.size() > scan.series[*found].frames.size()) found = i;
  }
  if (!found) throw Error(path, "no series with SeriesInstanceUID " + indexOrUid);
  return *found;
}

}  // namespace octoray::dicom
