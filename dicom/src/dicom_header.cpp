#include "dicom_header.h"

#include <gdcmReader.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <set>

#include <fmt/format.h>
#include <fmt/ranges.h>

#include "gdcm_support.h"
#include "octoray/core/error.h"
#include "octoray/core/text.h"

namespace octoray::dicom {
using detail::FileHeader;
using detail::numberValue;
using detail::numberValues;
using detail::stringValue;
using detail::stringValues;

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
double rescaleValue(const gdcm::DataSet& ds, const gdcm::Tag& tag, double fallback,
                    const std::string& path, const char* name) {
  const std::string text = stringValue(ds, tag);
  if (text.find_first_not_of(" ") == std::string::npos) return fallback;
  const auto value = numberValue(ds, tag);
  if (!value) throw Error(path, fmt::format("{} '{}' is not a finite number", name, text));
  return *value;
}

void checkRescale(const std::string& path, double slope, double intercept, int frame) {
  const std::string where = frame < 0 ? "" : fmt::format(" (frame {})", frame + 1);
  if (!std::isfinite(slope) || !std::isfinite(intercept)) {
    throw Error(path, fmt::format("RescaleSlope {} / RescaleIntercept {}{} is not a finite number",
                                  slope, intercept, where));
  }
  if (slope == 0) {
    throw Error(path, fmt::format("RescaleSlope is 0{}: every pixel would read as the intercept {}",
                                  where, intercept));
  }
}

// The display windows `ds` names, in order (PS3.3 C.11.2.1.2), each with the VOI LUT function
// `ds` declares (VOILUTFunction, C.11.2.1.3; sourceVoiFunction), which the viewer follows. A pair
// that is not two finite numbers is left out, and so is a width below 1 where the function is
// LINEAR (the default, which allows none, C.11.2.1.2.1) or a width not above 0 where it is
// LINEAR_EXACT or SIGMOID (which allow any above 0, C.11.2.1.3). A function that is not one of
// those three defined terms is taken as none (LINEAR). `problem` says each of these, where it is
// still empty. A window named twice is kept once.
std::vector<SourceWindow> readWindows(const gdcm::DataSet& ds, std::string& problem) {
  const std::string centerText = stringValue(ds, kWindowCenter),
                    widthText = stringValue(ds, kWindowWidth);
  if (centerText.empty() && widthText.empty()) return {};
  const auto say = [&](std::string text) {
    if (problem.empty()) problem = std::move(text);
  };
  const std::string declared = stringValue(ds, kVoiLutFunction);
  const std::optional<std::string> known = sourceVoiFunction(declared);
  if (!known) {
    say(
        fmt::format("VOILUTFunction '{}' is not LINEAR, LINEAR_EXACT or SIGMOID: its windows are "
                    "taken as LINEAR",
                    declared));
  }
  const std::string function = known.value_or("");
  const auto centers = numberValues(ds, kWindowCenter);
  const auto widths = numberValues(ds, kWindowWidth);
  if (!centers || !widths) {
    say(
        fmt::format("WindowCenter '{}' / WindowWidth '{}' are not finite numbers: no window "
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
      say(fmt::format(
          "WindowWidth {} is below 1, the least the LINEAR VOI function allows: that window "
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
      frame.rescaleIntercept =
          rescaleValue(*transform, kRescaleIntercept, 0.0, h.path, "RescaleIntercept");
    }
    checkRescale(h.path, frame.rescaleSlope, frame.rescaleIntercept,
                 static_cast<int>(h.frames.size()));
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

namespace detail {

bool isSecondaryCapture(const std::string& sopClass) {
  return sopClass.rfind("1.2.840.10008.5.1.4.1.1.7", 0) == 0;
}

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
  if (h.sopClass == kDirectorySopClass)
    throw Error(path, "DICOM directory (DICOMDIR), not an image");

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

}  // namespace detail
}  // namespace octoray::dicom
