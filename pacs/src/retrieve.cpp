#include "octoray/pacs/retrieve.h"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>
#include <cstring>
#include <cstdio>
#include <fstream>
#include <set>
#include <sstream>

#include <fmt/format.h>
#include <dcmtk/config/osconfig.h>
#include <dcmtk/dcmdata/dcdeftag.h>
#include <dcmtk/dcmdata/dcfilefo.h>
#include <dcmtk/dcmdata/dcistrmb.h>
#include <nlohmann/json.hpp>

#include "octoray/core/error.h"
#include "dcmtk_log.h"

namespace octoray::pacs {

namespace fs = std::filesystem;

namespace {

std::vector<uint8_t> readFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return {};
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// Writes `bytes` to `path` through a hidden temporary in the same folder, renamed on success.
void writeAtomically(const fs::path& path, const void* bytes, std::size_t size) {
  const fs::path temporary =
      path.parent_path() / fmt::format(".{}.partial-{}", path.filename().string(), ::getpid());
  {
    std::ofstream out(temporary, std::ios::binary | std::ios::trunc);
    out.write(static_cast<const char*>(bytes), static_cast<std::streamsize>(size));
    out.flush();
    if (!out) {
      std::error_code ec;
      fs::remove(temporary, ec);
      throw Error(path.string(), "cannot write (disk full or no permission?)");
    }
  }
  std::error_code ec;
  fs::rename(temporary, path, ec);
  if (ec) {
    fs::remove(temporary, ec);
    throw Error(path.string(), "cannot rename the temporary into place: " + ec.message());
  }
}

// Temporaries a killed run left behind.
void removeStaleTemporaries(const fs::path& folder) {
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(folder, ec)) {
    const std::string name = entry.path().filename().string();
    if (name.starts_with(".") && name.find(".partial-") != std::string::npos) {
      fs::remove(entry.path(), ec);
    }
  }
}

}  // namespace

std::string instanceFileName(const std::string& sopInstanceUid) { return sopInstanceUid + ".dcm"; }

std::string verifyInstance(const std::vector<uint8_t>& part10, const std::string& sopInstanceUid) {
  if (part10.size() < 132 || std::string_view(reinterpret_cast<const char*>(part10.data()) + 128, 4) != "DICM") {
    return "not a DICOM Part-10 file";
  }
  // DCMTK's parser, not GDCM's: GDCM accepts a file cut inside its pixel data (with a warning
  // on stderr); DCMTK's stream reports that the data ended early.
  configureDcmtkLog();
  DcmInputBufferStream stream;
  stream.setBuffer(part10.data(), static_cast<offile_off_t>(part10.size()));
  stream.setEos();
  DcmFileFormat file;
  file.transferInit();
  const OFCondition read = file.read(stream);
  file.transferEnd();
  if (read.bad()) return fmt::format("DICOM file cannot be parsed ({})", read.text());
  DcmDataset* ds = file.getDataset();
  OFString uid;
  if (ds == nullptr || ds->findAndGetOFString(DCM_SOPInstanceUID, uid).bad() || uid.empty()) {
    return "no SOPInstanceUID";
  }
  if (std::string(uid.c_str()) != sopInstanceUid) return fmt::format("holds instance {} instead", uid.c_str());
  if (!ds->tagExistsWithValue(DCM_PixelData)) return "no pixel data";
  return {};
}

bool isCompleteRetrieval(const fs::path& folder) {
  std::ifstream in(folder / kRetrievedRecordName);
  if (!in) return false;
  const nlohmann::json record = nlohmann::json::parse(in, nullptr, false);
  if (!record.is_object() || !record.contains("sopInstanceUids") || !record["sopInstanceUids"].is_array()) {
    return false;
  }
  std::error_code ec;
  for (const auto& uid : record["sopInstanceUids"]) {
    if (!uid.is_string() || !fs::is_regular_file(folder / instanceFileName(uid.get<std::string>()), ec)) {
      return false;
    }
  }
  return true;
}

RetrieveReport retrieveSeries(const RetrieveRequest& request, const InstanceFetcher& fetch) {
  const auto start = std::chrono::steady_clock::now();
  RetrieveReport report;
  report.folder = request.folder;
  report.instances = static_cast<int64_t>(request.instances.size());
  const std::string series = fmt::format("{} series {}", request.source, request.seriesInstanceUid);
  if (request.instances.empty()) throw Error(series, "the server lists no instances");

  std::error_code ec;
  fs::create_directories(request.folder, ec);
  if (ec) throw Error(request.folder.string(), "cannot create the folder: " + ec.message());
  fs::remove(request.folder / kRetrievedRecordName, ec);  // complete again only at the end
  removeStaleTemporaries(request.folder);

  std::set<std::string> wanted;
  std::vector<std::string> missing;
  for (const InstanceRecord& instance : request.instances) {
    const std::string& uid = instance.sopInstanceUid;
    if (!isDicomUid(uid)) {
      throw Error(series, fmt::format("the server lists an invalid SOPInstanceUID \"{}\"", uid));
    }
    if (!wanted.insert(uid).second) continue;
    const fs::path file = request.folder / instanceFileName(uid);
    if (fs::is_regular_file(file, ec) && verifyInstance(readFile(file), uid).empty()) {
      ++report.alreadyPresent;
    } else {
      missing.push_back(uid);
    }
  }
  const auto total = static_cast<int64_t>(wanted.size());
  report.instances = total;
  int64_t done = report.alreadyPresent;
  if (request.progress) request.progress(done, total);

  std::set<std::string> received;
  if (!missing.empty()) {
    fetch(missing, [&](const std::string& uid, std::vector<uint8_t> part10) {
      if (!wanted.contains(uid)) {
        throw Error(series, fmt::format("the server sent instance {}, which it did not list", uid));
      }
      if (const std::string problem = verifyInstance(part10, uid); !problem.empty()) {
        throw Error(series, fmt::format("instance {}: {}", uid, problem));
      }
      writeAtomically(request.folder / instanceFileName(uid), part10.data(), part10.size());
      if (received.insert(uid).second) {
        ++report.fetched;
        report.bytesFetched += part10.size();
        ++done;
        if (request.progress) request.progress(done, total);
      }
    });
  }
  std::vector<std::string> stillMissing;
  for (const std::string& uid : missing) {
    if (!received.contains(uid)) stillMissing.push_back(uid);
  }
  if (!stillMissing.empty()) {
    throw Error(series, fmt::format("{} of {} instances did not arrive (first: {}); run again to "
                                    "fetch only those",
                                    stillMissing.size(), total, stillMissing.front()));
  }

  nlohmann::json record = {{"format", "octoray-retrieved-series"},
                           {"version", 1},
                           {"source", request.source},
                           {"studyInstanceUid", request.studyInstanceUid},
                           {"seriesInstanceUid", request.seriesInstanceUid},
                           {"instances", total},
                           {"sopInstanceUids", std::vector<std::string>(wanted.begin(), wanted.end())}};
  const std::string text = record.dump(2) + "\n";
  writeAtomically(request.folder / kRetrievedRecordName, text.data(), text.size());
  report.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return report;
}

// The orientation as a key: rounded to 1e-4, so that nearly equal orientations group.
static std::array<long long, 6> orientationKey(const std::array<double, 6>& o) {
  std::array<long long, 6> key{};
  for (std::size_t i = 0; i < 6; ++i) key[i] = std::llround(o[i] * 1e4);
  return key;
}

void sortForViewing(std::vector<InstanceRecord>& instances) {
  std::map<std::array<long long, 6>, int> votes;
  std::optional<std::array<double, 6>> majority;
  int best = 0;
  for (const auto& i : instances) {
    if (!i.position || !i.orientation) continue;
    const int n = ++votes[orientationKey(*i.orientation)];
    if (n > best) best = n, majority = i.orientation;
  }
  std::array<double, 3> normal{0, 0, 0};
  if (majority) {
    const auto& o = *majority;
    normal = {o[1] * o[5] - o[2] * o[4], o[2] * o[3] - o[0] * o[5], o[0] * o[4] - o[1] * o[3]};
  }
  auto placed = [&](const InstanceRecord& i) {
    return majority && i.position && i.orientation && orientationKey(*i.orientation) == orientationKey(*majority);
  };
  auto along = [&](const InstanceRecord& i) {
    const auto& p = *i.position;
    return p[0] * normal[0] + p[1] * normal[1] + p[2] * normal[2];
  };
  std::stable_sort(instances.begin(), instances.end(), [&](const InstanceRecord& a, const InstanceRecord& b) {
    const bool pa = placed(a), pb = placed(b);
    if (pa != pb) return pa;
    if (pa && along(a) != along(b)) return along(a) < along(b);
    return a.instanceNumber < b.instanceNumber;  // ties keep the server's order
  });
}

}  // namespace octoray::pacs
