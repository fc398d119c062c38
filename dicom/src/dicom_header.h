#pragma once
// One DICOM file's header as the series scanner reads it: the attributes that classify it,
// group it into a series and place each of its frames (internal to dicom/).

#include <gdcmTag.h>

#include <optional>
#include <string>
#include <vector>

#include "octoray/dicom/dicom_series.h"

namespace octoray::dicom::detail {

// MediaStorageSOPClassUID in the file meta group, and the SOP class of a DICOMDIR, which the
// header reader refuses as an image and the scanner reads for the files it lists.
inline const gdcm::Tag kMediaStorageSopClass(0x0002, 0x0002);
inline constexpr const char* kDirectorySopClass = "1.2.840.10008.1.3.10";

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
  std::string windowProblem;    // why a window it names was left out (the first such), or ""
  std::string geometryProblem;  // DicomSeries::geometryProblem
};

// Reads one file's attributes (pixel data parsed, not decoded). Throws Error with the reason
// to skip it.
FileHeader readHeader(const std::string& path);

// Whether a SOP class UID is one of the Secondary Capture classes (screenshots, summaries).
bool isSecondaryCapture(const std::string& sopClass);

}  // namespace octoray::dicom::detail
