// octoray-pacs: query and retrieve CT from a PACS, over DICOMweb or DIMSE.
//   octoray-pacs echo URL
//   octoray-pacs find URL [--patient-id ID] [--patient-name NAME] [--accession N]
//                         [--date YYYYMMDD[-YYYYMMDD]] [--modality CT] [--study UID] [--json]
//   octoray-pacs get URL --study UID [--series UID] [--modality CT] -o DIR [--json]
// URL: http(s)://HOST/DICOMWEB-ROOT (credentials from --credentials FILE or
// $OCTORAY_PACS_CREDENTIALS, --ca-file PEM for a private CA) or dicom://AET@HOST:PORT
// (--calling-aet, default OCTORAY). `get` writes DIR/<StudyUID>/<SeriesUID>/ per series and
// resumes: instances already there and verified are not fetched again.
#include <CLI/CLI.hpp>
#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <iostream>

#include "cli_support.h"
#include "octoray/core/error.h"
#include "octoray/pacs/connection.h"
#include "octoray/pacs/dicomweb.h"

namespace {

using namespace octoray;

struct Arguments {
  std::string command, url, credentialsFile, caFile, callingAet = "OCTORAY";
  int timeoutSeconds = 30;
  pacs::StudyQuery query;
  std::string date, study, series, modality, output;
  bool json = false;
};

pacs::PacsOptions connectionOptions(const Arguments& a) {
  pacs::PacsOptions o;
  if (pacs::isHttpUrl(a.url)) {
    std::string warning;
    o.credentials = pacs::resolveCredentials(a.credentialsFile, &warning);
    if (!warning.empty()) fmt::print(stderr, "octoray-pacs: warning: {}\n", warning);
  } else if (!a.credentialsFile.empty()) {
    throw Error(a.credentialsFile, "--credentials applies to DICOMweb (http/https) URLs");
  }
  o.caFile = a.caFile;
  o.callingAet = a.callingAet;
  o.timeoutSeconds = a.timeoutSeconds;
  return o;
}

void splitDate(const std::string& date, pacs::StudyQuery& q) {
  if (date.empty()) return;
  const auto dash = date.find('-');
  q.studyDateFrom = date.substr(0, dash);
  q.studyDateTo = dash == std::string::npos ? q.studyDateFrom : date.substr(dash + 1);
  for (const std::string* d : {&q.studyDateFrom, &q.studyDateTo}) {
    if (!d->empty() && (d->size() != 8 || d->find_first_not_of("0123456789") != std::string::npos)) {
      throw Error("", fmt::format("--date \"{}\": expected YYYYMMDD or YYYYMMDD-YYYYMMDD (either end may be empty)", date));
    }
  }
}

int runEcho(const Arguments& a) {
  auto server = pacs::connectPacs(a.url, connectionOptions(a));
  server->echo();
  if (a.json) {
    std::cout << nlohmann::json{{"server", server->describe()}, {"ok", true}}.dump(2) << "\n";
  } else {
    fmt::print("{}: answers\n", server->describe());
  }
  return 0;
}

int runFind(Arguments a) {
  auto server = pacs::connectPacs(a.url, connectionOptions(a));
  if (!a.study.empty()) {
    const auto series = server->findSeries(a.study, a.modality);
    if (a.json) {
      nlohmann::json out = nlohmann::json::array();
      for (const auto& s : series) {
        out.push_back({{"studyInstanceUid", s.studyInstanceUid}, {"seriesInstanceUid", s.seriesInstanceUid},
                       {"modality", s.modality}, {"seriesNumber", s.seriesNumber},
                       {"seriesDescription", s.seriesDescription}, {"instances", s.instanceCount}});
      }
      std::cout << nlohmann::json{{"server", server->describe()}, {"series", out}}.dump(2) << "\n";
    } else {
      fmt::print("{} series in study {}\n", series.size(), a.study);
      for (const auto& s : series) {
        fmt::print("  {:>4} {:<4} {:>5} images  {:<40} {}\n", s.seriesNumber, s.modality,
                   s.instanceCount < 0 ? std::string("?") : std::to_string(s.instanceCount),
                   s.seriesDescription, s.seriesInstanceUid);
      }
    }
    return 0;
  }
  a.query.modality = a.modality;
  splitDate(a.date, a.query);
  const auto studies = server->findStudies(a.query);
  if (a.json) {
    nlohmann::json out = nlohmann::json::array();
    for (const auto& s : studies) {
      out.push_back({{"studyInstanceUid", s.studyInstanceUid}, {"patientId", s.patientId},
                     {"patientName", s.patientName}, {"studyDate", s.studyDate},
                     {"accessionNumber", s.accessionNumber}, {"studyDescription", s.studyDescription},
                     {"modalities", s.modalities}, {"series", s.seriesCount}, {"instances", s.instanceCount}});
    }
    std::cout << nlohmann::json{{"server", server->describe()}, {"studies", out}}.dump(2) << "\n";
  } else {
    fmt::print("{} studies\n", studies.size());
    for (const auto& s : studies) {
      std::string modalities;
      for (const auto& m : s.modalities) modalities += (modalities.empty() ? "" : "/") + m;
      fmt::print("  {} {:<12} {:<24} {:<8} {:<30} {}\n", s.studyDate, s.patientId, s.patientName,
                 modalities, s.studyDescription, s.studyInstanceUid);
    }
  }
  return 0;
}

int runGet(const Arguments& a) {
  auto server = pacs::connectPacs(a.url, connectionOptions(a));
  std::vector<pacs::SeriesRecord> series;
  if (!a.series.empty()) {
    pacs::SeriesRecord one;
    one.studyInstanceUid = a.study;
    one.seriesInstanceUid = a.series;
    series.push_back(one);
  } else {
    series = server->findSeries(a.study, a.modality);
    if (series.empty()) {
      throw Error(server->describe(), fmt::format("study {} has no {}series", a.study,
                                                  a.modality.empty() ? "" : a.modality + " "));
    }
  }
  nlohmann::json reports = nlohmann::json::array();
  for (const auto& s : series) {
    const std::filesystem::path folder = std::filesystem::path(a.output) / a.study / s.seriesInstanceUid;
    cli::ProgressBar bar("retrieving");
    const pacs::RetrieveReport r = pacs::retrieveSeriesInto(
        *server, a.study, s.seriesInstanceUid, folder,
        [&](int64_t done, int64_t total) { bar.update(static_cast<std::size_t>(done), static_cast<std::size_t>(total)); });
    bar.finish();
    reports.push_back({{"seriesInstanceUid", s.seriesInstanceUid}, {"folder", r.folder.string()},
                       {"instances", r.instances}, {"alreadyPresent", r.alreadyPresent},
                       {"fetched", r.fetched}, {"bytesFetched", r.bytesFetched}, {"seconds", r.seconds}});
    if (!a.json) {
      fmt::print("{}: {} instances ({} fetched, {} already there) in {:.1f} s\n", r.folder.string(),
                 r.instances, r.fetched, r.alreadyPresent, r.seconds);
    }
  }
  if (a.json) {
    std::cout << nlohmann::json{{"server", server->describe()}, {"studyInstanceUid", a.study},
                                {"series", reports}}.dump(2) << "\n";
  }
  return 0;
}

void addConnectionOptions(CLI::App* c, Arguments& a) {
  c->add_option("url", a.url, "http(s)://HOST/DICOMWEB-ROOT or dicom://AET@HOST:PORT")->required();
  c->add_option("--credentials", a.credentialsFile,
                "DICOMweb: file holding \"basic USER:PASSWORD\" or \"bearer TOKEN\" "
                "(default: $OCTORAY_PACS_CREDENTIALS)");
  c->add_option("--ca-file", a.caFile, "DICOMweb over https: PEM of a private CA to trust");
  c->add_option("--calling-aet", a.callingAet, "DIMSE: our AE title")->capture_default_str();
  c->add_option("--timeout", a.timeoutSeconds, "seconds before a silent server is given up")
      ->check(CLI::Range(1, 3600))->capture_default_str();
  c->add_flag("--json", a.json, "print the result as JSON");
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"octoray-pacs: query and retrieve CT from a PACS (DICOMweb or DIMSE)"};
  app.footer(
      "Examples:\n"
      "  octoray-pacs echo dicom://ORTHANC@pacs.local:4242\n"
      "  octoray-pacs find https://pacs.local/dicom-web --patient-id 12345 --modality CT\n"
      "  octoray-pacs find https://pacs.local/dicom-web --study 1.2.840.113619.2.55.3.1\n"
      "  octoray-pacs get https://pacs.local/dicom-web --credentials ~/.octoray-pacs \\\n"
      "      --study 1.2.840... --modality CT -o exams/   # ~/.octoray-pacs: basic USER:PASSWORD\n"
      "  octoray-import exams/1.2.840.../ -o head.octoray\n");
  app.require_subcommand(1);
  Arguments a;
  CLI::App* echo = app.add_subcommand("echo", "check that the server answers (C-ECHO, or a QIDO search)");
  addConnectionOptions(echo, a);
  CLI::App* find = app.add_subcommand("find", "search studies, or the series of --study");
  addConnectionOptions(find, a);
  find->add_option("--patient-id", a.query.patientId, "PatientID");
  find->add_option("--patient-name", a.query.patientName, "PatientName (wildcards * ?)");
  find->add_option("--accession", a.query.accessionNumber, "AccessionNumber");
  find->add_option("--date", a.date, "StudyDate YYYYMMDD or a range YYYYMMDD-YYYYMMDD");
  find->add_option("--modality", a.modality, "studies with a series of this modality (CT)");
  find->add_option("--study", a.study, "list the series of this StudyInstanceUID");
  CLI::App* get = app.add_subcommand("get", "retrieve a study's series into DIR, resumably");
  addConnectionOptions(get, a);
  get->add_option("--study", a.study, "StudyInstanceUID")->required();
  get->add_option("--series", a.series, "SeriesInstanceUID (default: every series of the study)");
  get->add_option("--modality", a.modality, "without --series: only series of this modality");
  get->add_option("-o,--output", a.output, "folder to retrieve into")->required();
  CLI11_PARSE(app, argc, argv);
  return cli::runTool("octoray-pacs", [&] {
    if (*echo) return runEcho(a);
    if (*find) return runFind(a);
    return runGet(a);
  });
}
