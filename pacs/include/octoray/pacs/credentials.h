#pragma once
// Credentials for a DICOMweb server: HTTP basic (user and password) or a bearer token. They
// come from a file or an environment variable, never from the command line (where `ps` shows
// them), and nothing in octoray prints them: Credentials has no stream operator, errors name
// the source and not the secret, and URLs holding user:password@ are refused.
//
// The text, in a file or in $OCTORAY_PACS_CREDENTIALS, is one line:
//   basic USER:PASSWORD
//   bearer TOKEN
// Blank lines and lines starting with '#' are ignored.

#include <string>

namespace octoray::pacs {

struct Credentials {
  enum class Kind { None, Basic, Bearer };
  Kind kind = Kind::None;
  std::string user;    // Basic only
  std::string secret;  // the password or the token
};

// The environment variable read when no file is given.
inline constexpr const char* kCredentialsEnvironmentVariable = "OCTORAY_PACS_CREDENTIALS";

// Parses the text above; `origin` names where it came from in errors (which never quote the
// text). Throws octoray::Error for anything else.
Credentials parseCredentials(const std::string& text, const std::string& origin);
// Reads `path` (a warning goes to `warning` when the file is readable by group or others).
Credentials loadCredentialsFile(const std::string& path, std::string* warning = nullptr);
// From `path` when not empty, else from $OCTORAY_PACS_CREDENTIALS when set, else none.
Credentials resolveCredentials(const std::string& path, std::string* warning = nullptr);

// Throws octoray::Error when `url` carries user information (scheme://user[:password]@host):
// credentials belong in a file, not in a URL that logs, shells and `ps` show. The message
// does not repeat the URL.
void refuseCredentialsInUrl(const std::string& url);

}  // namespace octoray::pacs
