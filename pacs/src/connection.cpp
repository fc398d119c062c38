#include "octoray/pacs/connection.h"


#include <fmt/format.h>

#include "octoray/core/error.h"
#include "octoray/core/text.h"
#include "octoray/pacs/dicomweb.h"
#include "octoray/pacs/dimse.h"

namespace octoray::pacs {

namespace {

class DicomWebConnection final : public PacsConnection {
 public:
  DicomWebConnection(const std::string& url, const PacsOptions& options)
      : client_(url, DicomWebOptions{options.credentials, options.caFile, 10, options.timeoutSeconds}) {}
  std::string describe() const override { return client_.baseUrl(); }
  void echo() override {
    StudyQuery nothing;
    nothing.studyInstanceUid = "1.2.3.4.5.6.7.8.9.0.1.2.3.4.5.6.7.8.9";
    client_.findStudies(nothing);
  }
  std::vector<StudyRecord> findStudies(const StudyQuery& query) override {
    return client_.findStudies(query);
  }
  std::vector<SeriesRecord> findSeries(const std::string& studyUid, const std::string& modality) override {
    return client_.findSeries(studyUid, modality);
  }
  std::vector<InstanceRecord> findInstances(const std::string& studyUid,
                                            const std::string& seriesUid) override {
    return client_.findInstances(studyUid, seriesUid);
  }
  void fetch(const std::string& studyUid, const std::string& seriesUid,
             const std::vector<std::string>& sopInstanceUids, const InstanceSink& sink) override {
    for (const std::string& uid : sopInstanceUids) {
      sink(uid, client_.retrieveInstance(studyUid, seriesUid, uid));
    }
  }

 private:
  DicomWebClient client_;
};

class DimseConnection final : public PacsConnection {
 public:
  DimseConnection(const std::string& url, const PacsOptions& options)
      : url_(url), endpoint_(parseDimseUrl(url)) {
    endpoint_.callingAet = options.callingAet;
    endpoint_.timeoutSeconds = options.timeoutSeconds;
  }
  std::string describe() const override { return url_; }
  void echo() override { dimseEcho(endpoint_); }
  std::vector<StudyRecord> findStudies(const StudyQuery& query) override {
    return dimseFindStudies(endpoint_, query);
  }
  std::vector<SeriesRecord> findSeries(const std::string& studyUid, const std::string& modality) override {
    return dimseFindSeries(endpoint_, studyUid, modality);
  }
  std::vector<InstanceRecord> findInstances(const std::string& studyUid,
                                            const std::string& seriesUid) override {
    return dimseFindInstances(endpoint_, studyUid, seriesUid);
  }
  void fetch(const std::string& studyUid, const std::string& seriesUid,
             const std::vector<std::string>& sopInstanceUids, const InstanceSink& sink) override {
    dimseGetSeries(endpoint_, studyUid, seriesUid, sopInstanceUids,
                   [&](const std::string& uid, std::vector<uint8_t> part10) { sink(uid, std::move(part10)); });
  }

 private:
  std::string url_;
  DimseEndpoint endpoint_;
};

}  // namespace

bool isPacsUrl(const std::string& text) {
  return isHttpUrl(text) || asciiLower(text.substr(0, 8)) == "dicom://";
}

std::unique_ptr<PacsConnection> connectPacs(const std::string& url, const PacsOptions& options) {
  if (isHttpUrl(url)) return std::make_unique<DicomWebConnection>(url, options);
  if (asciiLower(url.substr(0, 8)) == "dicom://") {
    if (options.credentials.kind != Credentials::Kind::None) {
      throw Error(url, "credentials apply to DICOMweb (http/https), not to DIMSE");
    }
    return std::make_unique<DimseConnection>(url, options);
  }
  throw Error(url, "not a PACS URL: expected http(s)://HOST/DICOMWEB-ROOT or dicom://AET@HOST:PORT");
}

RetrieveReport retrieveSeriesInto(PacsConnection& pacs, const std::string& studyUid,
                                  const std::string& seriesUid, const std::filesystem::path& folder,
                                  const std::function<void(int64_t done, int64_t total)>& progress) {
  RetrieveRequest request;
  request.source = pacs.describe();
  request.studyInstanceUid = studyUid;
  request.seriesInstanceUid = seriesUid;
  request.instances = pacs.findInstances(studyUid, seriesUid);
  sortForViewing(request.instances);
  request.folder = folder;
  request.progress = progress;
  return retrieveSeries(request, [&](const std::vector<std::string>& uids, const InstanceSink& sink) {
    pacs.fetch(studyUid, seriesUid, uids, sink);
  });
}

std::filesystem::path retrieveSeriesUrl(const std::string& url, const PacsOptions& options,
                                        const std::filesystem::path& cacheRoot,
                                        const std::function<void(int64_t done, int64_t total)>& progress) {
  const DicomWebTarget target = parseDicomWebUrl(url);
  if (target.seriesUid.empty()) {
    throw Error(target.baseUrl, "the URL names no series: expected .../studies/STUDY_UID/series/SERIES_UID");
  }
  auto pacs = connectPacs(target.baseUrl, options);
  const std::filesystem::path folder = cacheRoot / "pacs" / target.studyUid / target.seriesUid;
  retrieveSeriesInto(*pacs, target.studyUid, target.seriesUid, folder, progress);
  return folder;
}

}  // namespace octoray::pacs
