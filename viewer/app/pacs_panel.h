#pragma once
// The PACS panel (File > PACS…): a list of servers (DICOMweb or DIMSE URLs; only the path of
// a credentials file is kept, never a secret), a study query (patient ID, name, accession
// number, study date range, modality), the studies and series found, and "Retrieve and open":
// the series is retrieved in the background into the cache folder (resumably, pacs/retrieve.h)
// with a progress bar, in order along the slice normal, and opened as soon as the server has
// listed its instances: each slice appears in the MPR views as its file lands (dataset.h's
// IncomingSeries), the import starts when the last one has, and the 3D view when its store
// is built. Network work never runs on the render thread.

#include <atomic>
#include <cstdint>
#include <filesystem>
#include <future>
#include <mutex>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "octoray/pacs/query.h"
#include "octoray/viewer/dataset.h"

namespace octoray::viewer {

class App;

struct PacsServer {
  std::string name, url;
  std::string credentialsFile;  // a file holding "basic USER:PASSWORD" or "bearer TOKEN"
  std::string caFile;           // a private CA's PEM (https)
  std::string callingAet = "OCTORAY";
};

class PacsPanel {
 public:
  // Loads the server list from <config>/pacs-servers.json.
  PacsPanel();
  ~PacsPanel();  // stops a running retrieval after its current instance; waits for the job
  PacsPanel(const PacsPanel&) = delete;
  PacsPanel& operator=(const PacsPanel&) = delete;

  void draw(App& app, bool* open);
  // Each frame: a finished job's results or error; a finished retrieval opens the series.
  void poll(App& app);
  bool busy() const;
  // A job runs or its result has not been taken by poll() yet.
  bool pending() const { return job_.valid(); }
  // Script actions: "pacs-server" {"url", "credentials"?, "ca"?, "aet"?}, "pacs-search"
  // {"patientId"?, "patientName"?, "accession"?, "dateFrom"?, "dateTo"?, "modality"?},
  // "pacs-series" "STUDY_UID", "pacs-retrieve" {"study", "series"}.
  void action(App& app, const std::string& name, const nlohmann::json& value);
  nlohmann::json state() const;

 private:
  void startSearch();
  void startSeries(const std::string& studyUid);
  void startRetrieve(App& app, const std::string& studyUid, const std::string& seriesUid);
  void saveServers() const;
  PacsServer current() const;

  std::vector<PacsServer> servers_;
  int selected_ = -1;
  // The form (ImGui edits these buffers).
  char url_[512] = "", credentials_[512] = "", ca_[512] = "", aet_[17] = "OCTORAY";
  char patientId_[65] = "", patientName_[65] = "", accession_[17] = "", dateFrom_[9] = "",
       dateTo_[9] = "", modality_[17] = "CT";

  mutable std::mutex mutex_;  // guards what jobs write: results, error, retrieved folder
  std::future<void> job_;
  std::string jobName_;
  std::vector<pacs::StudyRecord> studies_;
  std::vector<pacs::SeriesRecord> series_;
  std::string seriesOfStudy_;
  std::string error_;
  std::shared_ptr<IncomingSeries> incoming_;  // listed by a retrieval, opened by poll()
  bool incomingOpened_ = false;                 // the running retrieval's series is open
  std::atomic<int64_t> done_{0}, total_{0};
  std::atomic<bool> cancel_{false};  // set by the destructor
};

}  // namespace octoray::viewer
