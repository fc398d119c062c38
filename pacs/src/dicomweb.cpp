#include "octoray/pacs/dicomweb.h"

#include <curl/curl.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <mutex>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "octoray/core/error.h"
#include "octoray/core/text.h"
#include "octoray/pacs/multipart.h"

namespace octoray::pacs {

namespace {

// Larger answers are refused: a WADO-RS instance is at most a few hundred MB, a QIDO answer
// far less; a server sending more is broken or hostile.
constexpr std::size_t kMaxResponseBytes = std::size_t{2} << 30;

void initialiseCurlOnce() {
  static std::once_flag once;
  std::call_once(once, [] {
    if (curl_global_init(CURL_GLOBAL_DEFAULT) != CURLE_OK) {
      throw Error("libcurl", "cannot initialise");
    }
  });
}

// The first value of a DICOM JSON attribute (PS3.18 F.2) as text: strings as they are,
// numbers printed, person names as their Alphabetic group. Empty when absent.
std::string firstValue(const nlohmann::json& dataset, const char* tag) {
  const auto it = dataset.find(tag);
  if (it == dataset.end() || !it->is_object()) return {};
  const auto value = it->find("Value");
  if (value == it->end() || !value->is_array() || value->empty()) return {};
  const nlohmann::json& v = value->front();
  if (v.is_string()) return v.get<std::string>();
  if (v.is_number_integer()) return std::to_string(v.get<int64_t>());
  if (v.is_number()) return fmt::format("{}", v.get<double>());
  if (v.is_object()) return v.value("Alphabetic", std::string());
  return {};
}

std::vector<std::string> allValues(const nlohmann::json& dataset, const char* tag) {
  std::vector<std::string> out;
  const auto it = dataset.find(tag);
  if (it == dataset.end() || !it->is_object()) return out;
  const auto value = it->find("Value");
  if (value == it->end() || !value->is_array()) return out;
  for (const auto& v : *value) {
    if (v.is_string()) out.push_back(v.get<std::string>());
  }
  return out;
}

// A multi-valued DS (numbers, or strings holding numbers, PS3.18 F.2.3); empty when a value
// is missing or not a finite number, or the count is not `count`.
std::vector<double> numberValues(const nlohmann::json& dataset, const char* tag, std::size_t count) {
  std::vector<double> out;
  const auto it = dataset.find(tag);
  if (it == dataset.end() || !it->is_object()) return out;
  const auto value = it->find("Value");
  if (value == it->end() || !value->is_array() || value->size() != count) return out;
  for (const auto& v : *value) {
    double x = std::numeric_limits<double>::quiet_NaN();
    if (v.is_number()) {
      x = v.get<double>();
    } else if (v.is_string()) {
      const std::string text = v.get<std::string>();
      char* end = nullptr;
      x = std::strtod(text.c_str(), &end);
      if (end == text.c_str() || *end != '\0') x = std::numeric_limits<double>::quiet_NaN();
    }
    if (!std::isfinite(x)) return {};
    out.push_back(x);
  }
  return out;
}

int64_t countValue(const nlohmann::json& dataset, const char* tag) {
  const std::string text = firstValue(dataset, tag);
  if (text.empty()) return -1;
  try {
    return std::stoll(text);
  } catch (const std::exception&) {
    return -1;
  }
}

// A UID as a path segment: digits and dots only (anything else could escape the path).
const std::string& checkedUid(const std::string& uid, const char* what) {
  if (!isDicomUid(uid)) {
    throw Error("", fmt::format("{} \"{}\" is not a DICOM UID (digits and dots, at most 64)", what, uid));
  }
  return uid;
}

}  // namespace

bool isHttpUrl(const std::string& text) {
  const std::string low = asciiLower(text.substr(0, 8));
  return low.starts_with("http://") || low.starts_with("https://");
}

DicomWebTarget parseDicomWebUrl(const std::string& url) {
  refuseCredentialsInUrl(url);
  if (!isHttpUrl(url)) throw Error(url, "not an http:// or https:// URL");
  DicomWebTarget target;
  std::string rest = url;
  const auto query = rest.find_first_of("?#");
  if (query != std::string::npos) rest.resize(query);
  while (!rest.empty() && rest.back() == '/') rest.pop_back();
  const auto studies = rest.find("/studies/");
  if (studies == std::string::npos) {
    target.baseUrl = rest;
    return target;
  }
  target.baseUrl = rest.substr(0, studies);
  std::string tail = rest.substr(studies + 9);
  const auto series = tail.find("/series/");
  if (series == std::string::npos) {
    target.studyUid = tail;
  } else {
    target.studyUid = tail.substr(0, series);
    target.seriesUid = tail.substr(series + 8);
    if (const auto more = target.seriesUid.find('/'); more != std::string::npos) {
      target.seriesUid.resize(more);
    }
  }
  checkedUid(target.studyUid, "study UID in the URL");
  if (!target.seriesUid.empty()) checkedUid(target.seriesUid, "series UID in the URL");
  return target;
}

struct DicomWebClient::Curl {
  CURL* handle = nullptr;
  ~Curl() {
    if (handle != nullptr) curl_easy_cleanup(handle);
  }
};

struct DicomWebClient::Response {
  long status = 0;
  std::string contentType;
  std::string body;
};

DicomWebClient::DicomWebClient(std::string baseUrl, DicomWebOptions options)
    : baseUrl_(std::move(baseUrl)), options_(std::move(options)), curl_(std::make_unique<Curl>()) {
  refuseCredentialsInUrl(baseUrl_);
  if (!isHttpUrl(baseUrl_)) throw Error(baseUrl_, "not an http:// or https:// URL");
  while (!baseUrl_.empty() && baseUrl_.back() == '/') baseUrl_.pop_back();
  initialiseCurlOnce();
  curl_->handle = curl_easy_init();
  if (curl_->handle == nullptr) throw Error(baseUrl_, "cannot create a libcurl handle");
}

DicomWebClient::~DicomWebClient() = default;

namespace {

struct Sink {
  std::string* body;
  bool tooLarge = false;
};

size_t writeBody(char* data, size_t size, size_t count, void* user) {
  auto* sink = static_cast<Sink*>(user);
  const size_t bytes = size * count;
  if (sink->body->size() + bytes > kMaxResponseBytes) {
    sink->tooLarge = true;
    return 0;  // aborts the transfer
  }
  sink->body->append(data, bytes);
  return bytes;
}

std::string describeCurlError(CURLcode code, const char* detail) {
  std::string what;
  switch (code) {
    case CURLE_COULDNT_RESOLVE_HOST: what = "cannot resolve the host name"; break;
    case CURLE_COULDNT_CONNECT: what = "cannot connect (server down or port closed)"; break;
    case CURLE_OPERATION_TIMEDOUT: what = "timed out"; break;
    case CURLE_PEER_FAILED_VERIFICATION:
      what = "the server's TLS certificate is not trusted (self-signed or from a private CA? "
             "pass its CA as --ca-file PEM; verification stays on)";
      break;
    case CURLE_SSL_CONNECT_ERROR: what = "TLS handshake failed"; break;
    case CURLE_PARTIAL_FILE:
    case CURLE_RECV_ERROR:
    case CURLE_GOT_NOTHING:
      what = "the server closed the connection before the answer was complete";
      break;
    case CURLE_SSL_CACERT_BADFILE: what = "cannot read the --ca-file"; break;
    default: what = curl_easy_strerror(code); break;
  }
  if (detail != nullptr && *detail) what += fmt::format(" ({})", detail);
  return what;
}

}  // namespace

DicomWebClient::Response DicomWebClient::get(const std::string& pathAndQuery,
                                             const std::string& accept) {
  CURL* h = curl_->handle;
  curl_easy_reset(h);
  Response response;
  Sink sink{&response.body};
  char errorBuffer[CURL_ERROR_SIZE] = {};
  const std::string url = baseUrl_ + pathAndQuery;
  // Messages name the resource without its query (which may hold a patient ID).
  const std::string origin = baseUrl_ + pathAndQuery.substr(0, pathAndQuery.find('?'));
  curl_easy_setopt(h, CURLOPT_URL, url.c_str());
  curl_easy_setopt(h, CURLOPT_PROTOCOLS_STR, "http,https");
  curl_easy_setopt(h, CURLOPT_NOSIGNAL, 1L);
  curl_easy_setopt(h, CURLOPT_FOLLOWLOCATION, 0L);
  curl_easy_setopt(h, CURLOPT_SSL_VERIFYPEER, 1L);
  curl_easy_setopt(h, CURLOPT_SSL_VERIFYHOST, 2L);
  if (!options_.caFile.empty()) curl_easy_setopt(h, CURLOPT_CAINFO, options_.caFile.c_str());
  curl_easy_setopt(h, CURLOPT_CONNECTTIMEOUT, static_cast<long>(options_.connectTimeoutSeconds));
  curl_easy_setopt(h, CURLOPT_LOW_SPEED_LIMIT, 1L);
  curl_easy_setopt(h, CURLOPT_LOW_SPEED_TIME, static_cast<long>(options_.stallTimeoutSeconds));
  curl_easy_setopt(h, CURLOPT_ERRORBUFFER, errorBuffer);
  curl_easy_setopt(h, CURLOPT_WRITEFUNCTION, writeBody);
  curl_easy_setopt(h, CURLOPT_WRITEDATA, &sink);
  curl_easy_setopt(h, CURLOPT_USERAGENT, "octoray-pacs");
  // No compression asked: a server deflating every instance costs more than it saves (Orthanc
  // on loopback, 140 CT slices, 75 MB: 6.1 s with gzip, 0.58 s without; octoray-pacs get).
  curl_easy_setopt(h, CURLOPT_ACCEPT_ENCODING, nullptr);
  switch (options_.credentials.kind) {
    case Credentials::Kind::Basic:
      curl_easy_setopt(h, CURLOPT_HTTPAUTH, CURLAUTH_BASIC);
      curl_easy_setopt(h, CURLOPT_USERNAME, options_.credentials.user.c_str());
      curl_easy_setopt(h, CURLOPT_PASSWORD, options_.credentials.secret.c_str());
      break;
    case Credentials::Kind::Bearer:
      curl_easy_setopt(h, CURLOPT_HTTPAUTH, CURLAUTH_BEARER);
      curl_easy_setopt(h, CURLOPT_XOAUTH2_BEARER, options_.credentials.secret.c_str());
      break;
    case Credentials::Kind::None: break;
  }
  curl_slist* headers = curl_slist_append(nullptr, ("Accept: " + accept).c_str());
  curl_easy_setopt(h, CURLOPT_HTTPHEADER, headers);
  const CURLcode code = curl_easy_perform(h);
  curl_slist_free_all(headers);
  if (sink.tooLarge) {
    throw Error(origin, fmt::format("answer larger than {} GiB refused", kMaxResponseBytes >> 30));
  }
  if (code != CURLE_OK) throw Error(origin, describeCurlError(code, errorBuffer));
  curl_easy_getinfo(h, CURLINFO_RESPONSE_CODE, &response.status);
  char* type = nullptr;
  curl_easy_getinfo(h, CURLINFO_CONTENT_TYPE, &type);
  if (type != nullptr) response.contentType = type;
  if (response.status == 401) {
    throw Error(origin, options_.credentials.kind == Credentials::Kind::None
                            ? "the server asks for credentials (HTTP 401): give --credentials FILE"
                            : "authentication failed (HTTP 401): the credentials were refused");
  }
  if (response.status == 403) throw Error(origin, "access denied (HTTP 403)");
  if (response.status == 404) throw Error(origin, "not found (HTTP 404)");
  if (response.status == 204) return response;  // QIDO: no match
  if (response.status < 200 || response.status >= 300) {
    throw Error(origin, fmt::format("the server answered HTTP {}", response.status));
  }
  return response;
}

namespace {

nlohmann::json parseQidoAnswer(const std::string& body, long status, const std::string& origin) {
  if (status == 204 || body.empty()) return nlohmann::json::array();
  nlohmann::json j = nlohmann::json::parse(body, nullptr, false);
  if (j.is_discarded() || !j.is_array()) {
    throw Error(origin, "the QIDO-RS answer is not a JSON array of datasets");
  }
  return j;
}

std::string escape(CURL* h, const std::string& value) {
  char* out = curl_easy_escape(h, value.c_str(), static_cast<int>(value.size()));
  std::string s = out != nullptr ? out : "";
  curl_free(out);
  return s;
}

}  // namespace

std::vector<StudyRecord> DicomWebClient::findStudies(const StudyQuery& q) {
  std::string query = "/studies?includefield=00081030&includefield=00080061&includefield=00201206"
                      "&includefield=00201208&includefield=00080050";
  auto add = [&](const char* key, const std::string& value) {
    if (!value.empty()) query += fmt::format("&{}={}", key, escape(curl_->handle, value));
  };
  add("PatientID", q.patientId);
  add("PatientName", q.patientName);
  add("AccessionNumber", q.accessionNumber);
  add("ModalitiesInStudy", q.modality);
  if (!q.studyInstanceUid.empty()) add("StudyInstanceUID", checkedUid(q.studyInstanceUid, "study UID"));
  if (!q.studyDateFrom.empty() || !q.studyDateTo.empty()) {
    add("StudyDate", q.studyDateFrom + "-" + q.studyDateTo);
  }
  const Response r = get(query, "application/dicom+json");
  std::vector<StudyRecord> studies;
  for (const auto& d : parseQidoAnswer(r.body, r.status, baseUrl_ + "/studies")) {
    StudyRecord s;
    s.studyInstanceUid = firstValue(d, "0020000D");
    s.patientId = firstValue(d, "00100020");
    s.patientName = firstValue(d, "00100010");
    s.studyDate = firstValue(d, "00080020");
    s.accessionNumber = firstValue(d, "00080050");
    s.studyDescription = firstValue(d, "00081030");
    s.modalities = allValues(d, "00080061");
    s.seriesCount = countValue(d, "00201206");
    s.instanceCount = countValue(d, "00201208");
    if (!s.studyInstanceUid.empty()) studies.push_back(std::move(s));
  }
  return studies;
}

std::vector<SeriesRecord> DicomWebClient::findSeries(const std::string& studyUid,
                                                     const std::string& modality) {
  std::string query = fmt::format("/studies/{}/series?includefield=0008103E&includefield=00201209"
                                  "&includefield=00200011",
                                  checkedUid(studyUid, "study UID"));
  if (!modality.empty()) query += "&Modality=" + escape(curl_->handle, modality);
  const Response r = get(query, "application/dicom+json");
  std::vector<SeriesRecord> series;
  for (const auto& d : parseQidoAnswer(r.body, r.status, baseUrl_ + "/studies/" + studyUid + "/series")) {
    SeriesRecord s;
    s.studyInstanceUid = studyUid;
    s.seriesInstanceUid = firstValue(d, "0020000E");
    s.modality = firstValue(d, "00080060");
    s.seriesNumber = firstValue(d, "00200011");
    s.seriesDescription = firstValue(d, "0008103E");
    s.instanceCount = countValue(d, "00201209");
    if (!s.seriesInstanceUid.empty()) series.push_back(std::move(s));
  }
  return series;
}

std::vector<InstanceRecord> DicomWebClient::findInstances(const std::string& studyUid,
                                                          const std::string& seriesUid) {
  // ImagePositionPatient and ImageOrientationPatient are not in QIDO-RS's default instance
  // attributes (PS3.18 Table 10.6.3-5): ask for them.
  const std::string path = fmt::format("/studies/{}/series/{}/instances?includefield=00200032&includefield=00200037",
                                       checkedUid(studyUid, "study UID"),
                                       checkedUid(seriesUid, "series UID"));
  const Response r = get(path, "application/dicom+json");
  std::vector<InstanceRecord> instances;
  for (const auto& d : parseQidoAnswer(r.body, r.status, baseUrl_ + path)) {
    InstanceRecord i;
    i.sopInstanceUid = firstValue(d, "00080018");
    i.sopClassUid = firstValue(d, "00080016");
    i.instanceNumber = countValue(d, "00200013");
    if (const auto p = numberValues(d, "00200032", 3); !p.empty()) i.position = std::array<double, 3>{p[0], p[1], p[2]};
    if (const auto o = numberValues(d, "00200037", 6); !o.empty()) {
      i.orientation = std::array<double, 6>{o[0], o[1], o[2], o[3], o[4], o[5]};
    }
    if (!i.sopInstanceUid.empty()) instances.push_back(std::move(i));
  }
  return instances;
}

std::vector<uint8_t> DicomWebClient::retrieveMultipartSingle(const std::string& path) {
  Response r;
  try {
    // The original transfer syntax, whatever it is (PS3.18 8.7.3.5.2).
    r = get(path, "multipart/related; type=\"application/dicom\"; transfer-syntax=*");
  } catch (const Error& e) {
    // A server that does not know transfer-syntax=* may refuse it (406, 400): ask plainly.
    if (e.reason().find("HTTP 406") == std::string::npos &&
        e.reason().find("HTTP 400") == std::string::npos) {
      throw;
    }
    r = get(path, "multipart/related; type=\"application/dicom\"");
  }
  const std::string origin = baseUrl_ + path;
  const std::string boundary = multipartBoundary(r.contentType, origin);
  const auto parts = parseMultipart(r.body, boundary, origin);
  if (parts.size() != 1) {
    throw Error(origin, fmt::format("expected one instance in the answer, got {}", parts.size()));
  }
  const std::string_view body = parts.front().body;
  if (body.size() < 132 || body.substr(128, 4) != "DICM") {
    throw Error(origin, "the part is not a DICOM Part-10 file (no DICM preamble)");
  }
  return {body.begin(), body.end()};
}

std::vector<uint8_t> DicomWebClient::retrieveInstance(const std::string& studyUid,
                                                      const std::string& seriesUid,
                                                      const std::string& sopInstanceUid) {
  return retrieveMultipartSingle(fmt::format("/studies/{}/series/{}/instances/{}",
                                             checkedUid(studyUid, "study UID"),
                                             checkedUid(seriesUid, "series UID"),
                                             checkedUid(sopInstanceUid, "SOP instance UID")));
}

}  // namespace octoray::pacs
