// DIMSE (dimse.h) against a real Orthanc (orthanc_server.h) holding Philips series 201 of
// ../shared: C-ECHO, C-FIND at study, series and image level, C-GET of the whole series and of
// some instances with the pixel data compared to the files uploaded (decoded by GDCM), compressed
// instances received in their own transfer syntax; and, from fake servers, the failures a real
// one does not produce on demand (nothing listening, no answer, association rejected).

#include <arpa/inet.h>
#include <gdcmImage.h>
#include <gdcmImageReader.h>
#include <gdcmReader.h>
#include <gdcmTrace.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <map>
#include <memory>
#include <set>
#include <sstream>
#include <thread>

#include "octoray/core/error.h"
#include "octoray/pacs/dimse.h"
#include "orthanc_server.h"
#include "test_paths.h"

namespace octoray::test {
namespace {

namespace fs = std::filesystem;
using pacs::DimseEndpoint;
using Clock = std::chrono::steady_clock;

constexpr const char* kCtImageStorage = "1.2.840.10008.5.1.4.1.1.2";

fs::path seriesFolder() { return philipsDir() / "S21570/S2010"; }

std::string trimmed(std::string text) {
  while (!text.empty() && (text.back() == ' ' || text.back() == '\0')) text.pop_back();
  return text;
}

std::string attribute(const gdcm::DataSet& dataset, uint16_t group, uint16_t element) {
  const gdcm::Tag tag(group, element);
  if (!dataset.FindDataElement(tag)) return {};
  const gdcm::ByteValue* value = dataset.GetDataElement(tag).GetByteValue();
  return value ? trimmed(std::string(value->GetPointer(), value->GetLength())) : std::string();
}

// What the comparisons need of one instance, read by GDCM independently of DCMTK.
struct Decoded {
  std::string sopInstanceUid, studyUid, seriesUid, patientId, studyDate, transferSyntax;
  std::vector<char> pixels;
};

Decoded decode(gdcm::ImageReader& reader, const std::string& what) {
  if (!reader.Read()) throw std::runtime_error("GDCM cannot read " + what);
  const gdcm::DataSet& dataset = reader.GetFile().GetDataSet();
  Decoded decoded;
  decoded.sopInstanceUid = attribute(dataset, 0x0008, 0x0018);
  decoded.studyUid = attribute(dataset, 0x0020, 0x000d);
  decoded.seriesUid = attribute(dataset, 0x0020, 0x000e);
  decoded.patientId = attribute(dataset, 0x0010, 0x0020);
  decoded.studyDate = attribute(dataset, 0x0008, 0x0020);
  decoded.transferSyntax =
      trimmed(reader.GetFile().GetHeader().GetDataSetTransferSyntax().GetString());
  const gdcm::Image& image = reader.GetImage();
  decoded.pixels.resize(image.GetBufferLength());
  if (!image.GetBuffer(decoded.pixels.data())) {
    throw std::runtime_error("GDCM cannot decode " + what);
  }
  return decoded;
}

Decoded decodeFile(const fs::path& file) {
  gdcm::ImageReader reader;
  reader.SetFileName(file.c_str());
  return decode(reader, file.string());
}

Decoded decodeBytes(const std::vector<uint8_t>& bytes, const std::string& what) {
  std::istringstream stream(std::string(bytes.begin(), bytes.end()));
  gdcm::ImageReader reader;
  reader.SetStream(stream);
  return decode(reader, what);
}

// A free loopback port with nothing listening on it.
int unusedPort() {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t length = sizeof address;
  ::bind(fd, reinterpret_cast<sockaddr*>(&address), sizeof address);
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&address), &length);
  ::close(fd);
  return ntohs(address.sin_port);
}

// A TCP server on 127.0.0.1 for failures: with `reply` empty it accepts and never answers,
// else it answers the first bytes it reads with `reply` and closes.
class FakeServer {
 public:
  explicit FakeServer(std::vector<uint8_t> reply) : reply_(std::move(reply)) {
    listener_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    socklen_t length = sizeof address;
    if (::bind(listener_, reinterpret_cast<sockaddr*>(&address), sizeof address) != 0 ||
        ::listen(listener_, 4) != 0 ||
        ::getsockname(listener_, reinterpret_cast<sockaddr*>(&address), &length) != 0) {
      throw std::runtime_error("FakeServer: cannot listen");
    }
    port_ = ntohs(address.sin_port);
    thread_ = std::thread([this] { serve(); });
  }
  ~FakeServer() {
    stop_ = true;
    thread_.join();
    ::close(listener_);
  }
  int port() const { return port_; }

 private:
  void serve() {
    std::vector<int> clients;
    while (!stop_) {
      pollfd ready{listener_, POLLIN, 0};
      if (::poll(&ready, 1, 50) <= 0) continue;
      const int client = ::accept4(listener_, nullptr, nullptr, SOCK_CLOEXEC);
      if (client < 0) continue;
      clients.push_back(client);
      if (reply_.empty()) continue;
      char request[4096];
      pollfd readable{client, POLLIN, 0};
      if (::poll(&readable, 1, 5000) > 0 && ::read(client, request, sizeof request) > 0) {
        (void)!::write(client, reply_.data(), reply_.size());
      }
    }
    for (int client : clients) ::close(client);
  }

  std::vector<uint8_t> reply_;
  int listener_ = -1;
  int port_ = 0;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

DimseEndpoint loopback(int port, const std::string& calledAet = "ORTHANC") {
  DimseEndpoint endpoint;
  endpoint.host = "127.0.0.1";
  endpoint.port = port;
  endpoint.calledAet = calledAet;
  endpoint.callingAet = "OCTORAY-TEST";
  endpoint.timeoutSeconds = 10;
  return endpoint;
}

#define EXPECT_ERROR_CONTAINING(statement, ...)                                           \
  do {                                                                                    \
    try {                                                                                 \
      statement;                                                                          \
      ADD_FAILURE() << #statement " did not throw";                                       \
    } catch (const octoray::Error& error) {                                               \
      const std::string message = error.what();                                           \
      for (const std::string& part : std::vector<std::string>{__VA_ARGS__}) {             \
        EXPECT_NE(message.find(part), std::string::npos) << message << " lacks " << part; \
      }                                                                                   \
    }                                                                                     \
  } while (0)

// ---------------------------------------------------------------------------------------------
// Against Orthanc: one server per suite (and per process: ctest runs each test alone).

class DimseOrthanc : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    if (!OrthancServer::available() || !fs::exists(seriesFolder())) return;
    try {
      server_ = std::make_unique<OrthancServer>(freshTempDir("orthanc-dimse"));
      std::vector<fs::path> files;
      for (const auto& entry : fs::directory_iterator(seriesFolder())) {
        if (entry.path().filename() != "DIRFILE") files.push_back(entry.path());
      }
      server_->upload(files);
      for (const fs::path& file : files) {
        gdcm::Reader reader;
        reader.SetFileName(file.c_str());
        if (!reader.Read()) throw std::runtime_error("GDCM cannot read " + file.string());
        const gdcm::DataSet& dataset = reader.GetFile().GetDataSet();
        originals_[attribute(dataset, 0x0008, 0x0018)] = file;
        studyUid_ = attribute(dataset, 0x0020, 0x000d);
        seriesUid_ = attribute(dataset, 0x0020, 0x000e);
        patientId_ = attribute(dataset, 0x0010, 0x0020);
        studyDate_ = attribute(dataset, 0x0008, 0x0020);
      }
    } catch (const std::exception& e) {
      setupError_ = e.what();
    }
  }
  static void TearDownTestSuite() { server_.reset(); }

  void SetUp() override {
    if (!OrthancServer::available()) {
      GTEST_SKIP() << "skipped: Orthanc or its DICOMweb plugin is not installed";
    }
    OCTORAY_REQUIRE_PATH(seriesFolder());
    ASSERT_TRUE(setupError_.empty()) << setupError_;
  }

  static DimseEndpoint endpoint() { return loopback(server_->dicomPort(), server_->aeTitle()); }

  static std::set<std::string> originalUids() {
    std::set<std::string> uids;
    for (const auto& [uid, file] : originals_) uids.insert(uid);
    return uids;
  }

  static inline std::unique_ptr<OrthancServer> server_;
  static inline std::string setupError_;
  static inline std::map<std::string, fs::path> originals_;  // SOPInstanceUID -> file
  static inline std::string studyUid_, seriesUid_, patientId_, studyDate_;
};

TEST_F(DimseOrthanc, EchoesAndFindsTheStudy) {
  pacs::dimseEcho(endpoint());

  pacs::StudyQuery byPatient;
  byPatient.patientId = patientId_;
  const auto studies = pacs::dimseFindStudies(endpoint(), byPatient);
  ASSERT_EQ(studies.size(), 1u);
  EXPECT_EQ(studies[0].studyInstanceUid, studyUid_);
  EXPECT_EQ(studies[0].patientId, patientId_);
  EXPECT_EQ(studies[0].studyDate, studyDate_);
  EXPECT_EQ(studies[0].modalities, std::vector<std::string>{"CT"});
  EXPECT_EQ(studies[0].seriesCount, 1);
  EXPECT_EQ(studies[0].instanceCount, static_cast<int64_t>(originals_.size()));

  pacs::StudyQuery byModality;
  byModality.modality = "CT";
  byModality.studyDateFrom = studyDate_;
  byModality.studyDateTo = studyDate_;
  const auto ct = pacs::dimseFindStudies(endpoint(), byModality);
  ASSERT_EQ(ct.size(), 1u);
  EXPECT_EQ(ct[0].studyInstanceUid, studyUid_);

  pacs::StudyQuery none;
  none.modality = "MR";
  EXPECT_TRUE(pacs::dimseFindStudies(endpoint(), none).empty());
  none = {};
  none.patientName = "NOBODY*";
  EXPECT_TRUE(pacs::dimseFindStudies(endpoint(), none).empty());
  none = {};
  none.studyDateTo = "19000101";
  EXPECT_TRUE(pacs::dimseFindStudies(endpoint(), none).empty());
}

TEST_F(DimseOrthanc, FindsTheSeriesAndItsInstances) {
  const auto series = pacs::dimseFindSeries(endpoint(), studyUid_);
  ASSERT_EQ(series.size(), 1u);
  EXPECT_EQ(series[0].studyInstanceUid, studyUid_);
  EXPECT_EQ(series[0].seriesInstanceUid, seriesUid_);
  EXPECT_EQ(series[0].modality, "CT");
  EXPECT_EQ(series[0].seriesNumber, "201");
  EXPECT_EQ(series[0].instanceCount, static_cast<int64_t>(originals_.size()));
  EXPECT_TRUE(pacs::dimseFindSeries(endpoint(), studyUid_, "MR").empty());

  const auto instances = pacs::dimseFindInstances(endpoint(), studyUid_, seriesUid_);
  std::set<std::string> uids;
  for (const auto& instance : instances) {
    uids.insert(instance.sopInstanceUid);
    EXPECT_EQ(instance.sopClassUid, kCtImageStorage);
    EXPECT_GT(instance.instanceNumber, 0);
  }
  EXPECT_EQ(uids, originalUids());
  EXPECT_TRUE(std::is_sorted(instances.begin(), instances.end(), [](const auto& a, const auto& b) {
    return a.instanceNumber < b.instanceNumber;
  }));
  std::vector<fs::path> files;
  for (const auto& [uid, file] : originals_) files.push_back(file);
  expectListedGeometry(instances, geometryOfFiles(files));
}

TEST_F(DimseOrthanc, GetsTheWholeSeriesWithTheSamePixels) {
  std::map<std::string, std::vector<uint8_t>> received;
  std::vector<std::pair<int64_t, int64_t>> progress;
  pacs::dimseGetSeries(
      endpoint(), studyUid_, seriesUid_, {},
      [&](const std::string& uid, std::vector<uint8_t> part10) {
        received[uid] = std::move(part10);
      },
      [&](int64_t done, int64_t total) { progress.emplace_back(done, total); });

  std::set<std::string> uids;
  for (const auto& [uid, bytes] : received) uids.insert(uid);
  ASSERT_EQ(uids, originalUids());
  for (const auto& [uid, bytes] : received) {
    const Decoded got = decodeBytes(bytes, "the C-GET of " + uid);
    const Decoded original = decodeFile(originals_.at(uid));
    EXPECT_EQ(got.sopInstanceUid, uid);
    EXPECT_EQ(got.seriesUid, seriesUid_);
    EXPECT_EQ(got.transferSyntax, original.transferSyntax);
    EXPECT_TRUE(got.pixels == original.pixels) << uid << ": pixel data differ";
  }
  const auto total = static_cast<int64_t>(originals_.size());
  ASSERT_FALSE(progress.empty());
  EXPECT_EQ(progress.front(), std::make_pair(int64_t{0}, total));
  EXPECT_EQ(progress.back(), std::make_pair(total, total));
}

TEST_F(DimseOrthanc, GetsOnlyTheInstancesAskedFor) {
  std::vector<std::string> half;
  for (const auto& uid : originalUids()) {
    if (half.size() * 2 < originals_.size()) half.push_back(uid);
  }
  std::set<std::string> received;
  pacs::dimseGetSeries(endpoint(), studyUid_, seriesUid_, half,
                       [&](const std::string& uid, std::vector<uint8_t> part10) {
                         EXPECT_EQ(decodeBytes(part10, uid).sopInstanceUid, uid);
                         received.insert(uid);
                       });
  EXPECT_EQ(received, std::set<std::string>(half.begin(), half.end()));
}

TEST_F(DimseOrthanc, ReportsInstancesThatDoNotArrive) {
  const std::string present = *originalUids().begin();
  const std::string absent = "1.2.826.0.1.3680043.2.1143.999999999";
  std::set<std::string> received;
  EXPECT_ERROR_CONTAINING(pacs::dimseGetSeries(endpoint(), studyUid_, seriesUid_, {present, absent},
                                               [&](const std::string& uid, std::vector<uint8_t>) {
                                                 received.insert(uid);
                                               }),
                          "dicom://ORTHANC@127.0.0.1:" + std::to_string(server_->dicomPort()),
                          "delivered 1 of 2 instances");
  EXPECT_EQ(received, std::set<std::string>{present});
}

TEST_F(DimseOrthanc, StopsWhenTheCallerCannotStore) {
  int stored = 0;
  try {
    pacs::dimseGetSeries(endpoint(), studyUid_, seriesUid_, {},
                         [&](const std::string&, std::vector<uint8_t>) {
                           if (++stored == 3) throw std::runtime_error("disk full");
                         });
    ADD_FAILURE() << "the store callback's exception was swallowed";
  } catch (const std::runtime_error& e) {
    EXPECT_STREQ(e.what(), "disk full");
  }
  EXPECT_EQ(stored, 3);
  pacs::dimseEcho(endpoint());  // the server is fine, and so is a new association
}

// Orthanc sends what it holds: RLE and JPEG 2000 instances (pydicom's test files) come in their
// own transfer syntax, MR and Secondary Capture classes accepted because C-FIND listed them.
TEST_F(DimseOrthanc, ReceivesCompressedInstancesAsTheServerHoldsThem) {
  const fs::path rle = pydicomTestFiles() / "MR_small_RLE.dcm";
  const fs::path j2k = pydicomTestFiles() / "JPEG2000.dcm";
  OCTORAY_REQUIRE_PATH(rle);
  OCTORAY_REQUIRE_PATH(j2k);
  gdcm::Trace::WarningOff();  // JPEG2000.dcm's (0028,0009) is no spacing GDCM knows
  server_->upload({rle, j2k});
  for (const fs::path& file : {rle, j2k}) {
    const Decoded original = decodeFile(file);
    std::vector<std::pair<std::string, std::vector<uint8_t>>> received;
    pacs::dimseGetSeries(endpoint(), original.studyUid, original.seriesUid, {},
                         [&](const std::string& uid, std::vector<uint8_t> part10) {
                           received.emplace_back(uid, std::move(part10));
                         });
    ASSERT_EQ(received.size(), 1u) << file;
    const Decoded got = decodeBytes(received[0].second, file.string());
    EXPECT_EQ(got.sopInstanceUid, original.sopInstanceUid);
    EXPECT_EQ(got.transferSyntax, original.transferSyntax) << file;
    EXPECT_TRUE(got.pixels == original.pixels) << file << ": pixel data differ";
  }
}

// ---------------------------------------------------------------------------------------------
// Without a server

TEST(DimseUrl, ParsesCalledAetHostAndPort) {
  const DimseEndpoint endpoint = pacs::parseDimseUrl("dicom://PACS_1@pacs.example.org:11112");
  EXPECT_EQ(endpoint.calledAet, "PACS_1");
  EXPECT_EQ(endpoint.host, "pacs.example.org");
  EXPECT_EQ(endpoint.port, 11112);
  EXPECT_EQ(endpoint.callingAet, "OCTORAY");
  EXPECT_EQ(pacs::dimseUrl(endpoint), "dicom://PACS_1@pacs.example.org:11112");
  EXPECT_EQ(pacs::parseDimseUrl("DICOM://ORTHANC@10.0.0.2/").port, 104);
  EXPECT_EQ(pacs::parseDimseUrl("DICOM://ORTHANC@10.0.0.2/").host, "10.0.0.2");

  for (const std::string bad :
       {"http://ORTHANC@host:104", "dicom://host:104", "dicom://@host:104", "dicom://AET@:104",
        "dicom://AET@host:0", "dicom://AET@host:65536", "dicom://AET@host:1o4",
        "dicom://AET@host:", "dicom://AE_TITLE_OF_17_CHARS@host", "dicom://A\\B@host",
        "dicom://AET@host:104/studies", "dicom://AET@[::1]:104"}) {
    try {
      pacs::parseDimseUrl(bad);
      ADD_FAILURE() << bad << " was accepted";
    } catch (const octoray::Error& e) {
      EXPECT_EQ(e.path(), bad);
    }
  }
  for (const std::string bad : {"dicom://AE_TITLE_OF_17_CHARS@host", "dicom://A\\B@host"}) {
    EXPECT_ERROR_CONTAINING(pacs::parseDimseUrl(bad), bad, "the AE title", "is not valid");
  }
}

TEST(DimseErrors, NothingListeningFailsAtOnceNamingTheServer) {
  const int port = unusedPort();
  const DimseEndpoint endpoint = loopback(port);
  const auto start = Clock::now();
  const std::string server = "dicom://ORTHANC@127.0.0.1:" + std::to_string(port);
  EXPECT_ERROR_CONTAINING(pacs::dimseEcho(endpoint), server, "connection refused", "OCTORAY-TEST");
  EXPECT_ERROR_CONTAINING(pacs::dimseFindStudies(endpoint, {}), server, "connection refused");
  EXPECT_ERROR_CONTAINING(pacs::dimseGetSeries(endpoint, "1.2.3", "1.2.3.4", {},
                                               [](const std::string&, std::vector<uint8_t>) {}),
                          server, "connection refused");
  EXPECT_LT(Clock::now() - start, std::chrono::seconds(3));
}

TEST(DimseErrors, SilentServerTimesOut) {
  FakeServer silent({});
  DimseEndpoint endpoint = loopback(silent.port());
  endpoint.timeoutSeconds = 1;
  const auto start = Clock::now();
  EXPECT_ERROR_CONTAINING(pacs::dimseEcho(endpoint), "127.0.0.1:" + std::to_string(silent.port()),
                          "no answer within 1 s");
  EXPECT_LT(Clock::now() - start, std::chrono::seconds(5));
}

TEST(DimseErrors, RejectedAssociationSaysWhy) {
  // A-ASSOCIATE-RJ (PS3.8 9.3.4): rejected permanent, by the service user, called AE title
  // not recognized.
  FakeServer rejecting({0x03, 0x00, 0x00, 0x00, 0x00, 0x04, 0x00, 0x01, 0x01, 0x07});
  EXPECT_ERROR_CONTAINING(pacs::dimseEcho(loopback(rejecting.port(), "NOT-ORTHANC")),
                          "dicom://NOT-ORTHANC@127.0.0.1:", "rejected",
                          "called AE title not recognized", "permanent");
}

TEST(DimseErrors, InvalidAeTitlesAreRefusedBeforeConnecting) {
  DimseEndpoint endpoint = loopback(unusedPort());
  endpoint.callingAet = "AN_AE_TITLE_TOO_LONG";
  EXPECT_ERROR_CONTAINING(pacs::dimseEcho(endpoint), "calling AE title", "not valid");
  endpoint = loopback(unusedPort(), "");
  EXPECT_ERROR_CONTAINING(pacs::dimseEcho(endpoint), "called AE title", "not valid");
}

}  // namespace
}  // namespace octoray::test
