#pragma once
// The one project error type: every module throws octoray::Error (or a type derived from
// it) at its borders, carrying the file concerned and what is wrong with it. Tools catch it
// at main and print "<file>: <reason>".

#include <stdexcept>
#include <string>

namespace octoray {

class Error : public std::runtime_error {
 public:
  Error(std::string path, std::string reason)
      : std::runtime_error(path.empty() ? reason : path + ": " + reason),
        path_(std::move(path)),
        reason_(std::move(reason)) {}

  const std::string& path() const { return path_; }
  const std::string& reason() const { return reason_; }

 private:
  std::string path_;
  std::string reason_;
};

}  // namespace octoray
