#pragma once
// Starting another program without a shell: argv as given, stdin from a string, stdout and
// stderr merged into what is returned, the exit status and peak memory from wait4(). Used for
// the workers and for sbatch.

#include <sys/types.h>


#include <functional>
#include <string>
#include <vector>

namespace octoray::batch::detail {

struct ProcessResult {
  int exitCode = -1;     // the program's exit status, or -1 when killed by a signal
  int signal = 0;        // the signal that killed it, else 0
  std::string output;    // stdout and stderr, interleaved
  double peakRssMiB = 0;
};

// Runs argv[0] (searched in PATH when it has no '/'), writing `input` to its stdin.
// `started` (if set) is called with the child's pid as soon as it runs, `ended` before it is
// reaped, so a caller can signal it meanwhile. Throws octoray::Error naming argv[0] when it
// cannot be started.
ProcessResult runProcess(const std::vector<std::string>& argv, const std::string& input,
                         const std::function<void(pid_t)>& started = {},
                         const std::function<void(pid_t)>& ended = {});

}  // namespace octoray::batch::detail
