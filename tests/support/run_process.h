#pragma once
// Runs a program (a built tool) as a child process, the way a user or a script would, and
// captures what it printed: for tests of exit status, stdout/stderr and files left behind.

#include <string>
#include <vector>

namespace octoray::test {

struct ProcessResult {
  int exitCode = -1;  // exit status, or -1 when the child was killed by a signal
  int signal = 0;     // the signal that ended the child, or 0
  std::string out;    // everything written to stdout
  std::string err;    // everything written to stderr
  bool timedOut = false;  // killed at the deadline (the test has failed)
};

// Seconds a program may run before runProcess kills it and fails the test:
// $OCTORAY_TEST_TOOL_TIMEOUT, else 300 (sanitizer builds are slow; nothing takes a minute).
int toolTimeoutSeconds();

// Runs argv[0] (a path) with the arguments argv[1..] and waits for it, at most
// toolTimeoutSeconds(). stdin is /dev/null.
ProcessResult runProcess(const std::vector<std::string>& argv);

}  // namespace octoray::test
