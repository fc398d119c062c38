#pragma once
// Text helpers shared by the modules.

#include <cctype>
#include <string>
#include <string_view>

namespace octoray {

// `text` with its ASCII letters in lower case, every other byte as it is: for names compared
// without case (URL schemes, HTTP header fields, media types).
inline std::string asciiLower(std::string_view text) {
  std::string out(text);
  for (char& c : out) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return out;
}

}  // namespace octoray
