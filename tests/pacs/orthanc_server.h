#pragma once
// A real Orthanc PACS for the pacs tests: started as a child process with its own
// configuration, storage and index under a test folder, on free ports, with the DICOMweb
// plugin; stopped (and always reaped) by the destructor. Orthanc 1.10 has no option to bind
// its sockets to one address, so both listen on every interface: HTTP answers loopback
// clients only ("RemoteAccessAllowed": false); the DICOM port accepts any caller for the
// life of the test. HTTPS needs the libssl.so shim that tests/CMakeLists.txt builds (Debian 12's
// civetweb looks up an OpenSSL 1.1 name and crashes without it).

#include <sys/types.h>

#include <array>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include "octoray/pacs/query.h"

namespace octoray::test {

struct OrthancOptions {
  bool tls = false;            // HTTPS with a self-signed certificate made by `openssl req`
  std::string user, password;  // when set: HTTP basic auth required, else no auth
};

class OrthancServer {
 public:
  // True when /usr/sbin/Orthanc and the DICOMweb plugin exist (tests skip otherwise).
  static bool available();

  // Starts Orthanc in `workDir` (created; emptied first) and waits (up to 30 s) until
  // GET /system answers. DICOM AET "ORTHANC" accepts any calling AET for C-ECHO, C-FIND,
  // C-GET, C-MOVE and C-STORE. Throws std::runtime_error with the log's tail on failure.
  OrthancServer(const std::filesystem::path& workDir, OrthancOptions options = {});
  // SIGTERM, up to 10 s to exit, then SIGKILL; the child is always reaped.
  ~OrthancServer();
  OrthancServer(const OrthancServer&) = delete;
  OrthancServer& operator=(const OrthancServer&) = delete;

  std::string httpUrl() const;      // "http://127.0.0.1:PORT" (https:// when tls)
  std::string dicomWebUrl() const;  // httpUrl() + "/dicom-web"
  int httpPort() const { return httpPort_; }
  int dicomPort() const { return dicomPort_; }
  std::string aeTitle() const { return "ORTHANC"; }
  // The PEM certificate to trust when tls, else empty.
  std::filesystem::path certificate() const { return certificate_; }
  // Orthanc's stdout and stderr (its log, --verbose).
  std::filesystem::path logFile() const { return workDir_ / "orthanc.log"; }

  // POSTs each DICOM file to /instances (with the credentials when set, trusting
  // certificate()). Throws std::runtime_error naming the file on any non-2xx answer.
  void upload(const std::vector<std::filesystem::path>& files);

 private:
  void start();  // one attempt: fresh folder, ports, configuration, child, readiness
  void stop();   // ends and reaps the child, if any
  std::string logTail() const;

  std::filesystem::path workDir_;
  OrthancOptions options_;
  std::filesystem::path certificate_;
  int httpPort_ = 0;
  int dicomPort_ = 0;
  pid_t pid_ = -1;
};

// ImagePositionPatient and ImageOrientationPatient of each file, by SOPInstanceUID, read by
// GDCM (what a PACS listing must answer for those instances).
struct FileGeometry {
  std::array<double, 3> position{};
  std::array<double, 6> orientation{};
};
std::map<std::string, FileGeometry> geometryOfFiles(const std::vector<std::filesystem::path>& files);

// Checks that every listed instance carries its file's geometry (to 1e-6 mm) and that
// pacs::sortForViewing orders them along the slice normal.
void expectListedGeometry(std::vector<pacs::InstanceRecord> listed, const std::map<std::string, FileGeometry>& files);

}  // namespace octoray::test
