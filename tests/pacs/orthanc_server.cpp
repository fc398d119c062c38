#include "orthanc_server.h"

#include <curl/curl.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <fstream>
#include <iterator>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <sstream>
#include <stdexcept>
#include <thread>

#include <gdcmReader.h>
#include <gtest/gtest.h>

#include "run_process.h"

extern char** environ;

namespace octoray::test {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

const fs::path kOrthanc = "/usr/sbin/Orthanc";
const fs::path kDicomWebPlugin = "/usr/share/orthanc/plugins/libOrthancDicomWeb.so";
const fs::path kOpenSsl = "/usr/bin/openssl";
constexpr auto kStartTimeout = std::chrono::seconds(30);
constexpr auto kStopTimeout = std::chrono::seconds(10);

// The child ended before answering: worth one more try on other ports (another process may
// have taken one between our probe and Orthanc's bind).
struct ExitedEarly : std::runtime_error {
  using std::runtime_error::runtime_error;
};

std::string readFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error("cannot read " + path.string());
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// Free TCP ports on 127.0.0.1, distinct: each probe socket stays bound until all are read.
std::vector<int> freeLoopbackPorts(int count) {
  std::vector<int> sockets, ports;
  for (int i = 0; i < count; ++i) {
    const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    socklen_t length = sizeof address;
    if (fd < 0 || ::bind(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) != 0 ||
        ::getsockname(fd, reinterpret_cast<sockaddr*>(&address), &length) != 0) {
      const std::string reason = std::strerror(errno);
      if (fd >= 0) ::close(fd);
      for (int s : sockets) ::close(s);
      throw std::runtime_error("cannot find a free port on 127.0.0.1: " + reason);
    }
    sockets.push_back(fd);
    ports.push_back(ntohs(address.sin_port));
  }
  for (int s : sockets) ::close(s);
  return ports;
}

// One libcurl easy handle, set up for our server: no proxy, the credentials and the CA file.
class HttpClient {
 public:
  HttpClient(const OrthancOptions& options, const fs::path& certificate) {
    static std::once_flag globalInit;
    std::call_once(globalInit, [] { curl_global_init(CURL_GLOBAL_DEFAULT); });
    curl_.reset(curl_easy_init());
    if (!curl_) throw std::runtime_error("curl_easy_init failed");
    CURL* c = curl_.get();
    curl_easy_setopt(c, CURLOPT_NOPROXY, "*");
    curl_easy_setopt(c, CURLOPT_NOSIGNAL, 1L);
    curl_easy_setopt(c, CURLOPT_CONNECTTIMEOUT_MS, 2000L);
    curl_easy_setopt(c, CURLOPT_TIMEOUT, 60L);
    curl_easy_setopt(c, CURLOPT_ERRORBUFFER, error_);
    curl_easy_setopt(c, CURLOPT_WRITEFUNCTION, &HttpClient::collect);
    curl_easy_setopt(c, CURLOPT_WRITEDATA, &body_);
    if (!options.user.empty()) {
      curl_easy_setopt(c, CURLOPT_HTTPAUTH, static_cast<long>(CURLAUTH_BASIC));
      curl_easy_setopt(c, CURLOPT_USERNAME, options.user.c_str());
      curl_easy_setopt(c, CURLOPT_PASSWORD, options.password.c_str());
    }
    if (!certificate.empty()) curl_easy_setopt(c, CURLOPT_CAINFO, certificate.c_str());
    headers_.reset(curl_slist_append(nullptr, "Content-Type: application/dicom"));
  }

  // GET (body null) or POST; returns the HTTP status, throws when no answer came.
  long request(const std::string& url, const std::string* postBody) {
    CURL* c = curl_.get();
    body_.clear();
    error_[0] = '\0';
    curl_easy_setopt(c, CURLOPT_URL, url.c_str());
    if (postBody) {
      curl_easy_setopt(c, CURLOPT_POST, 1L);
      curl_easy_setopt(c, CURLOPT_HTTPHEADER, headers_.get());
      curl_easy_setopt(c, CURLOPT_POSTFIELDS, postBody->data());
      curl_easy_setopt(c, CURLOPT_POSTFIELDSIZE_LARGE, static_cast<curl_off_t>(postBody->size()));
    } else {
      curl_easy_setopt(c, CURLOPT_HTTPGET, 1L);
      curl_easy_setopt(c, CURLOPT_HTTPHEADER, nullptr);
    }
    const CURLcode rc = curl_easy_perform(c);
    if (rc != CURLE_OK) {
      throw std::runtime_error(url + ": " + (error_[0] ? error_ : curl_easy_strerror(rc)));
    }
    long status = 0;
    curl_easy_getinfo(c, CURLINFO_RESPONSE_CODE, &status);
    return status;
  }
  const std::string& body() const { return body_; }

 private:
  static size_t collect(char* data, size_t size, size_t count, void* sink) {
    static_cast<std::string*>(sink)->append(data, size * count);
    return size * count;
  }
  struct CurlFree {
    void operator()(CURL* c) const { curl_easy_cleanup(c); }
    void operator()(curl_slist* l) const { curl_slist_free_all(l); }
  };
  std::unique_ptr<CURL, CurlFree> curl_;
  std::unique_ptr<curl_slist, CurlFree> headers_;
  std::string body_;
  char error_[CURL_ERROR_SIZE] = {};
};

// A self-signed certificate for 127.0.0.1; returns the PEM Orthanc serves (key + certificate).
fs::path makeCertificate(const fs::path& dir, const fs::path& certificate) {
  const fs::path key = dir / "server-key.pem";
  const ProcessResult made =
      runProcess({kOpenSsl.string(), "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout",
                  key.string(), "-out", certificate.string(), "-days", "2", "-subj",
                  "/CN=127.0.0.1", "-addext", "subjectAltName=IP:127.0.0.1,DNS:localhost"});
  if (made.exitCode != 0) {
    throw std::runtime_error("openssl req could not make a test certificate: " + made.err);
  }
  const fs::path combined = dir / "server.pem";
  std::ofstream(combined, std::ios::binary) << readFile(key) << readFile(certificate);
  return combined;
}

// The HTTP port answers loopback clients only; the DICOM port (no bind option in Orthanc 1.10)
// accepts any calling AET.
nlohmann::json makeConfiguration(const fs::path& dir, int httpPort, int dicomPort,
                                 const OrthancOptions& options, const fs::path& sslPem) {
  nlohmann::json config = {
      {"Name", "octoray-test"},
      {"StorageDirectory", (dir / "storage").string()},
      {"IndexDirectory", (dir / "index").string()},
      {"Plugins", {kDicomWebPlugin.string()}},
      {"LuaScripts", nlohmann::json::array()},
      {"HttpPort", httpPort},
      {"RemoteAccessAllowed", false},
      {"AuthenticationEnabled", !options.user.empty()},
      {"SslEnabled", options.tls},
      {"HttpThreadsCount", 8},
      {"OrthancExplorerEnabled", false},
      {"WebDavEnabled", false},
      {"DicomServerEnabled", true},
      {"DicomPort", dicomPort},
      {"DicomAet", "ORTHANC"},
      {"DicomCheckCalledAet", false},
      {"DicomAlwaysAllowEcho", true},
      {"DicomAlwaysAllowFind", true},
      {"DicomAlwaysAllowGet", true},
      {"DicomAlwaysAllowMove", true},
      {"DicomAlwaysAllowStore", true},
      {"DicomModalities", nlohmann::json::object()},
      {"DicomThreadsCount", 2},
      {"ConcurrentJobs", 1},
      {"SaveJobs", false},
      {"DicomWeb",
       {{"Enable", true},
        {"Root", "/dicom-web/"},
        {"EnableWado", true},
        {"Host", "127.0.0.1:" + std::to_string(httpPort)},
        {"Ssl", options.tls}}},
  };
  if (!options.user.empty()) config["RegisteredUsers"] = {{options.user, options.password}};
  if (options.tls) config["SslCertificate"] = sslPem.string();
  return config;
}

// This process's environment, with `libraryDir` (when set) first on LD_LIBRARY_PATH, and
// TCP_NODELAY=1, which turns Nagle's algorithm off in Orthanc's DICOM server (dcmnet): without
// it every DIMSE answer waits 40 ms for a delayed ACK.
std::vector<std::string> childEnvironment(const std::string& libraryDir) {
  std::vector<std::string> variables = {"TCP_NODELAY=1"};
  std::string libraryPath = libraryDir;
  for (char** variable = environ; *variable; ++variable) {
    const std::string entry = *variable;
    if (entry.rfind("TCP_NODELAY=", 0) == 0) continue;
    if (entry.rfind("LD_LIBRARY_PATH=", 0) == 0) {
      const std::string inherited = entry.substr(std::strlen("LD_LIBRARY_PATH="));
      if (libraryPath.empty()) {
        libraryPath = inherited;
      } else if (!inherited.empty()) {
        libraryPath += ":" + inherited;
      }
    } else {
      variables.push_back(entry);
    }
  }
  if (!libraryPath.empty()) variables.push_back("LD_LIBRARY_PATH=" + libraryPath);
  return variables;
}

// fork + exec with stdout/stderr into `log`; the child gets SIGTERM when this thread ends.
pid_t spawnOrthanc(const fs::path& config, const fs::path& log, const std::string& libraryDir) {
  // Everything the child needs is prepared here: between fork and exec it may not allocate.
  const std::string program = kOrthanc.string(), verbose = "--verbose", configArg = config.string();
  char* const argv[] = {const_cast<char*>(program.c_str()), const_cast<char*>(verbose.c_str()),
                        const_cast<char*>(configArg.c_str()), nullptr};
  const std::vector<std::string> variables = childEnvironment(libraryDir);
  std::vector<char*> envp;
  for (const auto& variable : variables) envp.push_back(const_cast<char*>(variable.c_str()));
  envp.push_back(nullptr);
  const int logFd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
  const int nullFd = ::open("/dev/null", O_RDONLY | O_CLOEXEC);
  if (logFd < 0 || nullFd < 0) {
    const std::string reason = std::strerror(errno);
    if (logFd >= 0) ::close(logFd);
    if (nullFd >= 0) ::close(nullFd);
    throw std::runtime_error("cannot open " + log.string() + ": " + reason);
  }
  const pid_t parent = ::getpid();
  const pid_t pid = ::fork();
  if (pid == 0) {
    // Never outlive the test binary, even when it is killed.
    ::prctl(PR_SET_PDEATHSIG, SIGTERM);
    if (::getppid() != parent) ::_exit(127);
    ::dup2(nullFd, STDIN_FILENO);
    ::dup2(logFd, STDOUT_FILENO);
    ::dup2(logFd, STDERR_FILENO);
    ::close_range(3, ~0U, 0);
    ::execve(argv[0], argv, envp.data());
    ::_exit(127);
  }
  const int forkErrno = errno;
  ::close(logFd);
  ::close(nullFd);
  if (pid < 0) throw std::runtime_error(std::string("fork: ") + std::strerror(forkErrno));
  return pid;
}

}  // namespace

bool OrthancServer::available() { return fs::exists(kOrthanc) && fs::exists(kDicomWebPlugin); }

OrthancServer::OrthancServer(const std::filesystem::path& workDir, OrthancOptions options)
    : workDir_(workDir), options_(std::move(options)) {
  if (workDir_.empty() || workDir_ == workDir_.root_path()) {
    throw std::runtime_error("OrthancServer: refusing to empty '" + workDir_.string() + "'");
  }
  if (!available()) {
    throw std::runtime_error(kOrthanc.string() + " or " + kDicomWebPlugin.string() +
                             " is not installed");
  }
  for (int attempt = 1;; ++attempt) {
    try {
      start();
      return;
    } catch (const ExitedEarly&) {
      stop();
      if (attempt == 2) throw;
    } catch (...) {
      stop();
      throw;
    }
  }
}

OrthancServer::~OrthancServer() { stop(); }

std::string OrthancServer::httpUrl() const {
  return std::string(options_.tls ? "https" : "http") + "://127.0.0.1:" + std::to_string(httpPort_);
}

std::string OrthancServer::dicomWebUrl() const { return httpUrl() + "/dicom-web"; }

void OrthancServer::start() {
  fs::remove_all(workDir_);
  fs::create_directories(workDir_);
  fs::path sslPem;
  certificate_.clear();
  if (options_.tls) {
    certificate_ = workDir_ / "certificate.pem";
    sslPem = makeCertificate(workDir_, certificate_);
  }
  const std::vector<int> ports = freeLoopbackPorts(2);
  httpPort_ = ports[0];
  dicomPort_ = ports[1];
  const fs::path config = workDir_ / "orthanc.json";
  std::ofstream(config)
      << makeConfiguration(workDir_, httpPort_, dicomPort_, options_, sslPem).dump(2);
  // See tests/CMakeLists.txt: Debian 12's civetweb needs OpenSSL 1.1's names for HTTPS.
  std::string libraryDir;
#ifdef OCTORAY_ORTHANC_LIBSSL_DIR
  if (options_.tls) libraryDir = OCTORAY_ORTHANC_LIBSSL_DIR;
#endif
  pid_ = spawnOrthanc(config, logFile(), libraryDir);

  // Ready when GET /system answers 200; a child that exits meanwhile fails at once.
  HttpClient http(options_, certificate_);
  const auto deadline = Clock::now() + kStartTimeout;
  std::string lastProblem = "no answer yet";
  for (;;) {
    int status = 0;
    if (::waitpid(pid_, &status, WNOHANG) == pid_) {
      pid_ = -1;
      throw ExitedEarly("Orthanc exited during start-up (" +
                        (WIFEXITED(status) ? "status " + std::to_string(WEXITSTATUS(status))
                                           : "signal " + std::to_string(WTERMSIG(status))) +
                        "); " + logFile().string() + " ends with:\n" + logTail());
    }
    try {
      const long code = http.request(httpUrl() + "/system", nullptr);
      if (code == 200) return;
      lastProblem = "GET /system answered HTTP " + std::to_string(code);
    } catch (const std::exception& e) {
      lastProblem = e.what();
    }
    if (Clock::now() > deadline) {
      throw std::runtime_error("Orthanc did not answer within 30 s (" + lastProblem + "); " +
                               logFile().string() + " ends with:\n" + logTail());
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
}

void OrthancServer::stop() {
  if (pid_ <= 0) return;
  ::kill(pid_, SIGTERM);
  const auto deadline = Clock::now() + kStopTimeout;
  int status = 0;
  for (;;) {
    const pid_t done = ::waitpid(pid_, &status, WNOHANG);
    if (done == pid_ || (done < 0 && errno == ECHILD)) break;
    if (Clock::now() > deadline) {
      ::kill(pid_, SIGKILL);
      while (::waitpid(pid_, &status, 0) < 0 && errno == EINTR) {
      }
      break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  pid_ = -1;
}

std::string OrthancServer::logTail() const {
  std::string log;
  try {
    log = readFile(logFile());
  } catch (const std::exception&) {
    return "(no log)";
  }
  // The last 40 lines.
  std::size_t start = log.size();
  for (int lines = 0; lines < 41 && start > 0; ++lines) {
    const std::size_t newline = log.rfind('\n', start - 1);
    start = newline == std::string::npos ? 0 : newline;
  }
  return log.substr(start == 0 ? 0 : start + 1);
}

void OrthancServer::upload(const std::vector<std::filesystem::path>& files) {
  HttpClient http(options_, certificate_);
  for (const auto& file : files) {
    const std::string bytes = readFile(file);
    const long code = http.request(httpUrl() + "/instances", &bytes);
    if (code < 200 || code >= 300) {
      throw std::runtime_error("Orthanc at " + httpUrl() + " refused " + file.string() + ": HTTP " +
                               std::to_string(code) + " " + http.body());
    }
  }
}

namespace {

std::vector<double> decimalStrings(const gdcm::DataSet& dataset, uint16_t group, uint16_t element) {
  const gdcm::Tag tag(group, element);
  std::vector<double> out;
  if (!dataset.FindDataElement(tag)) return out;
  const gdcm::ByteValue* value = dataset.GetDataElement(tag).GetByteValue();
  if (!value) return out;
  std::string text(value->GetPointer(), value->GetLength());
  for (char& c : text) c = c == '\\' ? ' ' : c;
  std::istringstream in(text);
  for (double x; in >> x;) out.push_back(x);
  return out;
}

}  // namespace

std::map<std::string, FileGeometry> geometryOfFiles(const std::vector<std::filesystem::path>& files) {
  std::map<std::string, FileGeometry> out;
  for (const auto& file : files) {
    gdcm::Reader reader;
    reader.SetFileName(file.c_str());
    if (!reader.Read()) throw std::runtime_error("GDCM cannot read " + file.string());
    const gdcm::DataSet& dataset = reader.GetFile().GetDataSet();
    const gdcm::Tag uidTag(0x0008, 0x0018);
    const gdcm::ByteValue* uidValue = dataset.GetDataElement(uidTag).GetByteValue();
    if (!uidValue) throw std::runtime_error(file.string() + ": no SOPInstanceUID");
    std::string uid(uidValue->GetPointer(), uidValue->GetLength());
    while (!uid.empty() && (uid.back() == '\0' || uid.back() == ' ')) uid.pop_back();
    const auto p = decimalStrings(dataset, 0x0020, 0x0032), o = decimalStrings(dataset, 0x0020, 0x0037);
    if (p.size() != 3 || o.size() != 6) throw std::runtime_error(file.string() + ": no position or orientation");
    out[uid] = {{p[0], p[1], p[2]}, {o[0], o[1], o[2], o[3], o[4], o[5]}};
  }
  return out;
}

void expectListedGeometry(std::vector<pacs::InstanceRecord> listed, const std::map<std::string, FileGeometry>& files) {
  ASSERT_EQ(listed.size(), files.size());
  for (const auto& instance : listed) {
    const auto it = files.find(instance.sopInstanceUid);
    ASSERT_NE(it, files.end()) << instance.sopInstanceUid;
    ASSERT_TRUE(instance.position.has_value()) << instance.sopInstanceUid;
    ASSERT_TRUE(instance.orientation.has_value()) << instance.sopInstanceUid;
    for (std::size_t i = 0; i < 3; ++i) EXPECT_NEAR((*instance.position)[i], it->second.position[i], 1e-6);
    for (std::size_t i = 0; i < 6; ++i) EXPECT_NEAR((*instance.orientation)[i], it->second.orientation[i], 1e-6);
  }
  pacs::sortForViewing(listed);
  const auto& o = *listed.front().orientation;
  const std::array<double, 3> n{o[1] * o[5] - o[2] * o[4], o[2] * o[3] - o[0] * o[5], o[0] * o[4] - o[1] * o[3]};
  for (std::size_t i = 1; i < listed.size(); ++i) {
    const auto& a = *listed[i - 1].position;
    const auto& b = *listed[i].position;
    EXPECT_LT(a[0] * n[0] + a[1] * n[1] + a[2] * n[2], b[0] * n[0] + b[1] * n[1] + b[2] * n[2]) << i;
  }
}

}  // namespace octoray::test
