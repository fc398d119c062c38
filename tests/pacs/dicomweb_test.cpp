// DICOMweb against a real Orthanc (tests/pacs/orthanc_server.h) holding the Philips CT study
// of ../shared: QIDO-RS search, WADO-RS retrieval into a store equal to the local import,
// resumption, authentication, TLS verification; and, from a fake server, the failures a real
// one does not produce on demand (a connection closed mid-answer, a malformed multipart body).
// No credential may appear in any output, file or process list.
#include <gtest/gtest.h>

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <fstream>
#include <functional>
#include <random>
#include <sstream>
#include <thread>

#include <fmt/format.h>
#include <gdcmReader.h>
#include <nlohmann/json.hpp>

#include "octoray/core/error.h"
#include "octoray/pacs/connection.h"
#include "octoray/pacs/dicomweb.h"
#include "octoray/pacs/retrieve.h"
#include "octoray/volume/store_reader.h"
#include "orthanc_server.h"
#include "run_process.h"
#include "test_paths.h"

extern char** environ;

namespace {

using namespace octoray;
namespace fs = std::filesystem;

fs::path seriesFolder() { return test::philipsDir() / "S21570" / "S2020"; }

std::vector<fs::path> seriesFiles() {
  std::vector<fs::path> files;
  for (const auto& e : fs::directory_iterator(seriesFolder())) {
    if (e.is_regular_file() && e.path().filename() != "DIRFILE") files.push_back(e.path());
  }
  std::sort(files.begin(), files.end());
  return files;
}

std::string attribute(const fs::path& file, uint16_t group, uint16_t element) {
  gdcm::Reader reader;
  reader.SetFileName(file.c_str());
  if (!reader.Read()) throw std::runtime_error("cannot read " + file.string());
  const auto& de = reader.GetFile().GetDataSet().GetDataElement(gdcm::Tag(group, element));
  const gdcm::ByteValue* v = de.GetByteValue();
  std::string s = v != nullptr ? std::string(v->GetPointer(), v->GetLength()) : "";
  while (!s.empty() && (s.back() == '\0' || s.back() == ' ')) s.pop_back();
  return s;
}

// A proxy in the environment is for real servers, not for the loopback ones of these tests.
void noProxyForLoopback() { ::setenv("NO_PROXY", "127.0.0.1,localhost", 1); }

std::string randomSecret() {
  std::random_device rd;
  return fmt::format("pw{:08x}{:08x}", rd(), rd());
}

std::string readText(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

// Every file under `root` whose bytes contain `needle`.
std::vector<fs::path> filesContaining(const fs::path& root, const std::string& needle) {
  std::vector<fs::path> found;
  if (!fs::exists(root)) return found;
  for (const auto& e : fs::recursive_directory_iterator(root)) {
    if (e.is_regular_file() && readText(e.path()).find(needle) != std::string::npos) found.push_back(e.path());
  }
  return found;
}

// One Orthanc with basic authentication and the 140-slice Philips series, per test process
// (ctest runs each test in its own process).
class DicomWeb : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    if (!test::OrthancServer::available() || !fs::exists(seriesFolder())) return;
    noProxyForLoopback();
    secret_ = randomSecret();
    server_ = std::make_unique<test::OrthancServer>(test::freshTempDir("orthanc"),
                                                    test::OrthancOptions{false, "octoray", secret_});
    server_->upload(seriesFiles());
  }
  static void TearDownTestSuite() { server_.reset(); }
  void SetUp() override {
    if (!test::OrthancServer::available()) GTEST_SKIP() << "skipped: Orthanc or its DICOMweb plugin is not installed";
    OCTORAY_REQUIRE_PATH(seriesFolder());
    ASSERT_TRUE(server_);
    const fs::path first = seriesFiles().front();
    patientId_ = attribute(first, 0x0010, 0x0020);
    studyUid_ = attribute(first, 0x0020, 0x000d);
    seriesUid_ = attribute(first, 0x0020, 0x000e);
  }

  static pacs::PacsOptions goodOptions() {
    pacs::PacsOptions o;
    o.credentials = {pacs::Credentials::Kind::Basic, "octoray", secret_};
    return o;
  }
  // A credentials file for the tools, readable by its owner only.
  fs::path credentialsFile(const fs::path& dir) const {
    const fs::path p = dir / "pacs.cred";
    std::ofstream(p) << "basic octoray:" << secret_ << "\n";
    fs::permissions(p, fs::perms::owner_read | fs::perms::owner_write);
    return p;
  }

  static inline std::unique_ptr<test::OrthancServer> server_;
  static inline std::string secret_;
  std::string patientId_, studyUid_, seriesUid_;
};

TEST_F(DicomWeb, QidoFindsTheStudyByPatientIdAndModality) {
  auto pacs = pacs::connectPacs(server_->dicomWebUrl(), goodOptions());
  pacs::StudyQuery q;
  q.patientId = patientId_;
  auto studies = pacs->findStudies(q);
  ASSERT_EQ(studies.size(), 1u);
  EXPECT_EQ(studies[0].studyInstanceUid, studyUid_);
  EXPECT_EQ(studies[0].patientId, patientId_);
  q.modality = "CT";
  studies = pacs->findStudies(q);
  ASSERT_EQ(studies.size(), 1u);
  EXPECT_NE(std::find(studies[0].modalities.begin(), studies[0].modalities.end(), "CT"),
            studies[0].modalities.end());
  q.modality = "MR";
  EXPECT_TRUE(pacs->findStudies(q).empty());
  q = {};
  q.patientId = patientId_ + "-nobody";
  EXPECT_TRUE(pacs->findStudies(q).empty());

  const auto series = pacs->findSeries(studyUid_, "CT");
  ASSERT_EQ(series.size(), 1u);
  EXPECT_EQ(series[0].seriesInstanceUid, seriesUid_);
  EXPECT_EQ(series[0].instanceCount, 140);
  // Each instance with its position and orientation: what places its slice before it arrives.
  test::expectListedGeometry(pacs->findInstances(studyUid_, seriesUid_), test::geometryOfFiles(seriesFiles()));
}

// octoray-pacs get over WADO-RS and over C-GET, then octoray-import of each retrieved folder
// and of the local files: the three stores hold the same samples in every brick.
TEST_F(DicomWeb, RetrievedSeriesImportsToTheSameStoreAsTheLocalFiles) {
  const fs::path dir = test::freshTempDir("wado");
  const fs::path creds = credentialsFile(dir);
  const std::string dimse = fmt::format("dicom://{}@127.0.0.1:{}", server_->aeTitle(), server_->dicomPort());
  std::vector<std::pair<fs::path, fs::path>> imports;  // source folder, store
  for (const auto& [url, name] : {std::pair{server_->dicomWebUrl(), std::string("wado")},
                                  std::pair{dimse, std::string("cget")}}) {
    SCOPED_TRACE(name);
    std::vector<std::string> argv = {test::toolPath("octoray-pacs").string(), "get", url, "--study", studyUid_,
                                     "--series", seriesUid_, "-o", (dir / name).string(), "--json"};
    if (name == "wado") argv.insert(argv.end(), {"--credentials", creds.string()});
    auto get = test::runProcess(argv);
    ASSERT_EQ(get.exitCode, 0) << get.err;
    const auto report = nlohmann::json::parse(get.out);
    EXPECT_EQ(report["series"][0]["instances"], 140);
    EXPECT_EQ(report["series"][0]["fetched"], 140);
    const fs::path folder = dir / name / studyUid_ / seriesUid_;
    EXPECT_TRUE(pacs::isCompleteRetrieval(folder));
    EXPECT_TRUE(filesContaining(dir / name, secret_).empty());
    EXPECT_EQ(get.out.find(secret_), std::string::npos);
    EXPECT_EQ(get.err.find(secret_), std::string::npos);
    imports.emplace_back(folder, dir / (name + ".octoray"));
  }
  imports.emplace_back(seriesFolder(), dir / "local.octoray");
  for (const auto& [source, store] : imports) {
    auto r = test::runProcess({test::toolPath("octoray-import").string(), source.string(), "-o", store.string()});
    ASSERT_EQ(r.exitCode, 0) << r.err;
  }
  const volume::StoreReader local((dir / "local.octoray").string());
  for (std::size_t s = 0; s < 2; ++s) {
    SCOPED_TRACE(imports[s].second.string());
    const volume::StoreReader retrieved(imports[s].second.string());
    ASSERT_EQ(retrieved.nodes().size(), local.nodes().size());
    for (int i = 0; i < 3; ++i) EXPECT_EQ(retrieved.header().dims[i], local.header().dims[i]);
    for (int i = 0; i < 12; ++i) EXPECT_EQ(retrieved.header().patientFromIndex[i], local.header().patientFromIndex[i]);
    for (std::size_t id = 0; id < local.nodes().size(); ++id) {
      const volume::Brick a = retrieved.readBrick(static_cast<int64_t>(id)), b = local.readBrick(static_cast<int64_t>(id));
      ASSERT_EQ(a.u16, b.u16) << "brick " << id;
      ASSERT_EQ(a.f32, b.f32) << "brick " << id;
    }
  }
}

// Interrupted after 70 instances, the retrieval resumes with only the other 70; an instance
// damaged on disk in between is fetched again.
TEST_F(DicomWeb, InterruptedRetrievalResumesWithOnlyTheRest) {
  const fs::path folder = test::freshTempDir("resume") / "series";
  auto pacs = pacs::connectPacs(server_->dicomWebUrl(), goodOptions());
  pacs::RetrieveRequest request;
  request.source = pacs->describe();
  request.studyInstanceUid = studyUid_;
  request.seriesInstanceUid = seriesUid_;
  request.instances = pacs->findInstances(studyUid_, seriesUid_);
  request.folder = folder;
  ASSERT_EQ(request.instances.size(), 140u);
  int fetchedBeforeInterruption = 0;
  const auto interrupted = [&](const std::vector<std::string>& uids, const pacs::InstanceSink& sink) {
    pacs->fetch(studyUid_, seriesUid_, uids, [&](const std::string& uid, std::vector<uint8_t> bytes) {
      if (fetchedBeforeInterruption == 70) throw Error("test", "interrupted");
      sink(uid, std::move(bytes));
      ++fetchedBeforeInterruption;
    });
  };
  EXPECT_THROW(pacs::retrieveSeries(request, interrupted), Error);
  EXPECT_FALSE(pacs::isCompleteRetrieval(folder));
  EXPECT_FALSE(fs::exists(folder / pacs::kRetrievedRecordName));
  std::size_t present = 0;
  std::string damaged;
  for (const auto& e : fs::directory_iterator(folder)) {
    if (e.path().extension() == ".dcm") {
      ++present;
      damaged = e.path().string();
    }
  }
  EXPECT_EQ(present, 70u);
  fs::resize_file(damaged, fs::file_size(damaged) / 2);  // a half-copied file

  std::vector<std::string> asked;
  const auto counting = [&](const std::vector<std::string>& uids, const pacs::InstanceSink& sink) {
    asked = uids;
    pacs->fetch(studyUid_, seriesUid_, uids, sink);
  };
  const pacs::RetrieveReport r = pacs::retrieveSeries(request, counting);
  EXPECT_EQ(r.instances, 140);
  EXPECT_EQ(r.alreadyPresent, 69);
  EXPECT_EQ(r.fetched, 71);
  EXPECT_EQ(asked.size(), 71u);
  EXPECT_NE(std::find(asked.begin(), asked.end(), fs::path(damaged).stem().string()), asked.end());
  EXPECT_TRUE(pacs::isCompleteRetrieval(folder));
}

// The tool killed (SIGKILL) half way: its command line never held the secret, the folder is
// not marked complete, and the rerun fetches only what is missing.
TEST_F(DicomWeb, KilledToolResumesAndNeverShowsTheSecret) {
  const fs::path dir = test::freshTempDir("killed");
  const fs::path creds = credentialsFile(dir);
  const fs::path out = dir / "exams";
  const fs::path folder = out / studyUid_ / seriesUid_;
  std::vector<std::string> argv = {test::toolPath("octoray-pacs").string(), "get", server_->dicomWebUrl(),
                                   "--credentials", creds.string(), "--study", studyUid_,
                                   "--series", seriesUid_, "-o", out.string(), "--json"};
  std::vector<char*> args;
  for (auto& a : argv) args.push_back(a.data());
  args.push_back(nullptr);
  pid_t pid = -1;
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, "/dev/null", O_WRONLY, 0);
  ASSERT_EQ(posix_spawn(&pid, args[0], &actions, nullptr, args.data(), environ), 0);
  posix_spawn_file_actions_destroy(&actions);
  std::string cmdline;  // read once the tool is at work (right after the spawn it may not be)
  // Stop it (SIGSTOP, then SIGKILL) once at least 20 instances are in place.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  int status = 0;
  bool ended = false;
  while (std::chrono::steady_clock::now() < deadline) {
    if (::waitpid(pid, &status, WNOHANG) == pid) {
      ended = true;
      break;
    }
    std::size_t n = 0;
    if (fs::exists(folder)) {
      for (const auto& e : fs::directory_iterator(folder)) n += e.path().extension() == ".dcm";
    }
    if (n >= 1 && cmdline.empty()) cmdline = readText(fmt::format("/proc/{}/cmdline", pid));
    if (n >= 20) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  EXPECT_NE(cmdline.find("--credentials"), std::string::npos) << "the tool's command line was not read";
  EXPECT_EQ(cmdline.find(secret_), std::string::npos);
  if (!ended) {
    ::kill(pid, SIGSTOP);
    ::kill(pid, SIGKILL);
    ::waitpid(pid, &status, 0);
  }
  if (ended || pacs::isCompleteRetrieval(folder)) {
    GTEST_SKIP() << "skipped: the retrieval finished before it could be killed (a loaded machine)";
  }
  std::size_t before = 0;
  for (const auto& e : fs::directory_iterator(folder)) before += e.path().extension() == ".dcm";
  EXPECT_FALSE(fs::exists(folder / pacs::kRetrievedRecordName));
  ASSERT_GE(before, 20u);

  auto rerun = test::runProcess(argv);
  ASSERT_EQ(rerun.exitCode, 0) << rerun.err;
  const auto report = nlohmann::json::parse(rerun.out);
  const int64_t kept = report["series"][0]["alreadyPresent"], fetched = report["series"][0]["fetched"];
  EXPECT_EQ(kept, static_cast<int64_t>(before));  // every file under its final name is complete
  EXPECT_EQ(kept + fetched, 140);
  EXPECT_TRUE(pacs::isCompleteRetrieval(folder));
  EXPECT_TRUE(filesContaining(dir / "exams", secret_).empty());
  EXPECT_EQ(rerun.out.find(secret_), std::string::npos);
}

// octoray-import with a DICOMweb series URL as its input: the series is retrieved into the
// cache folder ($OCTORAY_CACHE) and resolves to the same volume as the local files.
TEST_F(DicomWeb, ImportTakesADicomWebSeriesUrl) {
  const fs::path dir = test::freshTempDir("import-url");
  const fs::path creds = credentialsFile(dir);
  ::setenv("OCTORAY_CACHE", (dir / "cache").c_str(), 1);
  const std::string url = server_->dicomWebUrl() + "/studies/" + studyUid_ + "/series/" + seriesUid_;
  auto remote = test::runProcess({test::toolPath("octoray-import").string(), "--inspect", url, "--json",
                                  "--credentials", creds.string()});
  ASSERT_EQ(remote.exitCode, 0) << remote.err;
  auto local = test::runProcess({test::toolPath("octoray-import").string(), "--inspect",
                                 seriesFolder().string(), "--json"});
  ASSERT_EQ(local.exitCode, 0) << local.err;
  const auto a = nlohmann::json::parse(remote.out), b = nlohmann::json::parse(local.out);
  for (const char* key : {"dimensions", "patientFromIndex", "valueRange", "spacing"}) {
    if (b.contains(key)) {
      EXPECT_EQ(a[key], b[key]) << key;
    }
  }
  EXPECT_TRUE(a.contains("dimensions"));
  EXPECT_TRUE(pacs::isCompleteRetrieval(dir / "cache" / "pacs" / studyUid_ / seriesUid_));
  EXPECT_EQ(remote.out.find(secret_), std::string::npos);
  EXPECT_EQ(remote.err.find(secret_), std::string::npos);
  EXPECT_TRUE(filesContaining(dir / "cache", secret_).empty());

  // A URL that names no series is one clear message.
  auto study = test::runProcess({test::toolPath("octoray-import").string(), "--inspect",
                                 server_->dicomWebUrl() + "/studies/" + studyUid_, "--credentials", creds.string()});
  EXPECT_EQ(study.exitCode, 1);
  EXPECT_NE(study.err.find("names no series"), std::string::npos) << study.err;
}

TEST_F(DicomWeb, WrongCredentialsAreOneClearMessageWithoutTheSecret) {
  const fs::path dir = test::freshTempDir("auth");
  const std::string wrong = randomSecret();
  std::ofstream(dir / "wrong.cred") << "basic octoray:" << wrong << "\n";
  fs::permissions(dir / "wrong.cred", fs::perms::owner_read | fs::perms::owner_write);
  auto r = test::runProcess({test::toolPath("octoray-pacs").string(), "find", server_->dicomWebUrl(),
                             "--credentials", (dir / "wrong.cred").string(), "--patient-id", patientId_});
  EXPECT_EQ(r.exitCode, 1);
  EXPECT_NE(r.err.find("authentication failed (HTTP 401)"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find(server_->dicomWebUrl()), std::string::npos) << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  EXPECT_EQ(r.err.find(wrong), std::string::npos);
  EXPECT_TRUE(r.out.empty()) << r.out;

  // No credentials at all: the server's 401 says what to do.
  auto none = test::runProcess({test::toolPath("octoray-pacs").string(), "find", server_->dicomWebUrl()});
  EXPECT_EQ(none.exitCode, 1);
  EXPECT_NE(none.err.find("--credentials"), std::string::npos) << none.err;

  // Credentials in the URL are refused before anything is sent, and not repeated.
  const std::string inUrl = "http://octoray:" + secret_ + "@127.0.0.1:" + std::to_string(server_->httpPort()) + "/dicom-web";
  auto url = test::runProcess({test::toolPath("octoray-pacs").string(), "find", inUrl});
  EXPECT_EQ(url.exitCode, 1);
  EXPECT_EQ(url.err.find(secret_), std::string::npos) << url.err;
  EXPECT_NE(url.err.find("user information"), std::string::npos) << url.err;

  // From the environment variable, the same server answers.
  pacs::PacsOptions o;
  ::setenv(pacs::kCredentialsEnvironmentVariable, ("basic octoray:" + secret_).c_str(), 1);
  o.credentials = pacs::resolveCredentials("");
  ::unsetenv(pacs::kCredentialsEnvironmentVariable);
  EXPECT_NO_THROW(pacs::connectPacs(server_->dicomWebUrl(), o)->echo());
}

TEST(DicomWebFailures, UnreachableServerFailsFastNamingIt) {
  noProxyForLoopback();
  // A port nothing listens on: bound, then closed.
  int s = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  ASSERT_EQ(::bind(s, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
  socklen_t len = sizeof addr;
  ::getsockname(s, reinterpret_cast<sockaddr*>(&addr), &len);
  ::close(s);
  const std::string url = fmt::format("http://127.0.0.1:{}/dicom-web", ntohs(addr.sin_port));
  const auto start = std::chrono::steady_clock::now();
  try {
    pacs::connectPacs(url, {})->findStudies({});
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(url), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("cannot connect"), std::string::npos) << e.what();
  }
  EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(5));
}

TEST(DicomWebFailures, SelfSignedCertificateIsRefusedUnlessItsCaIsGiven) {
  if (!test::OrthancServer::available()) GTEST_SKIP() << "skipped: Orthanc is not installed";
  noProxyForLoopback();
  test::OrthancServer tls(test::freshTempDir("orthanc-tls"), test::OrthancOptions{true, "", ""});
  ASSERT_EQ(tls.dicomWebUrl().rfind("https://", 0), 0u);
  try {
    pacs::connectPacs(tls.dicomWebUrl(), {})->echo();
    FAIL() << "a self-signed certificate was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("certificate is not trusted"), std::string::npos) << e.what();
  }
  pacs::PacsOptions trusted;
  trusted.caFile = tls.certificate().string();
  EXPECT_NO_THROW(pacs::connectPacs(tls.dicomWebUrl(), trusted)->echo());
}

// A one-thread HTTP server on 127.0.0.1 answering each request with the bytes `answer`
// returns for its request line, then closing the connection.
class FakeServer {
 public:
  explicit FakeServer(std::function<std::string(const std::string&)> answer) : answer_(std::move(answer)) {
    fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (::bind(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0 || ::listen(fd_, 8) != 0) {
      throw std::runtime_error("fake server: cannot listen");
    }
    socklen_t len = sizeof addr;
    ::getsockname(fd_, reinterpret_cast<sockaddr*>(&addr), &len);
    port_ = ntohs(addr.sin_port);
    thread_ = std::thread([this] { serve(); });
  }
  ~FakeServer() {
    stop_ = true;
    thread_.join();
    ::close(fd_);
  }
  std::string url() const { return fmt::format("http://127.0.0.1:{}/dicom-web", port_); }

 private:
  void serve() {
    while (!stop_) {
      pollfd p{fd_, POLLIN, 0};
      if (::poll(&p, 1, 50) <= 0) continue;
      const int c = ::accept(fd_, nullptr, nullptr);
      if (c < 0) continue;
      std::string request;
      char buffer[4096];
      while (request.find("\r\n\r\n") == std::string::npos) {
        const ssize_t n = ::recv(c, buffer, sizeof buffer, 0);
        if (n <= 0) break;
        request.append(buffer, static_cast<std::size_t>(n));
      }
      const std::string reply = answer_(request.substr(0, request.find("\r\n")));
      std::size_t sent = 0;
      while (sent < reply.size()) {
        const ssize_t n = ::send(c, reply.data() + sent, reply.size() - sent, MSG_NOSIGNAL);
        if (n <= 0) break;
        sent += static_cast<std::size_t>(n);
      }
      ::shutdown(c, SHUT_RDWR);
      ::close(c);
    }
  }
  std::function<std::string(const std::string&)> answer_;
  int fd_ = -1, port_ = 0;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

std::string httpReply(const std::string& type, const std::string& body, std::size_t claimedLength = 0) {
  return fmt::format("HTTP/1.1 200 OK\r\nContent-Type: {}\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{}",
                     type, claimedLength ? claimedLength : body.size(), body);
}

// Two instances listed; the first arrives whole, the second as `second` makes it.
void expectFailedRetrieval(const std::function<std::string()>& second, const std::string& expected) {
  OCTORAY_REQUIRE_PATH(seriesFolder());
  noProxyForLoopback();
  const fs::path file = seriesFiles().front();
  const std::string sop = attribute(file, 0x0008, 0x0018);
  const std::string other = "1.2.3.4.5.6";
  const std::string part10 = readText(file);
  FakeServer server([&](const std::string& line) {
    if (line.find("/instances ") != std::string::npos || line.find("/instances?") != std::string::npos) {
      return httpReply("application/dicom+json",
                       fmt::format(R"([{{"00080018":{{"vr":"UI","Value":["{}"]}}}},{{"00080018":{{"vr":"UI","Value":["{}"]}}}}])", sop, other));
    }
    if (line.find("/instances/" + sop) != std::string::npos) {
      return httpReply("multipart/related; type=\"application/dicom\"; boundary=B",
                       "--B\r\nContent-Type: application/dicom\r\n\r\n" + part10 + "\r\n--B--\r\n");
    }
    return second();
  });
  const fs::path folder = test::freshTempDir("fake") / "series";
  auto pacs = pacs::connectPacs(server.url(), {});
  try {
    pacs::retrieveSeriesInto(*pacs, "1.2.3", "1.2.3.4", folder);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(server.url()), std::string::npos) << e.what();
  }
  EXPECT_FALSE(pacs::isCompleteRetrieval(folder));
  EXPECT_FALSE(fs::exists(folder / pacs::kRetrievedRecordName));
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(folder)) names.push_back(e.path().filename().string());
  EXPECT_EQ(names, std::vector<std::string>{sop + ".dcm"}) << "only the complete instance stays";
}

TEST(DicomWebFailures, ServerClosingMidTransferLeavesNoCompleteLookingSeries) {
  expectFailedRetrieval([] {
    const std::string half(50000, 'x');
    return httpReply("multipart/related; type=\"application/dicom\"; boundary=B",
                     "--B\r\nContent-Type: application/dicom\r\n\r\n" + half, 400000);
  }, "closed the connection before the answer was complete");
}

TEST(DicomWebFailures, MalformedMultipartBodyIsNamed) {
  expectFailedRetrieval([] {
    return httpReply("multipart/related; type=\"application/dicom\"; boundary=B",
                     "--B\r\nContent-Type: application/dicom\r\n\r\nDICM but never closed");
  }, "malformed multipart body");
}

}  // namespace
