#include "octoray/dicom/dicom_series.h"

#include <gdcmReader.h>

#include <tbb/parallel_for.h>
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <map>
#include <mutex>
#include <set>
#include <tuple>

#include <fmt/format.h>
#include <fmt/ranges.h>

#include "gdcm_support.h"
#include "octoray/core/error.h"
#include "octoray/core/text.h"

namespace octoray::dicom {
namespace fs = std::filesystem;
using detail::numberValue;
using detail::numberValues;
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

const gdcm::Tag kPixelData(0x7fe0, 0x0010);
const gdcm::Tag kSopClass(0x0008, 0x0016);
const gdcm::Tag kImageType(0x0008, 0x0008);
const gdcm::Tag kModality(0x0008, 0x0060);
const gdcm::Tag kSeriesDescription(0x0008, 0x103e);
const gdcm::Tag kSeriesUid(0x0020, 0x000e);
const gdcm::Tag kSeriesNumber(0x0020, 0x0011);
const gdcm::Tag kInstanceNumber(0x0020, 0x0013);
const gdcm::Tag kPosition(0x0020, 0x0032);
const gdcm::Tag kOrientation(0x0020, 0x0037);
const gdcm::Tag kPixelSpacing(0x0028, 0x0030);
const gdcm::Tag kRows(0x0028, 0x0010);
const gdcm::Tag kColumns(0x0028, 0x0011);
const gdcm::Tag kFrames(0x0028, 0x0008);
const gdcm::Tag kBitsAllocated(0x0028, 0x0100);
const gdcm::Tag kPhotometric(0x0028, 0x0004);
const gdcm::Tag kSamplesPerPixel(0x0028, 0x0002);
const gdcm::Tag kRescaleIntercept(0x0028, 0x1052);
const gdcm::Tag kRescaleSlope(0x0028, 0x1053);
const gdcm::Tag kSharedGroups(0x5200, 0x9229);
const gdcm::Tag kPerFrameGroups(0x5200, 0x9230);
const gdcm::Tag kPlanePositionSeq(0x0020, 0x9113);
const gdcm::Tag kPlaneOrientationSeq(0x0020, 0x9116);
const gdcm::Tag kPixelMeasuresSeq(0x0028, 0x9110);
const gdcm::Tag kPixelValueTransformSeq(0x0028, 0x9145);
const gdcm::Tag kWindowCenter(0x0028, 0x1050);
const gdcm::Tag kWindowWidth(0x0028, 0x1051);
const gdcm::Tag kWindowExplanation(0x0028, 0x1055);
const gdcm::Tag kVoiLutFunction(0x0028, 0x1056);
const gdcm::Tag kFrameVoiLutSeq(0x0028, 0x9132);
const gdcm::Tag kFrameTypeSeq(0x0018, 0x9226);  // CT Image Frame Type Sequence
const gdcm::Tag kFrameType(0x0008, 0x9007);
const gdcm::Tag kDirectoryRecords(0x0004, 0x1220);
const gdcm::Tag kReferencedFileId(0x0004, 0x1500);
const gdcm::Tag kMediaStorageSopClass(0x0002, 0x0002);
const char* kDirectorySopClass = "1.2.840.10008.1.3.10";

// Everything the scanner needs from one file's header.
struct FileHeader {
  std::string path;
  std::string sopClass, modality, description, seriesUid, photometric;
  std::vector<std::string> imageType;
  int seriesNumber = 0;
  int rows = 0, columns = 0, bitsAllocated = 0, bitsStored = 0, samplesPerPixel = 1;
  bool pixelSigned = false;
  std::optional<std::vector<double>> orientation, pixelSpacing;
  std::vector<FrameRef> frames;
  bool multiFrame = false;
  // The display windows each frame names (an enhanced object's per-frame or shared Frame VOI
  // LUT; a classic file's own for each of its frames), as many as `frames`.
  std::vector<std::vector<SourceWindow>> frameWindows;
  std::string windowProblem;  // why a window it names was left out (the first such), or ""
  std::string geometryProblem;  // DicomSeries::geometryProblem
};

bool isSecondaryCapture(const std::string& sopClass) {
  return sopClass.rfind("1.2.840.10008.5.1.4.1.1.7", 0) == 0;
}

// Functional-group lookup: the per-frame item wins over the shared item (PS3.3 C.7.6.16).
std::optional<gdcm::DataSet> groupMacro(const std::optional<gdcm::DataSet>& perFrame,
                                        const std::optional<gdcm::DataSet>& shared,
                                        const gdcm::Tag& macro) {
  if (perFrame) {
    if (auto item = detail::firstItem(*perFrame, macro)) return item;
  }
  if (shared) return detail::firstItem(*shared, macro);
  return std::nullopt;
}

// The modality LUT must be usable: a slope of 0 would turn every pixel into the intercept, a
// non-finite slope or intercept every pixel into NaN or infinity. Such a file is refused (and
// listed as skipped, naming the value), never read into a silently wrong volume.
// RescaleSlope or RescaleIntercept: `fallback` when absent; a value that is present but not a
// finite number ("NaN", "inf", junk) refuses the file instead of being replaced silently.
double rescaleValue(const gdcm::DataSet& ds, const gdcm::Tag& tag, double fallback, const std::string& path,
                    const char* name) {
  const std::string text = stringValue(ds, tag);
  if (text.find_first_not_of(" ") == std::string::npos) return fallback;
  const auto value = numberValue(ds, tag);
  if (!value) throw Error(path, fmt::format("{} '{}' is not a finite number", name, text));
  return *value;
}

void checkRescale(const std::string& path, double slope, double intercept, int frame) {
  const std::string where = frame < 0 ? "" : fmt::format(" (frame {})", frame + 1);
  if (!std::isfinite(slope) || !std::isfinite(intercept)) {
    throw Error(path, fmt::format("RescaleSlope {} / RescaleIntercept {}{} is not a finite number", slope,
                                  intercept, where));
  }
  if (slope == 0) {
    throw Error(path, fmt::format("RescaleSlope is 0{}: every pixel would read as the intercept {}", where,
                                  intercept));
  }
}

// The display windows `ds` names, in order (PS3.3 C.11.2.1.2), each with the VOI LUT function
// `ds` declares (VOILUTFunction, C.11.2.1.3; sourceVoiFunction), which the viewer follows. A pair that is not two
// finite numbers is left out, and so is a width below 1 where the function is LINEAR (the
// default, which allows none, C.11.2.1.2.1) or a width not above 0 where it is LINEAR_EXACT or
// SIGMOID (which allow any above 0, C.11.2.1.3). A function that is not one of those three
// defined terms is taken as none (LINEAR). `problem` says each of these, where it is still
// empty. A window named twice is kept once.
std::vector<SourceWindow> readWindows(const gdcm::DataSet& ds, std::string& problem) {
  const std::string centerText = stringValue(ds, kWindowCenter), widthText = stringValue(ds, kWindowWidth);
  if (centerText.empty() && widthText.empty()) return {};
  const auto say = [&](std::string text) {
    if (problem.empty()) problem = std::move(text);
  };
  const std::string declared = stringValue(ds, kVoiLutFunction);
  const std::optional<std::string> known = sourceVoiFunction(declared);
  if (!known) {
    say(fmt::format("VOILUTFunction '{}' is not LINEAR, LINEAR_EXACT or SIGMOID: its windows are "
                    "taken as LINEAR",
                    declared));
  }
  const std::string function = known.value_or("");
  const auto centers = numberValues(ds, kWindowCenter);
  const auto widths = numberValues(ds, kWindowWidth);
  if (!centers || !widths) {
    say(fmt::format("WindowCenter '{}' / WindowWidth '{}' are not finite numbers: no window "
                          "from the file",
                    centerText, widthText));
    return {};
  }
  if (centers->size() != widths->size()) {
    say(fmt::format("WindowCenter has {} values and WindowWidth {}: the first {} pairs are used",
                    centers->size(), widths->size(), std::min(centers->size(), widths->size())));
  }
  const std::vector<std::string> explanations = stringValues(ds, kWindowExplanation);
  std::vector<SourceWindow> windows;
  for (std::size_t i = 0; i < std::min(centers->size(), widths->size()); ++i) {
    const bool linear = function.empty();
    if (linear && (*widths)[i] < 1) {
      say(fmt::format("WindowWidth {} is below 1, the least the LINEAR VOI function allows: that window "
                      "is left out",
                      (*widths)[i]));
      continue;
    }
    if (!((*widths)[i] > 0)) {
      say(fmt::format("WindowWidth {} is not above 0: that window is left out", (*widths)[i]));
      continue;
    }
    SourceWindow w;
    w.center = (*centers)[i];
    w.width = (*widths)[i];
    if (i < explanations.size()) w.explanation = explanations[i];
    w.function = function;
    // Philips writes its one window twice ("40\\40", "80\\80"): a repeat is one window.
    const bool repeat = std::any_of(windows.begin(), windows.end(), [&](const SourceWindow& o) {
      return o.center == w.center && o.width == w.width && o.explanation == w.explanation;
    });
    if (!repeat) windows.push_back(std::move(w));
  }
  return windows;
}

void readEnhancedFrames(const gdcm::DataSet& ds, FileHeader& h, int frameCount) {
  const auto shared = detail::firstItem(ds, kSharedGroups);
  const auto perFrame = detail::sequenceItems(ds, kPerFrameGroups);
  std::optional<gdcm::DataSet> noItem;
  for (int f = 0; f < frameCount; ++f) {
    std::optional<gdcm::DataSet> mine;
    if (static_cast<std::size_t>(f) < perFrame.size()) mine = perFrame[static_cast<std::size_t>(f)];
    FrameRef frame;
    frame.path = h.path;
    frame.frameIndex = f;
    frame.instanceNumber = f + 1;
    if (auto pos = groupMacro(mine, shared, kPlanePositionSeq)) {
      if (auto v = numberValues(*pos, kPosition); v && v->size() == 3) {
        frame.positionMm = {(*v)[0], (*v)[1], (*v)[2]};
      } else {
        h.orientation.reset();  // a frame without a position: the object has no usable geometry
      }
    } else {
      h.orientation.reset();
    }
    // Each frame's own display windows (Frame VOI LUT), or none.
    if (auto voi = groupMacro(mine, shared, kFrameVoiLutSeq)) {
      h.frameWindows.push_back(readWindows(*voi, h.windowProblem));
    } else {
      h.frameWindows.emplace_back();
    }
    if (f == 0) {
      if (auto orient = groupMacro(mine, shared, kPlaneOrientationSeq)) {
        h.orientation = numberValues(*orient, kOrientation);
      }
      if (auto measures = groupMacro(mine, shared, kPixelMeasuresSeq)) {
        h.pixelSpacing = numberValues(*measures, kPixelSpacing);
      }
      if (auto frameType = groupMacro(mine, shared, kFrameTypeSeq)) {
        auto type = stringValues(*frameType, kFrameType);
        if (!type.empty()) h.imageType = type;
      }
    }
    if (auto transform = groupMacro(mine, shared, kPixelValueTransformSeq)) {
      frame.rescaleSlope = rescaleValue(*transform, kRescaleSlope, 1.0, h.path, "RescaleSlope");
      frame.rescaleIntercept = rescaleValue(*transform, kRescaleIntercept, 0.0, h.path, "RescaleIntercept");
    }
    checkRescale(h.path, frame.rescaleSlope, frame.rescaleIntercept, static_cast<int>(h.frames.size()));
    h.frames.push_back(frame);
  }
}

// The pixel data value must lie inside the file, and native (uncompressed) data must hold
// every frame. Encapsulated fragments are checked when they are decoded; here each frame needs
// at least its 8-byte item header. Deflated data sets cannot be checked before inflating.
void checkPixelLength(const gdcm::File& file, const FileHeader& h, int frameCount,
                      std::size_t pixelValueOffset) {
  std::error_code ec;
  const uint64_t fileBytes = std::filesystem::file_size(h.path, ec);
  if (ec) throw Error(h.path, "cannot read file size: " + ec.message());
  if (pixelValueOffset > fileBytes) throw Error(h.path, "file truncated before its pixel data");
  const gdcm::TransferSyntax& ts = file.GetHeader().GetDataSetTransferSyntax();
  if (ts == gdcm::TransferSyntax::DeflatedExplicitVRLittleEndian) return;
  const uint64_t available = fileBytes - pixelValueOffset;
  if (ts.IsEncapsulated()) {
    if (available / 8 < static_cast<uint64_t>(frameCount)) {
      throw Error(h.path, fmt::format("NumberOfFrames {} cannot fit in {} bytes of encapsulated "
                                      "pixel data (at least one fragment per frame)",
                                      frameCount, available));
    }
    return;
  }
  // At most 65535 x 65535 x 2^31 x 65535 x 65535 bits: long double keeps the comparison exact
  // enough where 64 bits would overflow.
  const long double bits = static_cast<long double>(h.rows) * h.columns * frameCount *
                           std::max(h.samplesPerPixel, 1) * h.bitsAllocated;
  const long double needed = std::ceil(bits / 8);
  if (static_cast<long double>(available) < needed) {
    throw Error(h.path, fmt::format("pixel data is {} bytes, {} rows x {} columns x {} frames "
                                    "need {:.0f} (file truncated)",
                                    available, h.rows, h.columns, frameCount, needed));
  }
}

// Reads one file's attributes (pixel data parsed, not decoded). Throws Error with the reason
// to skip it.
}  // namespace

PatientIdentity readPatientIdentity(const std::string& path) {
  detail::vetWithGdcm(path);
  gdcm::Reader reader;
  reader.SetFileName(path.c_str());
  if (!reader.ReadUpToTag(kPixelData, std::set<gdcm::Tag>{kPixelData})) {
    throw Error(path, "not a DICOM file, or truncated (GDCM could not parse it)");
  }
  const gdcm::DataSet& ds = reader.GetFile().GetDataSet();
  PatientIdentity p;
  p.name = stringValue(ds, gdcm::Tag(0x0010, 0x0010));
  p.id = stringValue(ds, gdcm::Tag(0x0010, 0x0020));
  p.birthDate = stringValue(ds, gdcm::Tag(0x0010, 0x0030));
  p.studyDate = stringValue(ds, gdcm::Tag(0x0008, 0x0020));
  p.studyDescription = stringValue(ds, gdcm::Tag(0x0008, 0x1030));
  p.studyUid = stringValue(ds, gdcm::Tag(0x0020, 0x000D));
  return p;
}

namespace {

FileHeader readHeader(const std::string& path) {
  detail::vetWithGdcm(path);
  // Everything up to the pixel data value, which is skipped (the stream stops at its start).
  gdcm::Reader reader;
  reader.SetFileName(path.c_str());
  if (!reader.ReadUpToTag(kPixelData, std::set<gdcm::Tag>{kPixelData})) {
    throw Error(path, "not a DICOM file, or truncated (GDCM could not parse it)");
  }
  const std::size_t pixelValueOffset = reader.GetStreamCurrentPosition();
  const gdcm::File& file = reader.GetFile();
  const gdcm::DataSet& ds = file.GetDataSet();
  FileHeader h;
  h.path = path;
  h.sopClass = stringValue(ds, kSopClass);
  if (h.sopClass.empty()) h.sopClass = stringValue(file.GetHeader(), kMediaStorageSopClass);
  if (h.sopClass == kDirectorySopClass) throw Error(path, "DICOM directory (DICOMDIR), not an image");

  auto rows = detail::unsignedShort(file, ds, kRows);
  auto columns = detail::unsignedShort(file, ds, kColumns);
  if (!rows || !columns) {
    throw Error(path, fmt::format("not an image (SOP class {} has no Rows/Columns)",
                                  h.sopClass.empty() ? "unknown" : h.sopClass));
  }
  h.rows = *rows;
  h.columns = *columns;
  h.bitsAllocated = detail::unsignedShort(file, ds, kBitsAllocated).value_or(0);
  h.bitsStored = detail::unsignedShort(file, ds, gdcm::Tag(0x0028, 0x0101)).value_or(0);
  h.pixelSigned = detail::unsignedShort(file, ds, gdcm::Tag(0x0028, 0x0103)).value_or(0) == 1;
  // The skipped pixel data value is not in the data set; the stream position tells it was there.
  if (pixelValueOffset == std::size_t(-1)) {
    throw Error(path, "image without pixel data");
  }
  h.samplesPerPixel = detail::unsignedShort(file, ds, kSamplesPerPixel).value_or(1);
  h.photometric = stringValue(ds, kPhotometric);
  h.modality = stringValue(ds, kModality);
  h.description = stringValue(ds, kSeriesDescription);
  h.seriesUid = stringValue(ds, kSeriesUid);
  h.imageType = stringValues(ds, kImageType);
  h.seriesNumber = static_cast<int>(numberValue(ds, kSeriesNumber).value_or(0));
  if (h.seriesUid.empty()) h.seriesUid = "(no SeriesInstanceUID)";

  const double framesValue = numberValue(ds, kFrames).value_or(1);
  if (!(framesValue >= 1 && framesValue <= std::numeric_limits<int>::max()) ||
      framesValue != std::floor(framesValue)) {
    throw Error(path, fmt::format("invalid NumberOfFrames {}", framesValue));
  }
  const int frameCount = static_cast<int>(framesValue);
  // Before anything is sized by the untrusted count: the pixel data must be able to hold it.
  checkPixelLength(file, h, frameCount, pixelValueOffset);
  if (ds.FindDataElement(kPerFrameGroups) || ds.FindDataElement(kSharedGroups)) {
    h.multiFrame = true;
    readEnhancedFrames(ds, h, frameCount);
  } else {
    h.orientation = numberValues(ds, kOrientation);
    h.pixelSpacing = numberValues(ds, kPixelSpacing);
    const std::vector<SourceWindow> windows = readWindows(ds, h.windowProblem);
    const auto position = numberValues(ds, kPosition);
    const double slope = rescaleValue(ds, kRescaleSlope, 1.0, path, "RescaleSlope");
    const double intercept = rescaleValue(ds, kRescaleIntercept, 0.0, path, "RescaleIntercept");
    checkRescale(path, slope, intercept, -1);
    const int instance = static_cast<int>(numberValue(ds, kInstanceNumber).value_or(0));
    if (!position || position->size() != 3) h.orientation.reset();
    // A legacy multi-frame image has one position for all frames: it is not a stack.
    if (frameCount > 1) h.orientation.reset();
    for (int f = 0; f < frameCount; ++f) {
      FrameRef frame;
      frame.path = path;
      frame.frameIndex = f;
      frame.instanceNumber = instance;
      if (position && position->size() == 3) {
        frame.positionMm = {(*position)[0], (*position)[1], (*position)[2]};
      }
      frame.rescaleSlope = slope;
      frame.rescaleIntercept = intercept;
      h.frames.push_back(frame);
      h.frameWindows.push_back(windows);
    }
  }
  const std::string ts = file.GetHeader().GetDataSetTransferSyntax().GetString()
                             ? file.GetHeader().GetDataSetTransferSyntax().GetString()
                             : "";
  for (auto& frame : h.frames) frame.transferSyntaxUid = ts;
  if (h.orientation && h.orientation->size() != 6) h.orientation.reset();
  if (h.pixelSpacing && h.pixelSpacing->size() != 2) h.pixelSpacing.reset();
  // The first of the three a geometry needs that is missing, or present but unusable (not
  // finite numbers, or not as many as needed): said by name where the series has no geometry.
  if (!h.multiFrame) {
    for (const auto& [tag, name, count] : {std::tuple{kPixelSpacing, "PixelSpacing", 2},
                                           std::tuple{kOrientation, "ImageOrientationPatient", 6},
                                           std::tuple{kPosition, "ImagePositionPatient", 3}}) {
      if (!ds.FindDataElement(tag)) {
        h.geometryProblem = fmt::format("no {}", name);
        break;
      }
      const auto values = numberValues(ds, tag);
      if (values && static_cast<int>(values->size()) == count) continue;
      h.geometryProblem = fmt::format("{} '{}' is not {} finite numbers", name,
                                      fmt::join(stringValues(ds, tag), "\\"), count);
      break;
    }
  }
  return h;
}

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

}  // namespace

namespace {
void readSeries(const std::vector<std::string>& files, const ScanOptions& options, DicomScan& scan);
}  // namespace

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

namespace {

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
