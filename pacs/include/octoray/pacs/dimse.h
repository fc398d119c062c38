#pragma once
// DIMSE, the PACS protocol of DICOM's network part (PS3.7), through DCMTK's dcmnet: C-ECHO,
// C-FIND in the Study Root model (study, series and image level) and C-GET of a series or
// some of its instances, received in whatever transfer syntax the server sends.
// Each call opens its own association and releases it. DCMTK's own log is off unless
// OCTORAY_DCMTK_LOG names a level (trace, debug, info, warn, error); at debug and below it
// prints datasets, patient data included.

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "octoray/pacs/query.h"

namespace octoray::pacs {

struct DimseEndpoint {
  std::string host;
  int port = 104;
  std::string calledAet = "ANY-SCP";   // the server's AE title
  std::string callingAet = "OCTORAY";  // ours
  int timeoutSeconds = 30;             // connecting, association, and each message
};

// Parses "dicom://CALLED_AET@HOST[:PORT]" (port 104 when absent); the calling AE title stays
// the default. Throws octoray::Error for anything else.
DimseEndpoint parseDimseUrl(const std::string& url);
// "dicom://CALLED_AET@HOST:PORT", the name errors give the server.
std::string dimseUrl(const DimseEndpoint& endpoint);

// Each call throws octoray::Error named by dimseUrl() when the server cannot be reached
// (connection refused, no answer within the timeout), rejects the association (with its
// reason), does not offer the service, or answers with a failure status.
void dimseEcho(const DimseEndpoint& endpoint);
std::vector<StudyRecord> dimseFindStudies(const DimseEndpoint& endpoint, const StudyQuery& query);
std::vector<SeriesRecord> dimseFindSeries(const DimseEndpoint& endpoint,
                                          const std::string& studyUid,
                                          const std::string& modality = {});
std::vector<InstanceRecord> dimseFindInstances(const DimseEndpoint& endpoint,
                                               const std::string& studyUid,
                                               const std::string& seriesUid);

// C-GET of the series' instances (`onlyInstances`, or all when empty): `store` receives each
// one as a Part-10 file, in the transfer syntax it came in, as it arrives; `progress` gets
// (instances received, instances expected). An image-level C-FIND comes first: it lists the
// instances to expect when `onlyInstances` is empty, tells which storage SOP classes to accept,
// and UIDs of `onlyInstances` it does not list are not requested. Throws octoray::Error when
// the association fails or when, at the end, an expected instance has not arrived ("delivered
// N of M"); an exception from `store` aborts the retrieval and propagates.
void dimseGetSeries(const DimseEndpoint& endpoint, const std::string& studyUid,
                    const std::string& seriesUid, const std::vector<std::string>& onlyInstances,
                    const std::function<void(const std::string& sopInstanceUid,
                                             std::vector<uint8_t> part10)>& store,
                    const std::function<void(int64_t done, int64_t total)>& progress = {});

}  // namespace octoray::pacs
