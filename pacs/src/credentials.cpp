#include "octoray/pacs/credentials.h"

#include <sys/stat.h>

#include <cstdlib>
#include <fstream>
#include <sstream>

#include <fmt/format.h>

#include "octoray/core/error.h"

namespace octoray::pacs {

namespace {

std::string trim(const std::string& s) {
  const auto begin = s.find_first_not_of(" \t\r\n");
  if (begin == std::string::npos) return {};
  const auto end = s.find_last_not_of(" \t\r\n");
  return s.substr(begin, end - begin + 1);
}

}  // namespace

Credentials parseCredentials(const std::string& text, const std::string& origin) {
  std::istringstream lines(text);
  std::string line;
  Credentials found;
  int meaningful = 0;
  while (std::getline(lines, line)) {
    line = trim(line);
    if (line.empty() || line.front() == '#') continue;
    if (++meaningful > 1) throw Error(origin, "more than one credentials line");
    const auto space = line.find_first_of(" \t");
    const std::string kind = line.substr(0, space);
    const std::string value = space == std::string::npos ? std::string() : trim(line.substr(space));
    if (kind == "basic") {
      const auto colon = value.find(':');
      if (colon == std::string::npos || colon == 0) {
        throw Error(origin, "expected \"basic USER:PASSWORD\"");
      }
      found.kind = Credentials::Kind::Basic;
      found.user = value.substr(0, colon);
      found.secret = value.substr(colon + 1);
    } else if (kind == "bearer") {
      if (value.empty() || value.find_first_of(" \t") != std::string::npos) {
        throw Error(origin, "expected \"bearer TOKEN\" (one word)");
      }
      found.kind = Credentials::Kind::Bearer;
      found.secret = value;
    } else {
      throw Error(origin, "expected a line \"basic USER:PASSWORD\" or \"bearer TOKEN\"");
    }
  }
  if (meaningful == 0) throw Error(origin, "no credentials in it");
  return found;
}

Credentials loadCredentialsFile(const std::string& path, std::string* warning) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error(path, "cannot open the credentials file");
  std::ostringstream text;
  text << in.rdbuf();
  struct stat st {};
  if (warning != nullptr && ::stat(path.c_str(), &st) == 0 && (st.st_mode & (S_IRWXG | S_IRWXO)) != 0) {
    *warning = fmt::format("{}: credentials file is readable by others (chmod 600 it)", path);
  }
  return parseCredentials(text.str(), path);
}

Credentials resolveCredentials(const std::string& path, std::string* warning) {
  if (!path.empty()) return loadCredentialsFile(path, warning);
  if (const char* env = std::getenv(kCredentialsEnvironmentVariable); env != nullptr && *env) {
    return parseCredentials(env, std::string("$") + kCredentialsEnvironmentVariable);
  }
  return {};
}

void refuseCredentialsInUrl(const std::string& url) {
  const auto scheme = url.find("://");
  if (scheme == std::string::npos) return;
  const auto authorityEnd = url.find_first_of("/?#", scheme + 3);
  const std::string authority = url.substr(scheme + 3, authorityEnd == std::string::npos
                                                           ? std::string::npos
                                                           : authorityEnd - scheme - 3);
  if (authority.find('@') != std::string::npos) {
    throw Error(url.substr(0, scheme + 3) + "…",
                "the URL holds user information (user:password@): put credentials in a file "
                "(--credentials FILE) or $" + std::string(kCredentialsEnvironmentVariable));
  }
}

}  // namespace octoray::pacs
