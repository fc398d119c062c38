#pragma once
// A DICOMweb client (PS3.18): QIDO-RS search of studies, series and instances, and WADO-RS
// retrieval of instances as they are stored (multipart/related; type="application/dicom";
// transfer-syntax=* — the original, whatever its transfer syntax). Over libcurl: TLS with
// certificate and host verification always on (a private CA is given as a PEM file, never by
// turning verification off), HTTP basic or bearer authentication from Credentials, timeouts
// for connection and for a stalled transfer. Every failure is an octoray::Error naming the
// server (never the credentials) and what went wrong: unreachable, TLS, 401/403, 404, a body
// cut short, a malformed answer.

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "octoray/pacs/credentials.h"
#include "octoray/pacs/query.h"

namespace octoray::pacs {

struct DicomWebOptions {
  Credentials credentials;
  std::string caFile;               // PEM bundle to trust besides the system's (a private CA)
  int connectTimeoutSeconds = 10;
  int stallTimeoutSeconds = 30;     // abort when under 1 byte/s arrives for this long
};

class DicomWebClient {
 public:
  // `baseUrl`: the service root, e.g. https://pacs.example.org/dicom-web (a trailing slash is
  // dropped). Throws octoray::Error for a URL that is not http(s) or holds user information.
  DicomWebClient(std::string baseUrl, DicomWebOptions options = {});
  ~DicomWebClient();
  DicomWebClient(const DicomWebClient&) = delete;
  DicomWebClient& operator=(const DicomWebClient&) = delete;

  const std::string& baseUrl() const { return baseUrl_; }

  std::vector<StudyRecord> findStudies(const StudyQuery& query);
  std::vector<SeriesRecord> findSeries(const std::string& studyUid,
                                       const std::string& modality = {});
  std::vector<InstanceRecord> findInstances(const std::string& studyUid,
                                            const std::string& seriesUid);

  // One instance as its Part-10 bytes (WADO-RS .../instances/{uid}).
  std::vector<uint8_t> retrieveInstance(const std::string& studyUid, const std::string& seriesUid,
                                        const std::string& sopInstanceUid);

 private:
  struct Response;
  Response get(const std::string& pathAndQuery, const std::string& accept);
  std::vector<uint8_t> retrieveMultipartSingle(const std::string& path);

  std::string baseUrl_;
  DicomWebOptions options_;
  struct Curl;
  std::unique_ptr<Curl> curl_;
};

// A DICOMweb URL split into the service root and the study/series it names:
// ".../dicom-web/studies/S/series/R" -> {".../dicom-web", "S", "R"}; either UID may be empty.
struct DicomWebTarget {
  std::string baseUrl, studyUid, seriesUid;
};
DicomWebTarget parseDicomWebUrl(const std::string& url);

// True for http:// and https:// URLs.
bool isHttpUrl(const std::string& text);

}  // namespace octoray::pacs
