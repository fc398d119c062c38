#include "octoray/pacs/multipart.h"

#include <algorithm>

#include <fmt/format.h>

#include "octoray/core/error.h"
#include "octoray/core/text.h"

namespace octoray::pacs {

namespace {

[[noreturn]] void malformed(const std::string& origin, const std::string& what) {
  throw Error(origin, "malformed multipart body: " + what);
}

// The value of header `name` (case-insensitive) in a CRLF-separated header block.
std::string headerValue(std::string_view block, std::string_view name) {
  std::size_t pos = 0;
  while (pos < block.size()) {
    std::size_t end = block.find("\r\n", pos);
    if (end == std::string_view::npos) end = block.size();
    const std::string_view line = block.substr(pos, end - pos);
    const auto colon = line.find(':');
    if (colon != std::string_view::npos && asciiLower(line.substr(0, colon)) == asciiLower(name)) {
      std::string_view value = line.substr(colon + 1);
      while (!value.empty() && (value.front() == ' ' || value.front() == '\t')) value.remove_prefix(1);
      while (!value.empty() && (value.back() == ' ' || value.back() == '\t')) value.remove_suffix(1);
      return std::string(value);
    }
    pos = end + 2;
  }
  return {};
}

}  // namespace

std::string multipartBoundary(const std::string& contentType, const std::string& origin) {
  const std::string low = asciiLower(contentType);
  if (!low.starts_with("multipart/")) {
    throw Error(origin, fmt::format("expected a multipart answer, got Content-Type \"{}\"",
                                    contentType.empty() ? "(none)" : contentType));
  }
  // Parameters after ';': find boundary=, outside quotes.
  std::size_t pos = low.find(';');
  while (pos != std::string::npos) {
    std::size_t begin = pos + 1;
    while (begin < low.size() && (low[begin] == ' ' || low[begin] == '\t')) ++begin;
    const std::size_t eq = low.find('=', begin);
    if (eq == std::string::npos) break;
    const std::string key = low.substr(begin, eq - begin);
    std::size_t valueBegin = eq + 1, valueEnd;
    std::string value;
    if (valueBegin < contentType.size() && contentType[valueBegin] == '"') {
      valueEnd = contentType.find('"', valueBegin + 1);
      if (valueEnd == std::string::npos) break;
      value = contentType.substr(valueBegin + 1, valueEnd - valueBegin - 1);
      pos = contentType.find(';', valueEnd);
    } else {
      valueEnd = contentType.find(';', valueBegin);
      value = contentType.substr(valueBegin, valueEnd == std::string::npos ? std::string::npos
                                                                            : valueEnd - valueBegin);
      while (!value.empty() && (value.back() == ' ' || value.back() == '\t')) value.pop_back();
      pos = valueEnd;
    }
    if (key == "boundary") {
      if (value.empty() || value.size() > 70) break;  // RFC 2046: 1..70 characters
      return value;
    }
  }
  throw Error(origin, fmt::format("multipart answer without a valid boundary (Content-Type \"{}\")",
                                  contentType));
}

std::vector<MultipartPart> parseMultipart(std::string_view body, const std::string& boundary,
                                          const std::string& origin) {
  const std::string delimiter = "--" + boundary;
  const std::string innerDelimiter = "\r\n" + delimiter;
  // The first delimiter starts the body or follows a preamble line.
  std::size_t pos;
  if (body.starts_with(delimiter)) {
    pos = delimiter.size();
  } else {
    pos = body.find(innerDelimiter);
    if (pos == std::string_view::npos) malformed(origin, "no boundary delimiter");
    pos += innerDelimiter.size();
  }
  std::vector<MultipartPart> parts;
  for (;;) {
    if (body.substr(pos, 2) == "--") return parts;  // the closing delimiter
    // Transport padding, then CRLF.
    while (pos < body.size() && (body[pos] == ' ' || body[pos] == '\t')) ++pos;
    if (body.substr(pos, 2) != "\r\n") {
      malformed(origin, pos >= body.size() ? "ends after a delimiter (truncated)"
                                           : "a delimiter is not followed by a line break");
    }
    pos += 2;
    MultipartPart part;
    std::size_t bodyBegin;
    if (body.substr(pos, 2) == "\r\n") {  // no headers
      bodyBegin = pos + 2;
    } else {
      const std::size_t headersEnd = body.find("\r\n\r\n", pos);
      if (headersEnd == std::string_view::npos) malformed(origin, "a part's headers never end (truncated)");
      part.contentType = headerValue(body.substr(pos, headersEnd - pos), "content-type");
      bodyBegin = headersEnd + 4;
    }
    const std::size_t next = body.find(innerDelimiter, bodyBegin);
    if (next == std::string_view::npos) {
      malformed(origin, fmt::format("part {} has no closing delimiter (truncated after {} bytes)",
                                    parts.size() + 1, body.size()));
    }
    part.body = body.substr(bodyBegin, next - bodyBegin);
    parts.push_back(part);
    pos = next + innerDelimiter.size();
    if (pos >= body.size()) malformed(origin, "ends inside a delimiter (truncated)");
  }
}

}  // namespace octoray::pacs
