// DIMSE through DCMTK's dcmnet at the level of its ASC_ and DIMSE_ functions rather than
// DcmSCU: DcmSCU 3.6.7 keeps an association's reject reason to itself, and its C-GET loop
// cannot hand instances over in memory. Every call opens one association, does its work and
// releases it; everything DCMTK allocates is owned by a unique_ptr or by Association.

#include "octoray/pacs/dimse.h"

#include "dimse_association.h"

// clang-format off
#include <dcmtk/config/osconfig.h>  // DCMTK's configuration comes before any other DCMTK header
// clang-format on
#include <dcmtk/dcmdata/dcdeftag.h>
#include <dcmtk/dcmdata/dcfilefo.h>
#include <dcmtk/dcmdata/dcostrmb.h>
#include <dcmtk/dcmdata/dcuid.h>
#include <dcmtk/dcmdata/dcxfer.h>
#include <dcmtk/dcmnet/assoc.h>
#include <dcmtk/dcmnet/dimse.h>
#include <dcmtk/dcmnet/diutil.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <exception>
#include <memory>
#include <set>
#include <unordered_set>

#include "octoray/core/error.h"
#include "octoray/core/text.h"

namespace octoray::pacs {
namespace {

using detail::Association;
using detail::checkAeTitle;
using detail::ContextRequest;
using detail::statusHex;
using detail::uncompressedSyntaxes;

// SOPInstanceUIDs per C-GET request when only some instances are wanted (4 KB of keys).
constexpr std::size_t kUidsPerGet = 64;

// ---------------------------------------------------------------------------------------------
// C-FIND

std::string getString(DcmDataset& dataset, const DcmTagKey& tag) {
  OFString value;
  if (dataset.findAndGetOFStringArray(tag, value).bad()) return {};
  std::string text(value.c_str(), value.length());
  while (!text.empty() && (text.back() == ' ' || text.back() == '\0')) text.pop_back();
  while (!text.empty() && text.front() == ' ') text.erase(text.begin());
  return text;
}

int64_t getCount(DcmDataset& dataset, const DcmTagKey& tag) {
  const std::string text = getString(dataset, tag);
  if (text.empty()) return -1;
  char* end = nullptr;
  const long long value = std::strtoll(text.c_str(), &end, 10);
  return (end && *end == '\0') ? value : -1;
}

// A multi-valued DS ("a\\b\\c"); empty unless it holds exactly `count` finite numbers.
std::vector<double> getNumbers(DcmDataset& dataset, const DcmTagKey& tag, std::size_t count) {
  const std::string text = getString(dataset, tag);
  std::vector<double> out;
  std::size_t start = 0;
  while (start <= text.size() && !text.empty()) {
    const std::size_t end = std::min(text.find('\\', start), text.size());
    const std::string item = text.substr(start, end - start);
    char* stop = nullptr;
    const double x = std::strtod(item.c_str(), &stop);
    if (item.empty() || stop == item.c_str() || !std::isfinite(x)) return {};
    while (*stop == ' ') ++stop;
    if (*stop != '\0') return {};
    out.push_back(x);
    start = end + 1;
  }
  return out.size() == count ? out : std::vector<double>{};
}

bool isAscii(const std::string& text) {
  return std::all_of(text.begin(), text.end(), [](char c) { return (c & 0x80) == 0; });
}

// Answers come in the server's character set: converted to UTF-8 where DCMTK can; where it
// cannot, or where bytes outside ASCII come without a character set, they become '?' so that
// no invalid UTF-8 reaches the caller.
void toUtf8(DcmDataset& dataset) {
  const std::string charset = getString(dataset, DCM_SpecificCharacterSet);
  if (charset == "ISO_IR 192") return;
  if (!charset.empty() && charset != "ISO_IR 6" && dataset.convertToUTF8().good()) return;
  for (unsigned long i = 0; i < dataset.card(); ++i) {
    DcmElement* element = dataset.getElement(i);
    char* value = nullptr;
    if (!element || !element->isaString() || element->getString(value).bad() || !value) continue;
    std::string text(value);
    if (isAscii(text)) continue;
    for (char& c : text) {
      if (c & 0x80) c = '?';
    }
    element->putString(text.c_str());
  }
}

// Sends one Study Root C-FIND and returns the identifiers of every match.
std::vector<std::unique_ptr<DcmDataset>> find(const DimseEndpoint& endpoint, DcmDataset& keys) {
  Association association(endpoint, {{UID_FINDStudyRootQueryRetrieveInformationModel,
                                      uncompressedSyntaxes(), ASC_SC_ROLE_DEFAULT}});
  const T_ASC_PresentationContextID context =
      association.contextFor(UID_FINDStudyRootQueryRetrieveInformationModel, "Study Root C-FIND");

  struct Matches {
    std::vector<std::unique_ptr<DcmDataset>> datasets;
    bool outOfMemory = false;
  } matches;
  // Called from C code: no exception may leave it.
  auto collect = [](void* data, T_DIMSE_C_FindRQ*, int, T_DIMSE_C_FindRSP*, DcmDataset* ids) {
    auto* found = static_cast<Matches*>(data);
    if (!ids) return;
    try {
      found->datasets.push_back(std::make_unique<DcmDataset>(*ids));
    } catch (const std::bad_alloc&) {
      found->outOfMemory = true;
    }
  };

  T_DIMSE_C_FindRQ request{};
  request.MessageID = association.get()->nextMsgID++;
  OFStandard::strlcpy(request.AffectedSOPClassUID, UID_FINDStudyRootQueryRetrieveInformationModel,
                      sizeof request.AffectedSOPClassUID);
  request.Priority = DIMSE_PRIORITY_MEDIUM;
  request.DataSetType = DIMSE_DATASET_PRESENT;
  T_DIMSE_C_FindRSP response{};
  DcmDataset* rawDetail = nullptr;
  int responses = 0;
  const OFCondition condition =
      DIMSE_findUser(association.get(), context, &request, &keys, responses, collect, &matches,
                     DIMSE_NONBLOCKING, association.timeout(), &response, &rawDetail);
  std::unique_ptr<DcmDataset> detail(rawDetail);
  if (condition.bad()) association.fail("C-FIND", condition);
  if (matches.outOfMemory) association.fail("C-FIND: out of memory");
  if (response.DimseStatus != STATUS_Success) {
    association.fail(fmt::format("C-FIND failed: {} (status {})",
                                 DU_cfindStatusString(response.DimseStatus),
                                 statusHex(response.DimseStatus)));
  }
  for (auto& dataset : matches.datasets) toUtf8(*dataset);
  return std::move(matches.datasets);
}

// Puts `value` (possibly empty: a return key) into the query.
void putKey(DcmDataset& keys, const DcmTagKey& tag, const std::string& value) {
  keys.putAndInsertString(tag, value.c_str());
}

// PS3.4 C.2.2.2.5: "from-to", "from-", "-to" or one date.
std::string dateRange(const std::string& from, const std::string& to) {
  if (from.empty() && to.empty()) return {};
  if (from == to) return from;
  return from + "-" + to;
}

std::vector<std::string> splitValues(const std::string& text) {
  std::vector<std::string> values;
  std::size_t start = 0;
  while (start <= text.size()) {
    const std::size_t end = std::min(text.find('\\', start), text.size());
    if (end > start) values.push_back(text.substr(start, end - start));
    start = end + 1;
  }
  return values;
}

// ---------------------------------------------------------------------------------------------
// C-GET

// The transfer syntaxes a retrieved instance may come in, one presentation context each after
// the uncompressed pair, so the server can send every instance as it holds it.
const std::vector<const char*>& compressedSyntaxes() {
  static const std::vector<const char*> syntaxes = {
      UID_JPEGProcess14SV1TransferSyntax,     UID_JPEGProcess14TransferSyntax,
      UID_JPEGLSLosslessTransferSyntax,       UID_JPEGLSLossyTransferSyntax,
      UID_JPEG2000LosslessOnlyTransferSyntax, UID_JPEG2000TransferSyntax,
      UID_RLELosslessTransferSyntax,          UID_JPEGProcess1TransferSyntax,
      UID_JPEGProcess2_4TransferSyntax};
  return syntaxes;
}

// Storage contexts (our SCP role) for the SOP classes the series holds, plus CT's in case the
// server did not say; at most 127 contexts in all with the C-GET one.
std::vector<ContextRequest> retrieveContexts(const std::set<std::string>& sopClasses) {
  std::vector<std::string> classes(sopClasses.begin(), sopClasses.end());
  for (const char* usual :
       {UID_CTImageStorage, UID_EnhancedCTImageStorage, UID_SecondaryCaptureImageStorage}) {
    if (!sopClasses.count(usual)) classes.push_back(usual);
  }
  // Presentation context IDs are odd numbers below 256.
  constexpr std::size_t kMaxContexts = 127;
  const std::size_t perSyntax = 1 + compressedSyntaxes().size();
  const bool onePerSyntax = 1 + classes.size() * perSyntax <= kMaxContexts;
  const std::size_t perClass = onePerSyntax ? perSyntax : 2;
  std::vector<ContextRequest> contexts = {
      {UID_GETStudyRootQueryRetrieveInformationModel, uncompressedSyntaxes(), ASC_SC_ROLE_DEFAULT}};
  for (const std::string& sopClass : classes) {
    if (contexts.size() + perClass > kMaxContexts) break;
    contexts.push_back({sopClass, uncompressedSyntaxes(), ASC_SC_ROLE_SCP});
    if (onePerSyntax) {
      for (const char* syntax : compressedSyntaxes()) {
        contexts.push_back({sopClass, {syntax}, ASC_SC_ROLE_SCP});
      }
    } else {
      contexts.push_back({sopClass, compressedSyntaxes(), ASC_SC_ROLE_SCP});
    }
  }
  return contexts;
}

// The received dataset as a Part-10 file in the transfer syntax it came in.
std::vector<uint8_t> toPart10(std::unique_ptr<DcmDataset> dataset, const std::string& syntaxUid) {
  const E_TransferSyntax syntax = DcmXfer(syntaxUid.c_str()).getXfer();
  DcmFileFormat file(dataset.release(), OFFalse);  // takes the dataset over
  std::vector<uint8_t> bytes;
  std::vector<uint8_t> chunk(1 << 16);
  DcmOutputBufferStream stream(chunk.data(), static_cast<offile_off_t>(chunk.size()));
  file.transferInit();
  OFCondition condition = EC_StreamNotifyClient;
  while (condition == EC_StreamNotifyClient) {
    condition = file.write(stream, syntax, EET_ExplicitLength, nullptr);
    void* written = nullptr;
    offile_off_t length = 0;
    stream.flushBuffer(written, length);
    const auto* begin = static_cast<const uint8_t*>(written);
    bytes.insert(bytes.end(), begin, begin + length);
  }
  file.transferEnd();
  if (condition.bad()) throw std::runtime_error(std::string("cannot encode: ") + condition.text());
  return bytes;
}

struct GetSession {
  const std::function<void(const std::string&, std::vector<uint8_t>)>& store;
  const std::function<void(int64_t, int64_t)>& progress;
  int64_t total = 0;
  std::unordered_set<std::string> received;
  int failedSubOperations = 0;
  Uint16 lastStatus = STATUS_Success;
};

// Receives the C-STORE sub-operation just announced and answers it.
void receiveInstance(Association& association, T_ASC_PresentationContextID context,
                     const T_DIMSE_C_StoreRQ& request, GetSession& session) {
  DcmDataset* raw = nullptr;
  const OFCondition condition =
      DIMSE_receiveDataSetInMemory(association.get(), DIMSE_NONBLOCKING, association.timeout(),
                                   &context, &raw, nullptr, nullptr);
  std::unique_ptr<DcmDataset> dataset(raw);
  if (condition.bad()) association.fail("C-GET: receiving an instance", condition);

  std::string uid = getString(*dataset, DCM_SOPInstanceUID);
  if (uid.empty()) uid = request.AffectedSOPInstanceUID;
  std::exception_ptr failure;
  Uint16 status = STATUS_Success;
  try {
    session.store(uid, toPart10(std::move(dataset), association.transferSyntaxOf(context)));
    session.received.insert(uid);
    if (session.progress) {
      session.progress(static_cast<int64_t>(session.received.size()), session.total);
    }
  } catch (...) {
    failure = std::current_exception();
    status = STATUS_STORE_Refused_OutOfResources;
  }

  T_DIMSE_Message answer{};
  answer.CommandField = DIMSE_C_STORE_RSP;
  T_DIMSE_C_StoreRSP& response = answer.msg.CStoreRSP;
  response.MessageIDBeingRespondedTo = request.MessageID;
  response.DimseStatus = status;
  response.DataSetType = DIMSE_DATASET_NULL;
  OFStandard::strlcpy(response.AffectedSOPClassUID, request.AffectedSOPClassUID,
                      sizeof response.AffectedSOPClassUID);
  OFStandard::strlcpy(response.AffectedSOPInstanceUID, request.AffectedSOPInstanceUID,
                      sizeof response.AffectedSOPInstanceUID);
  response.opts = O_STORE_AFFECTEDSOPCLASSUID | O_STORE_AFFECTEDSOPINSTANCEUID;
  if (failure) {
    association.abort();  // the caller cannot take more: stop here
    std::rethrow_exception(failure);
  }
  const OFCondition sent = DIMSE_sendMessageUsingMemoryData(association.get(), context, &answer,
                                                            nullptr, nullptr, nullptr, nullptr);
  if (sent.bad()) association.fail("C-GET: answering a C-STORE", sent);
}

// One C-GET request: answers the server's C-STOREs until its final C-GET response.
void get(Association& association, T_ASC_PresentationContextID context, DcmDataset& keys,
         GetSession& session) {
  T_DIMSE_Message message{};
  message.CommandField = DIMSE_C_GET_RQ;
  T_DIMSE_C_GetRQ& request = message.msg.CGetRQ;
  request.MessageID = association.get()->nextMsgID++;
  OFStandard::strlcpy(request.AffectedSOPClassUID, UID_GETStudyRootQueryRetrieveInformationModel,
                      sizeof request.AffectedSOPClassUID);
  request.Priority = DIMSE_PRIORITY_MEDIUM;
  request.DataSetType = DIMSE_DATASET_PRESENT;
  OFCondition condition = DIMSE_sendMessageUsingMemoryData(association.get(), context, &message,
                                                           nullptr, &keys, nullptr, nullptr);
  if (condition.bad()) association.fail("C-GET", condition);

  for (;;) {
    T_DIMSE_Message incoming{};
    T_ASC_PresentationContextID incomingContext = 0;
    DcmDataset* rawDetail = nullptr;
    condition = DIMSE_receiveCommand(association.get(), DIMSE_NONBLOCKING, association.timeout(),
                                     &incomingContext, &incoming, &rawDetail);
    std::unique_ptr<DcmDataset> detail(rawDetail);
    if (condition.bad()) association.fail("C-GET", condition);

    if (incoming.CommandField == DIMSE_C_STORE_RQ) {
      receiveInstance(association, incomingContext, incoming.msg.CStoreRQ, session);
      continue;
    }
    if (incoming.CommandField != DIMSE_C_GET_RSP) {
      association.fail(fmt::format("C-GET: unexpected DIMSE command 0x{:04X}",
                                   static_cast<unsigned>(incoming.CommandField)));
    }
    const T_DIMSE_C_GetRSP& response = incoming.msg.CGetRSP;
    if (response.DataSetType != DIMSE_DATASET_NULL) {
      // The failed SOP instances' list: what is missing is found by comparison below.
      DcmDataset* rawList = nullptr;
      condition =
          DIMSE_receiveDataSetInMemory(association.get(), DIMSE_NONBLOCKING, association.timeout(),
                                       &incomingContext, &rawList, nullptr, nullptr);
      std::unique_ptr<DcmDataset> failedList(rawList);
      if (condition.bad()) association.fail("C-GET", condition);
    }
    if (DICOM_PENDING_STATUS(response.DimseStatus)) continue;
    session.lastStatus = response.DimseStatus;
    if (response.opts & O_GET_NUMBEROFFAILEDSUBOPERATIONS) {
      session.failedSubOperations += response.NumberOfFailedSubOperations;
    }
    return;
  }
}

}  // namespace

// ---------------------------------------------------------------------------------------------

std::string dimseUrl(const DimseEndpoint& endpoint) {
  return fmt::format("dicom://{}@{}:{}", endpoint.calledAet, endpoint.host, endpoint.port);
}

DimseEndpoint parseDimseUrl(const std::string& url) {
  static const std::string scheme = "dicom://";
  const std::string expected = "expected dicom://CALLED_AET@HOST[:PORT]";
  if (asciiLower(url.substr(0, scheme.size())) != scheme) {
    throw Error(url, "not a DIMSE address: " + expected);
  }
  std::string rest = url.substr(scheme.size());
  if (!rest.empty() && rest.back() == '/') rest.pop_back();
  const std::size_t at = rest.rfind('@');
  if (at == std::string::npos || at == 0) {
    throw Error(url, "the server's AE title is missing: " + expected);
  }
  DimseEndpoint endpoint;
  endpoint.calledAet = rest.substr(0, at);
  const std::string hostPort = rest.substr(at + 1);
  if (hostPort.find_first_of("/?#[]") != std::string::npos) {
    throw Error(url, "unexpected characters after the AE title: " + expected +
                         " (IPv6 addresses are not supported)");
  }
  const std::size_t colon = hostPort.rfind(':');
  endpoint.host = hostPort.substr(0, colon);
  if (colon != std::string::npos) {
    const std::string port = hostPort.substr(colon + 1);
    if (port.empty() || port.size() > 5 ||
        !std::all_of(port.begin(), port.end(), [](char c) { return c >= '0' && c <= '9'; }) ||
        std::stoi(port) < 1 || std::stoi(port) > 65535) {
      throw Error(url, "the port must be a number from 1 to 65535");
    }
    endpoint.port = std::stoi(port);
  }
  if (endpoint.host.empty()) throw Error(url, "the host is missing: " + expected);
  checkAeTitle(url, "the AE title", endpoint.calledAet);
  return endpoint;
}

void dimseEcho(const DimseEndpoint& endpoint) {
  Association association(
      endpoint, {{UID_VerificationSOPClass, uncompressedSyntaxes(), ASC_SC_ROLE_DEFAULT}});
  association.contextFor(UID_VerificationSOPClass, "C-ECHO (Verification)");
  DIC_US status = 0;
  DcmDataset* rawDetail = nullptr;
  const OFCondition condition =
      DIMSE_echoUser(association.get(), association.get()->nextMsgID++, DIMSE_NONBLOCKING,
                     association.timeout(), &status, &rawDetail);
  std::unique_ptr<DcmDataset> detail(rawDetail);
  if (condition.bad()) association.fail("C-ECHO", condition);
  if (status != STATUS_Success) association.fail("C-ECHO answered status " + statusHex(status));
}

std::vector<StudyRecord> dimseFindStudies(const DimseEndpoint& endpoint, const StudyQuery& query) {
  DcmDataset keys;
  const bool utf8 =
      !(isAscii(query.patientName) && isAscii(query.patientId) && isAscii(query.accessionNumber));
  if (utf8) putKey(keys, DCM_SpecificCharacterSet, "ISO_IR 192");
  putKey(keys, DCM_QueryRetrieveLevel, "STUDY");
  putKey(keys, DCM_StudyInstanceUID, query.studyInstanceUid);
  putKey(keys, DCM_PatientID, query.patientId);
  putKey(keys, DCM_PatientName, query.patientName);
  putKey(keys, DCM_StudyDate, dateRange(query.studyDateFrom, query.studyDateTo));
  putKey(keys, DCM_AccessionNumber, query.accessionNumber);
  putKey(keys, DCM_StudyDescription, "");
  putKey(keys, DCM_ModalitiesInStudy, query.modality);
  putKey(keys, DCM_NumberOfStudyRelatedSeries, "");
  putKey(keys, DCM_NumberOfStudyRelatedInstances, "");

  std::vector<StudyRecord> studies;
  for (const auto& match : find(endpoint, keys)) {
    StudyRecord study;
    study.studyInstanceUid = getString(*match, DCM_StudyInstanceUID);
    study.patientId = getString(*match, DCM_PatientID);
    study.patientName = getString(*match, DCM_PatientName);
    study.studyDate = getString(*match, DCM_StudyDate);
    study.accessionNumber = getString(*match, DCM_AccessionNumber);
    study.studyDescription = getString(*match, DCM_StudyDescription);
    study.modalities = splitValues(getString(*match, DCM_ModalitiesInStudy));
    study.seriesCount = getCount(*match, DCM_NumberOfStudyRelatedSeries);
    study.instanceCount = getCount(*match, DCM_NumberOfStudyRelatedInstances);
    studies.push_back(std::move(study));
  }
  return studies;
}

std::vector<SeriesRecord> dimseFindSeries(const DimseEndpoint& endpoint,
                                          const std::string& studyUid,
                                          const std::string& modality) {
  DcmDataset keys;
  putKey(keys, DCM_QueryRetrieveLevel, "SERIES");
  putKey(keys, DCM_StudyInstanceUID, studyUid);
  putKey(keys, DCM_SeriesInstanceUID, "");
  putKey(keys, DCM_Modality, modality);
  putKey(keys, DCM_SeriesNumber, "");
  putKey(keys, DCM_SeriesDescription, "");
  putKey(keys, DCM_NumberOfSeriesRelatedInstances, "");

  std::vector<SeriesRecord> series;
  for (const auto& match : find(endpoint, keys)) {
    SeriesRecord record;
    record.studyInstanceUid = getString(*match, DCM_StudyInstanceUID);
    if (record.studyInstanceUid.empty()) record.studyInstanceUid = studyUid;
    record.seriesInstanceUid = getString(*match, DCM_SeriesInstanceUID);
    record.modality = getString(*match, DCM_Modality);
    record.seriesNumber = getString(*match, DCM_SeriesNumber);
    record.seriesDescription = getString(*match, DCM_SeriesDescription);
    record.instanceCount = getCount(*match, DCM_NumberOfSeriesRelatedInstances);
    series.push_back(std::move(record));
  }
  return series;
}

std::vector<InstanceRecord> dimseFindInstances(const DimseEndpoint& endpoint,
                                               const std::string& studyUid,
                                               const std::string& seriesUid) {
  DcmDataset keys;
  putKey(keys, DCM_QueryRetrieveLevel, "IMAGE");
  putKey(keys, DCM_StudyInstanceUID, studyUid);
  putKey(keys, DCM_SeriesInstanceUID, seriesUid);
  putKey(keys, DCM_SOPInstanceUID, "");
  putKey(keys, DCM_SOPClassUID, "");
  putKey(keys, DCM_InstanceNumber, "");
  putKey(keys, DCM_ImagePositionPatient, "");
  putKey(keys, DCM_ImageOrientationPatient, "");

  std::vector<InstanceRecord> instances;
  for (const auto& match : find(endpoint, keys)) {
    InstanceRecord record;
    record.sopInstanceUid = getString(*match, DCM_SOPInstanceUID);
    record.sopClassUid = getString(*match, DCM_SOPClassUID);
    record.instanceNumber = getCount(*match, DCM_InstanceNumber);
    if (const auto p = getNumbers(*match, DCM_ImagePositionPatient, 3); !p.empty()) {
      record.position = std::array<double, 3>{p[0], p[1], p[2]};
    }
    if (const auto o = getNumbers(*match, DCM_ImageOrientationPatient, 6); !o.empty()) {
      record.orientation = std::array<double, 6>{o[0], o[1], o[2], o[3], o[4], o[5]};
    }
    if (!record.sopInstanceUid.empty()) instances.push_back(std::move(record));
  }
  std::sort(instances.begin(), instances.end(), [](const auto& a, const auto& b) {
    return a.instanceNumber != b.instanceNumber ? a.instanceNumber < b.instanceNumber
                                                : a.sopInstanceUid < b.sopInstanceUid;
  });
  return instances;
}

void dimseGetSeries(const DimseEndpoint& endpoint, const std::string& studyUid,
                    const std::string& seriesUid, const std::vector<std::string>& onlyInstances,
                    const std::function<void(const std::string& sopInstanceUid,
                                             std::vector<uint8_t> part10)>& store,
                    const std::function<void(int64_t done, int64_t total)>& progress) {
  const std::string name = dimseUrl(endpoint);
  if (studyUid.empty() || seriesUid.empty()) {
    throw Error(name, "C-GET needs the study and the series instance UIDs");
  }
  // What the server holds: the instances to expect and the storage SOP classes to accept.
  const std::vector<InstanceRecord> listed = dimseFindInstances(endpoint, studyUid, seriesUid);
  std::set<std::string> sopClasses;
  std::vector<std::string> expected;
  std::unordered_set<std::string> listedUids;
  for (const InstanceRecord& instance : listed) {
    if (!instance.sopClassUid.empty()) sopClasses.insert(instance.sopClassUid);
    if (onlyInstances.empty()) expected.push_back(instance.sopInstanceUid);
    listedUids.insert(instance.sopInstanceUid);
  }
  // Asked for by UID: those the server does not list are not requested (a server may fail the
  // whole C-GET for one unknown UID, as Orthanc does), and are reported missing at the end.
  std::vector<std::string> requested;
  if (!onlyInstances.empty()) {
    expected = onlyInstances;
    for (const std::string& uid : onlyInstances) {
      if (listedUids.empty() || listedUids.count(uid)) requested.push_back(uid);
    }
  }
  if (expected.empty()) throw Error(name, "C-FIND lists no instance of series " + seriesUid);

  GetSession session{store, progress, static_cast<int64_t>(expected.size()), {}, 0, STATUS_Success};
  if (progress) progress(0, session.total);

  Association association(endpoint, retrieveContexts(sopClasses));
  const T_ASC_PresentationContextID context =
      association.contextFor(UID_GETStudyRootQueryRetrieveInformationModel, "Study Root C-GET");
  const auto requestKeys = [&](const std::string& level) {
    auto keys = std::make_unique<DcmDataset>();
    putKey(*keys, DCM_QueryRetrieveLevel, level);
    putKey(*keys, DCM_StudyInstanceUID, studyUid);
    putKey(*keys, DCM_SeriesInstanceUID, seriesUid);
    return keys;
  };
  if (onlyInstances.empty()) {
    get(association, context, *requestKeys("SERIES"), session);
  } else {
    // A list of UIDs is a multi-valued key (PS3.4 C.4.3.1.3.1), sent a batch at a time.
    for (std::size_t first = 0; first < requested.size(); first += kUidsPerGet) {
      const std::size_t last = std::min(requested.size(), first + kUidsPerGet);
      std::string uids;
      for (std::size_t i = first; i < last; ++i) uids += (i > first ? "\\" : "") + requested[i];
      auto keys = requestKeys("IMAGE");
      putKey(*keys, DCM_SOPInstanceUID, uids);
      get(association, context, *keys, session);
    }
  }

  std::size_t missing = 0;
  for (const std::string& uid : expected) missing += session.received.count(uid) ? 0 : 1;
  if (missing > 0) {
    std::string why;
    if (session.failedSubOperations > 0) {
      why =
          fmt::format("; the server reports {} failed sub-operations", session.failedSubOperations);
    }
    if (session.lastStatus != STATUS_Success) {
      why += fmt::format("; last status: {} ({})", DU_cgetStatusString(session.lastStatus),
                         statusHex(session.lastStatus));
    }
    throw Error(name, fmt::format("C-GET delivered {} of {} instances{}", expected.size() - missing,
                                  expected.size(), why));
  }
}

}  // namespace octoray::pacs
