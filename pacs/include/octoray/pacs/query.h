#pragma once
// What a PACS query asks and answers, the same for DICOMweb (QIDO-RS) and DIMSE (C-FIND):
// a study-level filter, and the studies, series and instances found.

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace octoray::pacs {

// Empty fields do not filter. Patient name and accession number may hold DICOM wildcards
// (* and ?). Dates are YYYYMMDD; either end of the range may be empty.
struct StudyQuery {
  std::string patientId;
  std::string patientName;
  std::string accessionNumber;
  std::string studyDateFrom, studyDateTo;
  std::string modality;  // "CT": studies with a series of that modality (ModalitiesInStudy)
  std::string studyInstanceUid;
};

struct StudyRecord {
  std::string studyInstanceUid;
  std::string patientId;
  std::string patientName;
  std::string studyDate;
  std::string accessionNumber;
  std::string studyDescription;
  std::vector<std::string> modalities;  // ModalitiesInStudy
  int64_t seriesCount = -1;             // -1: the server did not say
  int64_t instanceCount = -1;
};

struct SeriesRecord {
  std::string studyInstanceUid;
  std::string seriesInstanceUid;
  std::string modality;
  std::string seriesNumber;
  std::string seriesDescription;
  int64_t instanceCount = -1;  // -1: the server did not say
};

// A DICOM UID as it may appear in a URL path or a file name: 1..64 characters, digits
// separated by single dots, starting and ending with a digit (PS3.5 9.1).
inline bool isDicomUid(const std::string& uid) {
  if (uid.empty() || uid.size() > 64 || uid.front() == '.' || uid.back() == '.') return false;
  for (std::size_t i = 0; i < uid.size(); ++i) {
    const char c = uid[i];
    if (c == '.' ? uid[i - 1] == '.' : (c < '0' || c > '9')) return false;
  }
  return true;
}

struct InstanceRecord {
  std::string sopInstanceUid;
  std::string sopClassUid;
  int64_t instanceNumber = -1;
  // ImagePositionPatient and ImageOrientationPatient, where the server answers them (both are
  // instance-level keys PACS index, Orthanc and dcm4chee among them): they place each slice
  // before its pixels arrive, so a viewer can show the series while it is retrieved.
  std::optional<std::array<double, 3>> position;
  std::optional<std::array<double, 6>> orientation;
};

// Orders `instances` along the slice normal (the majority orientation's; instances of another
// orientation or without a position go last, by InstanceNumber) so that a retrieval delivers a
// stack from one end to the other; without positions, by InstanceNumber (ties keep the
// server's order).
void sortForViewing(std::vector<InstanceRecord>& instances);

}  // namespace octoray::pacs
