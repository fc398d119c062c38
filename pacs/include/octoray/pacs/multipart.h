#pragma once
// multipart/related bodies (RFC 2046 §5.1, RFC 2387), as WADO-RS returns DICOM instances:
// each part one Part-10 file. Strict: a body without its closing delimiter (a server that
// closed mid-transfer) or without a boundary is an error, never a shorter list of parts.

#include <string>
#include <string_view>
#include <vector>

namespace octoray::pacs {

struct MultipartPart {
  std::string contentType;  // the part's Content-Type header, empty when absent
  std::string_view body;    // points into the parsed buffer
};

// The boundary parameter of a Content-Type header ("multipart/related; type=...;
// boundary=XYZ", quoted or not). Throws octoray::Error(origin, ...) when the type is not
// multipart or there is no boundary.
std::string multipartBoundary(const std::string& contentType, const std::string& origin);

// Splits `body` into its parts. Throws octoray::Error(origin, "malformed multipart body: ...")
// when the first delimiter, a part's header block or the closing delimiter is missing.
std::vector<MultipartPart> parseMultipart(std::string_view body, const std::string& boundary,
                                          const std::string& origin);

}  // namespace octoray::pacs
