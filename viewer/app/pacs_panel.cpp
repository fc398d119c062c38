#include "pacs_panel.h"

#include <imgui.h>

#include <algorithm>
#include <cstdio>
#include <fstream>

#include <fmt/format.h>

#include "app.h"
#include "octoray/core/error.h"
#include "octoray/pacs/connection.h"
#include "octoray/pacs/dicomweb.h"
#include "util.h"

namespace octoray::viewer {

namespace fs = std::filesystem;

namespace {

fs::path serversFile() { return configDir() / "pacs-servers.json"; }

template <std::size_t N>
void copyTo(char (&buffer)[N], const std::string& text) {
  std::snprintf(buffer, N, "%s", text.c_str());
}

pacs::PacsOptions optionsFor(const PacsServer& server) {
  pacs::PacsOptions o;
  if (pacs::isHttpUrl(server.url)) o.credentials = pacs::resolveCredentials(server.credentialsFile);
  o.caFile = server.caFile;
  o.callingAet = server.callingAet.empty() ? "OCTORAY" : server.callingAet;
  return o;
}

}  // namespace

PacsPanel::PacsPanel() {
  std::ifstream in(serversFile());
  if (!in) return;
  const nlohmann::json j = nlohmann::json::parse(in, nullptr, false);
  if (!j.is_array()) return;
  for (const auto& s : j) {
    if (!s.is_object() || !s.contains("url") || !s["url"].is_string()) continue;
    servers_.push_back({s.value("name", std::string()), s["url"].get<std::string>(),
                        s.value("credentialsFile", std::string()), s.value("caFile", std::string()),
                        s.value("callingAet", std::string("OCTORAY"))});
  }
  if (!servers_.empty()) {
    selected_ = 0;
    copyTo(url_, servers_[0].url);
    copyTo(credentials_, servers_[0].credentialsFile);
    copyTo(ca_, servers_[0].caFile);
    copyTo(aet_, servers_[0].callingAet);
  }
}

PacsPanel::~PacsPanel() {
  // A retrieval stops after the instance it is receiving (what is complete stays for a rerun);
  // a search ends within the connection's timeout.
  cancel_ = true;
  if (job_.valid()) job_.wait();
}

void PacsPanel::saveServers() const {
  nlohmann::json j = nlohmann::json::array();
  for (const auto& s : servers_) {
    j.push_back({{"name", s.name}, {"url", s.url}, {"credentialsFile", s.credentialsFile},
                 {"caFile", s.caFile}, {"callingAet", s.callingAet}});
  }
  std::error_code ec;
  fs::create_directories(configDir(), ec);
  std::ofstream(serversFile()) << j.dump(2) << "\n";
}

PacsServer PacsPanel::current() const { return {url_, url_, credentials_, ca_, aet_}; }

bool PacsPanel::busy() const {
  return job_.valid() && job_.wait_for(std::chrono::seconds(0)) != std::future_status::ready;
}

void PacsPanel::startSearch() {
  if (busy()) return;
  pacs::StudyQuery q;
  q.patientId = patientId_;
  q.patientName = patientName_;
  q.accessionNumber = accession_;
  q.studyDateFrom = dateFrom_;
  q.studyDateTo = dateTo_;
  q.modality = modality_;
  const PacsServer server = current();
  {
    std::lock_guard lock(mutex_);
    error_.clear();
    studies_.clear();
    series_.clear();
    seriesOfStudy_.clear();
  }
  jobName_ = "searching";
  job_ = std::async(std::launch::async, [this, q, server] {
    try {
      auto found = pacs::connectPacs(server.url, optionsFor(server))->findStudies(q);
      std::lock_guard lock(mutex_);
      studies_ = std::move(found);
    } catch (const std::exception& e) {
      std::lock_guard lock(mutex_);
      error_ = e.what();
    }
  });
}

void PacsPanel::startSeries(const std::string& studyUid) {
  if (busy()) return;
  const PacsServer server = current();
  const std::string modality = modality_;
  {
    std::lock_guard lock(mutex_);
    error_.clear();
    series_.clear();
    seriesOfStudy_ = studyUid;
  }
  jobName_ = "listing series";
  job_ = std::async(std::launch::async, [this, server, studyUid, modality] {
    try {
      auto found = pacs::connectPacs(server.url, optionsFor(server))->findSeries(studyUid, modality);
      std::lock_guard lock(mutex_);
      series_ = std::move(found);
    } catch (const std::exception& e) {
      std::lock_guard lock(mutex_);
      error_ = e.what();
    }
  });
}

void PacsPanel::startRetrieve(App& app, const std::string& studyUid, const std::string& seriesUid) {
  if (busy()) return;
  const PacsServer server = current();
  const fs::path folder = app.cacheDir() / "pacs" / studyUid / seriesUid;
  std::string description;
  {
    std::lock_guard lock(mutex_);
    error_.clear();
    incoming_.reset();
    for (const auto& s : series_) {
      if (s.seriesInstanceUid == seriesUid) description = s.seriesDescription;
    }
  }
  incomingOpened_ = false;
  done_ = 0;
  total_ = 0;
  jobName_ = "retrieving";
  job_ = std::async(std::launch::async, [this, server, studyUid, seriesUid, folder, description] {
    std::shared_ptr<IncomingSeries> incoming;
    try {
      auto connection = pacs::connectPacs(server.url, optionsFor(server));
      pacs::RetrieveRequest request;
      request.source = connection->describe();
      request.studyInstanceUid = studyUid;
      request.seriesInstanceUid = seriesUid;
      request.instances = connection->findInstances(studyUid, seriesUid);
      pacs::sortForViewing(request.instances);
      request.folder = folder;
      // What the viewer shows while the files arrive: every slice's place, from the listing.
      incoming = std::make_shared<IncomingSeries>();
      incoming->folder = folder;
      incoming->description = description;
      for (const auto& i : request.instances) {
        incoming->slices.push_back({folder / pacs::instanceFileName(i.sopInstanceUid), i.position, i.orientation});
      }
      {
        std::lock_guard lock(mutex_);
        incoming_ = incoming;
      }
      request.progress = [this](int64_t done, int64_t total) {
        done_ = done;
        total_ = total;
      };
      pacs::retrieveSeries(request, [&](const std::vector<std::string>& uids, const pacs::InstanceSink& sink) {
        connection->fetch(studyUid, seriesUid, uids, [&](const std::string& uid, std::vector<uint8_t> part10) {
          if (cancel_) throw Error(folder.string(), "retrieval cancelled (the viewer closed)");
          sink(uid, std::move(part10));
        });
      });
      incoming->state = IncomingSeries::State::Complete;
    } catch (const std::exception& e) {
      if (incoming) incoming->fail(e.what());
      std::lock_guard lock(mutex_);
      error_ = e.what();
    }
  });
}

void PacsPanel::poll(App& app) {
  std::shared_ptr<IncomingSeries> open;
  {
    std::lock_guard lock(mutex_);
    if (incoming_ && !incomingOpened_) open = incoming_;
  }
  if (open) {
    incomingOpened_ = true;
    app.openIncoming(std::move(open));
  }
  if (!job_.valid() || busy()) return;
  job_.get();
  std::lock_guard lock(mutex_);
  // A failed retrieval whose series is still open is reported by the dataset (in the window);
  // else here.
  const bool shownByDataset = incomingOpened_ && incoming_ && app.dataset() &&
                              app.dataset()->path() == incoming_->folder.string();
  if (!error_.empty() && !shownByDataset) app.messages.push_back(error_);
  incoming_.reset();
}

void PacsPanel::action(App& app, const std::string& name, const nlohmann::json& value) {
  auto text = [&](const char* key) {
    return value.is_object() && value.contains(key) && value[key].is_string() ? value[key].get<std::string>()
                                                                               : std::string();
  };
  if (name == "pacs-server") {
    copyTo(url_, text("url"));
    copyTo(credentials_, text("credentials"));
    copyTo(ca_, text("ca"));
    copyTo(aet_, text("aet").empty() ? std::string("OCTORAY") : text("aet"));
  } else if (name == "pacs-search") {
    copyTo(patientId_, text("patientId"));
    copyTo(patientName_, text("patientName"));
    copyTo(accession_, text("accession"));
    copyTo(dateFrom_, text("dateFrom"));
    copyTo(dateTo_, text("dateTo"));
    copyTo(modality_, text("modality"));
    startSearch();
  } else if (name == "pacs-series") {
    if (!value.is_string()) throw Error("", "action pacs-series: expected a StudyInstanceUID");
    startSeries(value.get<std::string>());
  } else if (name == "pacs-retrieve") {
    if (text("study").empty() || text("series").empty()) {
      throw Error("", "action pacs-retrieve: expected {\"study\": UID, \"series\": UID}");
    }
    startRetrieve(app, text("study"), text("series"));
  } else {
    throw Error("", fmt::format("unknown action \"{}\"", name));
  }
}

nlohmann::json PacsPanel::state() const {
  std::lock_guard lock(mutex_);
  nlohmann::json studies = nlohmann::json::array(), series = nlohmann::json::array();
  for (const auto& s : studies_) studies.push_back(s.studyInstanceUid);
  for (const auto& s : series_) series.push_back({{"uid", s.seriesInstanceUid}, {"instances", s.instanceCount}});
  return {{"server", url_}, {"busy", busy()}, {"studies", studies}, {"series", series},
          {"retrieved", done_.load()}, {"expected", total_.load()}, {"error", error_}};
}

void PacsPanel::draw(App& app, bool* open) {
  ImGui::SetNextWindowSize(ImVec2(760, 620), ImGuiCond_FirstUseEver);
  ImGui::Begin("PACS", open, ImGuiWindowFlags_NoSavedSettings);

  // Servers.
  if (ImGui::BeginCombo("Server", selected_ >= 0 && selected_ < static_cast<int>(servers_.size())
                                      ? servers_[static_cast<std::size_t>(selected_)].name.c_str()
                                      : "(new)")) {
    for (std::size_t i = 0; i < servers_.size(); ++i) {
      if (ImGui::Selectable(servers_[i].name.c_str(), selected_ == static_cast<int>(i))) {
        selected_ = static_cast<int>(i);
        copyTo(url_, servers_[i].url);
        copyTo(credentials_, servers_[i].credentialsFile);
        copyTo(ca_, servers_[i].caFile);
        copyTo(aet_, servers_[i].callingAet);
      }
    }
    ImGui::EndCombo();
  }
  ImGui::SameLine();
  if (ImGui::Button("Save server") && url_[0] != 0) {
    PacsServer s = current();
    auto it = std::find_if(servers_.begin(), servers_.end(), [&](const auto& x) { return x.url == s.url; });
    if (it == servers_.end()) {
      servers_.push_back(s);
      selected_ = static_cast<int>(servers_.size()) - 1;
    } else {
      *it = s;
    }
    saveServers();
  }
  ImGui::SameLine();
  if (ImGui::Button("Remove") && selected_ >= 0 && selected_ < static_cast<int>(servers_.size())) {
    servers_.erase(servers_.begin() + selected_);
    selected_ = -1;
    saveServers();
  }
  ImGui::InputText("URL", url_, sizeof url_);
  ImGui::TextDisabled("https://HOST/dicom-web (DICOMweb) or dicom://AET@HOST:PORT (DIMSE)");
  ImGui::InputText("Credentials file", credentials_, sizeof credentials_);
  ImGui::TextDisabled("a file holding \"basic USER:PASSWORD\" or \"bearer TOKEN\"; empty: $OCTORAY_PACS_CREDENTIALS");
  ImGui::InputText("CA file (https)", ca_, sizeof ca_);
  ImGui::InputText("Our AE title (DIMSE)", aet_, sizeof aet_);
  ImGui::Separator();

  // Query.
  ImGui::PushItemWidth(150);
  ImGui::InputText("Patient ID", patientId_, sizeof patientId_);
  ImGui::SameLine();
  ImGui::InputText("Name", patientName_, sizeof patientName_);
  ImGui::SameLine();
  ImGui::InputText("Accession", accession_, sizeof accession_);
  ImGui::InputText("Date from", dateFrom_, sizeof dateFrom_);
  ImGui::SameLine();
  ImGui::InputText("to", dateTo_, sizeof dateTo_);
  ImGui::SameLine();
  ImGui::InputText("Modality", modality_, sizeof modality_);
  ImGui::PopItemWidth();
  const bool running = busy();
  if (running) ImGui::BeginDisabled();
  if (ImGui::Button("Search")) startSearch();
  if (running) ImGui::EndDisabled();
  if (running) {
    ImGui::SameLine();
    if (jobName_ == "retrieving" && total_ > 0) {
      const float f = static_cast<float>(done_.load()) / static_cast<float>(total_.load());
      ImGui::ProgressBar(f, ImVec2(-1, 0), fmt::format("retrieving {} of {}", done_.load(), total_.load()).c_str());
    } else {
      ImGui::TextDisabled("%s\u2026", jobName_.c_str());
    }
  }

  std::string clicked, retrieve, retrieveStudy;
  {
  std::lock_guard lock(mutex_);
  if (!error_.empty()) ImGui::TextColored(ImVec4(1, 0.45f, 0.45f, 1), "%s", error_.c_str());
  // Studies.
  if (ImGui::BeginTable("studies", 6, ImGuiTableFlags_Borders | ImGuiTableFlags_RowBg | ImGuiTableFlags_ScrollY,
                        ImVec2(0, 160))) {
    ImGui::TableSetupColumn("Date");
    ImGui::TableSetupColumn("Patient ID");
    ImGui::TableSetupColumn("Name");
    ImGui::TableSetupColumn("Modalities");
    ImGui::TableSetupColumn("Description");
    ImGui::TableSetupColumn("Series");
    ImGui::TableHeadersRow();
    for (const auto& s : studies_) {
      ImGui::TableNextRow();
      ImGui::TableNextColumn();
      const bool isOpen = s.studyInstanceUid == seriesOfStudy_;
      if (ImGui::Selectable((s.studyDate + "##" + s.studyInstanceUid).c_str(), isOpen,
                            ImGuiSelectableFlags_SpanAllColumns) && !running) {
        clicked = s.studyInstanceUid;
      }
      ImGui::TableNextColumn();
      ImGui::TextUnformatted(s.patientId.c_str());
      ImGui::TableNextColumn();
      ImGui::TextUnformatted(s.patientName.c_str());
      ImGui::TableNextColumn();
      std::string modalities;
      for (const auto& m : s.modalities) modalities += (modalities.empty() ? "" : "/") + m;
      ImGui::TextUnformatted(modalities.c_str());
      ImGui::TableNextColumn();
      ImGui::TextUnformatted(s.studyDescription.c_str());
      ImGui::TableNextColumn();
      ImGui::Text("%s", s.seriesCount < 0 ? "?" : std::to_string(s.seriesCount).c_str());
    }
    ImGui::EndTable();
  }
  // Series of the chosen study.
  if (!seriesOfStudy_.empty() &&
      ImGui::BeginTable("series", 5, ImGuiTableFlags_Borders | ImGuiTableFlags_RowBg | ImGuiTableFlags_ScrollY,
                        ImVec2(0, 150))) {
    ImGui::TableSetupColumn("#");
    ImGui::TableSetupColumn("Modality");
    ImGui::TableSetupColumn("Images");
    ImGui::TableSetupColumn("Description");
    ImGui::TableSetupColumn("");
    ImGui::TableHeadersRow();
    retrieveStudy = seriesOfStudy_;
    for (const auto& s : series_) {
      ImGui::TableNextRow();
      ImGui::TableNextColumn();
      ImGui::TextUnformatted(s.seriesNumber.c_str());
      ImGui::TableNextColumn();
      ImGui::TextUnformatted(s.modality.c_str());
      ImGui::TableNextColumn();
      ImGui::Text("%s", s.instanceCount < 0 ? "?" : std::to_string(s.instanceCount).c_str());
      ImGui::TableNextColumn();
      ImGui::TextUnformatted(s.seriesDescription.c_str());
      ImGui::TableNextColumn();
      if (running) ImGui::BeginDisabled();
      if (ImGui::SmallButton(("Retrieve and open##" + s.seriesInstanceUid).c_str())) retrieve = s.seriesInstanceUid;
      if (running) ImGui::EndDisabled();
    }
    ImGui::EndTable();
  }
  }
  if (!clicked.empty()) startSeries(clicked);
  if (!retrieve.empty()) startRetrieve(app, retrieveStudy, retrieve);
  ImGui::End();
}

}  // namespace octoray::viewer
