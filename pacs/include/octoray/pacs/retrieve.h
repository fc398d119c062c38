#pragma once
// Retrieving a series into a folder, resumably, whatever the protocol (WADO-RS or C-GET):
//   FOLDER/<SOPInstanceUID>.dcm      one file per instance, written to a hidden temporary and
//                                    renamed, so a file under its final name is complete;
//   FOLDER/.octoray-retrieved.json   written last, only when every instance the server listed
//                                    is present and verified: a folder without it is partial.
// A rerun keeps every instance already present that parses as DICOM with the expected
// SOPInstanceUID and pixel data, and fetches only the others. The record holds the series,
// the instance count and the server's URL (never credentials); no patient identifier.

#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "octoray/pacs/query.h"

namespace octoray::pacs {

// Receives one instance (its SOPInstanceUID and Part-10 bytes). Fetchers call it once per
// instance they deliver, in any order.
using InstanceSink = std::function<void(const std::string& sopInstanceUid, std::vector<uint8_t> part10)>;
// Fetches the listed instances of the series, calling `sink` for each; throws octoray::Error
// when it cannot.
using InstanceFetcher = std::function<void(const std::vector<std::string>& sopInstanceUids,
                                           const InstanceSink& sink)>;

struct RetrieveRequest {
  std::string source;  // the server, for the record and messages (no credentials)
  std::string studyInstanceUid, seriesInstanceUid;
  std::vector<InstanceRecord> instances;  // what the server lists for the series
  std::filesystem::path folder;
  std::function<void(int64_t done, int64_t total)> progress;
};

struct RetrieveReport {
  std::filesystem::path folder;
  int64_t instances = 0;       // listed by the server
  int64_t alreadyPresent = 0;  // kept from an earlier run
  int64_t fetched = 0;         // fetched now
  uint64_t bytesFetched = 0;
  double seconds = 0;
};

inline constexpr const char* kRetrievedRecordName = ".octoray-retrieved.json";

// The name an instance's file has in the folder once it is complete: "<SOPInstanceUID>.dcm".
std::string instanceFileName(const std::string& sopInstanceUid);

// Retrieves the missing instances of `request` through `fetch`. Throws octoray::Error naming
// the folder or the server when the series is not complete at the end (instances missing,
// one delivered that was not asked for or fails verification); what was complete stays for
// the next run, the record is not written.
RetrieveReport retrieveSeries(const RetrieveRequest& request, const InstanceFetcher& fetch);

// True when `folder` holds a completion record whose instance files are all present.
bool isCompleteRetrieval(const std::filesystem::path& folder);

// Checks that `part10` is a DICOM file of instance `sopInstanceUid` with pixel data; returns
// an empty string when it is, else what is wrong.
std::string verifyInstance(const std::vector<uint8_t>& part10, const std::string& sopInstanceUid);

}  // namespace octoray::pacs
