#pragma once
// One interface over both PACS protocols, chosen by the URL:
//   http://HOST[:PORT]/PATH, https://...   DICOMweb (QIDO-RS, WADO-RS): dicomweb.h
//   dicom://CALLED_AET@HOST:PORT           DIMSE (C-ECHO, C-FIND, C-GET): dimse.h
// and the resumable retrieval of a series into a folder through either (retrieve.h).

#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "octoray/pacs/credentials.h"
#include "octoray/pacs/query.h"
#include "octoray/pacs/retrieve.h"

namespace octoray::pacs {

struct PacsOptions {
  Credentials credentials;           // DICOMweb only
  std::string caFile;                // DICOMweb over https: a private CA's PEM
  std::string callingAet = "OCTORAY";  // DIMSE: our AE title
  int timeoutSeconds = 30;
};

class PacsConnection {
 public:
  virtual ~PacsConnection() = default;
  // The server as the user named it, for messages and records (never credentials).
  virtual std::string describe() const = 0;
  // Checks that the server answers (C-ECHO; for DICOMweb a QIDO search with no match).
  virtual void echo() = 0;
  virtual std::vector<StudyRecord> findStudies(const StudyQuery& query) = 0;
  virtual std::vector<SeriesRecord> findSeries(const std::string& studyUid,
                                               const std::string& modality = {}) = 0;
  virtual std::vector<InstanceRecord> findInstances(const std::string& studyUid,
                                                    const std::string& seriesUid) = 0;
  virtual void fetch(const std::string& studyUid, const std::string& seriesUid,
                     const std::vector<std::string>& sopInstanceUids, const InstanceSink& sink) = 0;
};

// Throws octoray::Error for a URL of another scheme or one holding credentials.
std::unique_ptr<PacsConnection> connectPacs(const std::string& url, const PacsOptions& options);

// True for the URLs connectPacs accepts.
bool isPacsUrl(const std::string& text);

// Lists the series' instances and retrieves the missing ones into `folder` (retrieve.h).
RetrieveReport retrieveSeriesInto(PacsConnection& pacs, const std::string& studyUid,
                                  const std::string& seriesUid, const std::filesystem::path& folder,
                                  const std::function<void(int64_t done, int64_t total)>& progress = {});

// For tools that take a DICOMweb series URL as their input (octoray-import
// https://HOST/dicom-web/studies/S/series/R): retrieves that series, resuming, into
// <cacheRoot>/pacs/<S>/<R>/ and returns the folder. The server's instance list is asked every
// time; instances already there and verified are not fetched again. Throws
// octoray::Error when the URL names no series.
std::filesystem::path retrieveSeriesUrl(const std::string& url, const PacsOptions& options,
                                        const std::filesystem::path& cacheRoot,
                                        const std::function<void(int64_t done, int64_t total)>& progress = {});

}  // namespace octoray::pacs
