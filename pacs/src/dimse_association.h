#pragma once
// The association layer under dimse.cpp's services: one DICOM association with a server,
// opened with the presentation contexts a service needs and released (or aborted after an
// error) when it goes out of scope, with every failure in words that name the server.

// clang-format off
#include <dcmtk/config/osconfig.h>  // DCMTK's configuration comes before any other DCMTK header
// clang-format on
#include <dcmtk/dcmnet/assoc.h>

#include <string>
#include <vector>

#include "octoray/pacs/dimse.h"

namespace octoray::pacs::detail {

// Throws Error(source, "<what> '<aet>' is not valid ...") unless `aet` is a PS3.5 AE title:
// 1 to 16 characters of the default repertoire, no backslash, not only spaces.
void checkAeTitle(const std::string& source, const std::string& what, const std::string& aet);

// A DIMSE status as PS3.7 writes it: "0xA700".
std::string statusHex(Uint16 status);

// One presentation context to propose: an abstract syntax, the transfer syntaxes offered for
// it, and our role (SCP for the storage contexts of C-GET).
struct ContextRequest {
  std::string abstractSyntax;
  std::vector<const char*> transferSyntaxes;
  T_ASC_SC_ROLE role = ASC_SC_ROLE_DEFAULT;
};

// Explicit and implicit VR little endian, in that order of preference.
const std::vector<const char*>& uncompressedSyntaxes();

// One association with the server, released (or aborted after an error) by the destructor.
class Association {
 public:
  // Checks the endpoint, connects and negotiates `contexts`; throws Error(dimseUrl(endpoint),
  // why) when the server cannot be reached, rejects the association (with its reason) or
  // accepts none of the contexts.
  Association(const DimseEndpoint& endpoint, const std::vector<ContextRequest>& contexts);
  ~Association();
  Association(const Association&) = delete;
  Association& operator=(const Association&) = delete;

  T_ASC_Association* get() const { return association_; }
  const std::string& name() const { return name_; }
  int timeout() const { return endpoint_.timeoutSeconds; }

  // The accepted context for `abstractSyntax`; throws naming `service` when there is none.
  T_ASC_PresentationContextID contextFor(const char* abstractSyntax, const std::string& service);
  // The transfer syntax the server accepted for context `id` (empty if there is none).
  std::string transferSyntaxOf(T_ASC_PresentationContextID id) const;

  // Aborts the association and throws Error(name, reason).
  [[noreturn]] void fail(const std::string& reason);
  // The same, with what went wrong on the association in words ("no answer within 30 s").
  [[noreturn]] void fail(const std::string& doing, const OFCondition& condition);
  void abort() { close(false); }

 private:
  void open(const std::vector<ContextRequest>& contexts);
  void close(bool orderly) noexcept;

  DimseEndpoint endpoint_;
  std::string name_;
  T_ASC_Network* network_ = nullptr;
  T_ASC_Parameters* parameters_ = nullptr;  // ours until an association takes them
  T_ASC_Association* association_ = nullptr;
  bool open_ = false;
};

}  // namespace octoray::pacs::detail
