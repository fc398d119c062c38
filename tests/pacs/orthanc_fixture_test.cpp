// The Orthanc fixture itself: it starts, stores what it is sent, serves HTTPS with basic auth
// when asked, and leaves neither a process nor an open port behind.

#include <arpa/inet.h>
#include <curl/curl.h>
#include <dirent.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <fstream>
#include <iterator>
#include <nlohmann/json.hpp>

#include "orthanc_server.h"
#include "test_paths.h"

namespace octoray::test {
namespace {

namespace fs = std::filesystem;

#define OCTORAY_REQUIRE_ORTHANC()                                                 \
  do {                                                                            \
    if (!OrthancServer::available()) {                                            \
      GTEST_SKIP() << "skipped: Orthanc or its DICOMweb plugin is not installed " \
                      "(apt-get install orthanc orthanc-dicomweb)";               \
    }                                                                             \
  } while (0)

struct Answer {
  CURLcode result = CURLE_OK;
  long status = 0;
  std::string body;
};

size_t collect(char* data, size_t size, size_t count, void* sink) {
  static_cast<std::string*>(sink)->append(data, size * count);
  return size * count;
}

// A plain GET, with optional credentials and CA file.
Answer get(const std::string& url, const std::string& user = {}, const std::string& password = {},
           const fs::path& caFile = {}) {
  Answer answer;
  CURL* curl = curl_easy_init();
  curl_easy_setopt(curl, CURLOPT_URL, url.c_str());
  curl_easy_setopt(curl, CURLOPT_NOPROXY, "*");
  curl_easy_setopt(curl, CURLOPT_NOSIGNAL, 1L);
  curl_easy_setopt(curl, CURLOPT_TIMEOUT, 20L);
  curl_easy_setopt(curl, CURLOPT_WRITEFUNCTION, &collect);
  curl_easy_setopt(curl, CURLOPT_WRITEDATA, &answer.body);
  if (!user.empty()) {
    curl_easy_setopt(curl, CURLOPT_USERNAME, user.c_str());
    curl_easy_setopt(curl, CURLOPT_PASSWORD, password.c_str());
  }
  if (!caFile.empty()) curl_easy_setopt(curl, CURLOPT_CAINFO, caFile.c_str());
  answer.result = curl_easy_perform(curl);
  curl_easy_getinfo(curl, CURLINFO_RESPONSE_CODE, &answer.status);
  curl_easy_cleanup(curl);
  return answer;
}

// True when something accepts TCP connections on 127.0.0.1:port.
bool listening(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_port = htons(static_cast<uint16_t>(port));
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  const bool connected = ::connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) == 0;
  ::close(fd);
  return connected;
}

// Processes whose command line mentions `needle` (the server's own configuration file).
int processesMentioning(const std::string& needle) {
  int count = 0;
  for (const auto& entry : fs::directory_iterator("/proc")) {
    std::ifstream in(entry.path() / "cmdline", std::ios::binary);
    const std::string cmdline{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
    if (cmdline.find(needle) != std::string::npos) ++count;
  }
  return count;
}

std::vector<fs::path> firstImages(const fs::path& dir, std::size_t count) {
  std::vector<fs::path> files;
  for (const auto& entry : fs::directory_iterator(dir)) {
    if (entry.path().filename() != "DIRFILE") files.push_back(entry.path());
  }
  std::sort(files.begin(), files.end());
  files.resize(std::min(files.size(), count));
  return files;
}

TEST(OrthancFixture, StartsStoresAndStopsCleanly) {
  OCTORAY_REQUIRE_ORTHANC();
  const fs::path series = philipsDir() / "S21570/S2010";
  OCTORAY_REQUIRE_PATH(series);
  const fs::path dir = freshTempDir("orthanc");
  const std::string config = (dir / "orthanc.json").string();
  int httpPort = 0, dicomPort = 0;
  {
    OrthancServer server(dir);
    httpPort = server.httpPort();
    dicomPort = server.dicomPort();
    EXPECT_EQ(server.httpUrl(), "http://127.0.0.1:" + std::to_string(httpPort));
    EXPECT_EQ(server.dicomWebUrl(), server.httpUrl() + "/dicom-web");
    EXPECT_EQ(server.aeTitle(), "ORTHANC");
    EXPECT_TRUE(server.certificate().empty());
    EXPECT_EQ(processesMentioning(config), 1);
    EXPECT_TRUE(listening(dicomPort));

    server.upload(firstImages(series, 3));
    const Answer instances = get(server.httpUrl() + "/instances");
    ASSERT_EQ(instances.result, CURLE_OK);
    ASSERT_EQ(instances.status, 200);
    EXPECT_EQ(nlohmann::json::parse(instances.body).size(), 3u);
    // The DICOMweb plugin answers too.
    EXPECT_EQ(get(server.dicomWebUrl() + "/studies").status, 200);
    // Not DICOM: refused, and the file named.
    const fs::path notDicom = dir / "not-dicom.txt";
    std::ofstream(notDicom) << "not a DICOM file\n";
    try {
      server.upload({notDicom});
      ADD_FAILURE() << "a text file was accepted";
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find("not-dicom.txt"), std::string::npos) << e.what();
    }
  }
  EXPECT_FALSE(listening(httpPort));
  EXPECT_FALSE(listening(dicomPort));
  EXPECT_EQ(processesMentioning(config), 0);
}

TEST(OrthancFixture, ServesHttpsWithBasicAuth) {
  OCTORAY_REQUIRE_ORTHANC();
  const fs::path series = philipsDir() / "S21570/S2010";
  OCTORAY_REQUIRE_PATH(series);
  OrthancServer server(freshTempDir("orthanc"), {true, "alice", "s3cret:x"});
  ASSERT_EQ(server.httpUrl().rfind("https://127.0.0.1:", 0), 0u) << server.httpUrl();
  ASSERT_TRUE(fs::exists(server.certificate()));

  EXPECT_EQ(get(server.httpUrl() + "/system", "alice", "s3cret:x", server.certificate()).status,
            200);
  EXPECT_EQ(get(server.httpUrl() + "/system", {}, {}, server.certificate()).status, 401);
  EXPECT_EQ(get(server.httpUrl() + "/system", "alice", "wrong", server.certificate()).status, 401);
  // Untrusted without the certificate.
  EXPECT_EQ(get(server.httpUrl() + "/system", "alice", "s3cret:x").result,
            CURLE_PEER_FAILED_VERIFICATION);

  server.upload(firstImages(series, 1));
  const Answer instances =
      get(server.httpUrl() + "/instances", "alice", "s3cret:x", server.certificate());
  ASSERT_EQ(instances.status, 200);
  EXPECT_EQ(nlohmann::json::parse(instances.body).size(), 1u);
}

}  // namespace
}  // namespace octoray::test
