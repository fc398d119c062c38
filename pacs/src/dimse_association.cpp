// The association layer of DIMSE (dimse_association.h): DCMTK's ASC_ functions, with every
// failure turned into one sentence that names the server.

#include "dimse_association.h"

#include <dcmtk/dcmdata/dcuid.h>
#include <dcmtk/dcmnet/dcmtrans.h>
#include <dcmtk/dcmnet/dimse.h>
#include <dcmtk/dcmnet/dul.h>
#include <fmt/format.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <sys/socket.h>

#include <algorithm>

#include "dcmtk_log.h"
#include "octoray/core/error.h"

namespace octoray::pacs::detail {
namespace {

constexpr Uint32 kMaxPduBytes = 65536;

void checkEndpoint(const DimseEndpoint& endpoint) {
  const std::string name = dimseUrl(endpoint);
  // dcmnet keeps "host:port" in 64 bytes.
  if (endpoint.host.empty() || endpoint.host.size() > 57) {
    throw Error(name, "the host name must have 1 to 57 characters");
  }
  if (endpoint.port < 1 || endpoint.port > 65535) throw Error(name, "the port must be 1 to 65535");
  checkAeTitle(name, "the called AE title", endpoint.calledAet);
  checkAeTitle(name, "the calling AE title", endpoint.callingAet);
  if (endpoint.timeoutSeconds < 1) throw Error(name, "the timeout must be at least 1 second");
}

std::string rejectReason(T_ASC_Parameters* params) {
  T_ASC_RejectParameters reject{};
  ASC_getRejectParameters(params, &reject);
  std::string reason;
  switch (reject.reason) {
    case ASC_REASON_SU_CALLINGAETITLENOTRECOGNIZED:
      reason = "calling AE title not recognized";
      break;
    case ASC_REASON_SU_CALLEDAETITLENOTRECOGNIZED:
      reason = "called AE title not recognized";
      break;
    case ASC_REASON_SU_APPCONTEXTNAMENOTSUPPORTED:
      reason = "application context not supported";
      break;
    case ASC_REASON_SP_ACSE_PROTOCOLVERSIONNOTSUPPORTED:
      reason = "protocol version not supported";
      break;
    case ASC_REASON_SP_PRES_TEMPORARYCONGESTION:
      reason = "temporary congestion";
      break;
    case ASC_REASON_SP_PRES_LOCALLIMITEXCEEDED:
      reason = "local limit exceeded";
      break;
    default:
      reason = "no reason given";
      break;
  }
  const bool permanent = reject.result == ASC_RESULT_REJECTEDPERMANENT;
  return reason + (permanent ? ", permanent" : ", transient");
}

// What went wrong on an established association, in words.
std::string conditionReason(const OFCondition& condition, int timeoutSeconds) {
  if (condition == DIMSE_NODATAAVAILABLE || condition == DUL_READTIMEOUT) {
    return fmt::format("no answer within {} s", timeoutSeconds);
  }
  if (condition == DUL_PEERABORTEDASSOCIATION) return "the server aborted the association";
  if (condition == DUL_PEERREQUESTEDRELEASE) return "the server closed the association";
  if (condition == DUL_NETWORKCLOSED) return "the server closed the connection";
  return condition.text();
}

// DcmTransportConnection::getSocket() is protected; a member pointer taken through a derived
// class reaches it without touching the connection.
struct SocketOf : DcmTransportConnection {
  static DcmNativeSocketType of(DcmTransportConnection& connection) {
    return (connection.*(&SocketOf::getSocket))();
  }
};

}  // namespace

// PS3.5 AE: 1 to 16 characters of the default repertoire, no backslash, not only spaces.
void checkAeTitle(const std::string& source, const std::string& what, const std::string& aet) {
  const bool valid = !aet.empty() && aet.size() <= 16 &&
                     aet.find_first_not_of(' ') != std::string::npos &&
                     std::all_of(aet.begin(), aet.end(),
                                 [](char c) { return c >= 0x20 && c < 0x7f && c != '\\'; });
  if (!valid) {
    throw Error(source, what + " '" + aet + "' is not valid (1 to 16 characters, no backslash)");
  }
}

std::string statusHex(Uint16 status) { return fmt::format("0x{:04X}", status); }

const std::vector<const char*>& uncompressedSyntaxes() {
  static const std::vector<const char*> syntaxes = {UID_LittleEndianExplicitTransferSyntax,
                                                    UID_LittleEndianImplicitTransferSyntax};
  return syntaxes;
}

Association::Association(const DimseEndpoint& endpoint, const std::vector<ContextRequest>& contexts)
    : endpoint_(endpoint), name_(dimseUrl(endpoint)) {
  checkEndpoint(endpoint);
  configureDcmtkLog();
  try {
    open(contexts);
  } catch (...) {
    close(false);
    throw;
  }
}

Association::~Association() { close(true); }

T_ASC_PresentationContextID Association::contextFor(const char* abstractSyntax, const std::string& service) {
  const T_ASC_PresentationContextID id = ASC_findAcceptedPresentationContextID(association_, abstractSyntax);
  if (id == 0) fail("the server does not offer " + service);
  return id;
}

std::string Association::transferSyntaxOf(T_ASC_PresentationContextID id) const {
  T_ASC_PresentationContext context{};
  if (ASC_findAcceptedPresentationContext(association_->params, id, &context).bad()) return {};
  return context.acceptedTransferSyntax;
}

void Association::fail(const std::string& reason) {
  close(false);
  throw Error(name_, reason);
}

void Association::fail(const std::string& doing, const OFCondition& condition) {
  fail(doing + ": " + conditionReason(condition, endpoint_.timeoutSeconds));
}

void Association::open(const std::vector<ContextRequest>& contexts) {
  const int timeout = endpoint_.timeoutSeconds;
  dcmConnectionTimeout.set(timeout);  // process-wide in dcmnet; every call sets its own
  OFCondition condition = ASC_initializeNetwork(NET_REQUESTOR, 0, timeout, &network_);
  if (condition.bad()) {
    throw Error(name_, std::string("cannot set up DICOM networking: ") + condition.text());
  }
  condition = ASC_createAssociationParameters(&parameters_, kMaxPduBytes);
  if (condition.bad()) throw Error(name_, condition.text());
  ASC_setAPTitles(parameters_, endpoint_.callingAet.c_str(), endpoint_.calledAet.c_str(),
                  nullptr);
  const std::string peer = fmt::format("{}:{}", endpoint_.host, endpoint_.port);
  ASC_setPresentationAddresses(parameters_, OFStandard::getHostName().c_str(), peer.c_str());
  T_ASC_PresentationContextID id = 1;
  for (const ContextRequest& context : contexts) {
    condition = ASC_addPresentationContext(
        parameters_, id, context.abstractSyntax.c_str(),
        const_cast<const char**>(context.transferSyntaxes.data()),
        static_cast<int>(context.transferSyntaxes.size()), context.role);
    if (condition.bad()) throw Error(name_, condition.text());
    id = static_cast<T_ASC_PresentationContextID>(id + 2);
  }

  T_ASC_Association* association = nullptr;
  condition = ASC_requestAssociation(network_, parameters_, &association);
  if (association) {
    association_ = association;  // it owns the parameters from here on
    parameters_ = nullptr;
  }
  const std::string who = fmt::format("(calling AE title {}, called AE title {})",
                                      endpoint_.callingAet, endpoint_.calledAet);
  if (condition == DUL_ASSOCIATIONREJECTED) {
    throw Error(name_, "the server rejected the association " + who + ": " +
                           rejectReason(association_ ? association_->params : parameters_));
  }
  if (condition.bad()) {
    const std::string text = condition.text();
    std::string reason = text;
    if (text.find("refused") != std::string::npos) {
      reason = "connection refused";
    } else if (text.find("timed out") != std::string::npos || condition == DUL_READTIMEOUT) {
      reason = fmt::format("no answer within {} s", timeout);
    } else if (condition == DUL_PEERABORTEDASSOCIATION || condition == DUL_NETWORKCLOSED) {
      reason = "the server closed the connection";
    }
    throw Error(name_, "cannot open an association " + who + ": " + reason);
  }
  open_ = true;
  // A DIMSE message is a command and a dataset written apart: with Nagle's algorithm on, the
  // second waits for the server's delayed ACK (40 ms per message on Linux).
  // (dcmnet does so only when the process environment holds TCP_NODELAY=1.)
  if (DcmTransportConnection* connection =
          DUL_getTransportConnection(association_->DULassociation)) {
    const int noDelay = 1;
    ::setsockopt(SocketOf::of(*connection), IPPROTO_TCP, TCP_NODELAY, &noDelay, sizeof noDelay);
  }
  if (ASC_countAcceptedPresentationContexts(association_->params) == 0) {
    fail("the server accepted none of the services proposed");
  }
}

void Association::close(bool orderly) noexcept {
  if (association_) {
    if (open_) {
      if (!orderly || ASC_releaseAssociation(association_).bad()) {
        ASC_abortAssociation(association_);
      }
      open_ = false;
    }
    ASC_destroyAssociation(&association_);  // and its parameters
    association_ = nullptr;
  }
  if (parameters_) ASC_destroyAssociationParameters(&parameters_);
  if (network_) ASC_dropNetwork(&network_);
}

}  // namespace octoray::pacs::detail
