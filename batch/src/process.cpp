#include "octoray/batch/process.h"

#include <fcntl.h>
#include <spawn.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <csignal>
#include <cstring>
#include <thread>

#include "octoray/core/error.h"

extern char** environ;

namespace octoray::batch::detail {

namespace {

struct Pipe {
  int fd[2] = {-1, -1};
  Pipe() {
    if (::pipe2(fd, O_CLOEXEC) != 0) throw Error("", std::string("pipe: ") + std::strerror(errno));
  }
  ~Pipe() {
    closeEnd(0);
    closeEnd(1);
  }
  void closeEnd(int e) {
    if (fd[e] >= 0) ::close(fd[e]);
    fd[e] = -1;
  }
};

}  // namespace

ProcessResult runProcess(const std::vector<std::string>& argv, const std::string& input,
                         const std::function<void(pid_t)>& started,
                         const std::function<void(pid_t)>& ended) {
  Pipe in, out;
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_adddup2(&actions, in.fd[0], 0);
  posix_spawn_file_actions_adddup2(&actions, out.fd[1], 1);
  posix_spawn_file_actions_adddup2(&actions, out.fd[1], 2);
  // The child starts with default signal dispositions and an empty mask, whatever this process
  // (a tool that handles SIGINT/SIGTERM) set up.
  posix_spawnattr_t attributes;
  posix_spawnattr_init(&attributes);
  sigset_t all, none;
  sigfillset(&all);
  sigemptyset(&none);
  posix_spawnattr_setsigdefault(&attributes, &all);
  posix_spawnattr_setsigmask(&attributes, &none);
  posix_spawnattr_setflags(&attributes, POSIX_SPAWN_SETSIGDEF | POSIX_SPAWN_SETSIGMASK);
  std::vector<char*> args;
  for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  pid_t pid = 0;
  const int error = argv.front().find('/') == std::string::npos
                        ? posix_spawnp(&pid, args[0], &actions, &attributes, args.data(), environ)
                        : posix_spawn(&pid, args[0], &actions, &attributes, args.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  posix_spawnattr_destroy(&attributes);
  if (error != 0) throw Error(argv.front(), std::string("cannot start: ") + std::strerror(error));
  if (started) started(pid);
  in.closeEnd(0);
  out.closeEnd(1);

  // stdin is fed by a thread of its own, so a child that writes much before reading all of it
  // cannot deadlock with us.
  std::thread feeder([&in, &input] {
    std::size_t written = 0;
    while (written < input.size()) {
      const ssize_t n = ::write(in.fd[1], input.data() + written, input.size() - written);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) break;  // the child closed stdin (or died): it reports that itself
      written += static_cast<std::size_t>(n);
    }
    in.closeEnd(1);
  });
  ProcessResult result;
  char buffer[8192];
  while (true) {
    const ssize_t n = ::read(out.fd[0], buffer, sizeof buffer);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    result.output.append(buffer, static_cast<std::size_t>(n));
  }
  feeder.join();
  // Wait without reaping first, so that the pid stays this child's while `ended` runs.
  siginfo_t info{};
  while (::waitid(P_PID, static_cast<id_t>(pid), &info, WEXITED | WNOWAIT) < 0 && errno == EINTR) {
  }
  if (ended) ended(pid);
  int status = 0;
  rusage usage{};
  while (::wait4(pid, &status, 0, &usage) < 0 && errno == EINTR) {
  }
  result.peakRssMiB = static_cast<double>(usage.ru_maxrss) / 1024.0;
  if (WIFEXITED(status)) {
    result.exitCode = WEXITSTATUS(status);
  } else if (WIFSIGNALED(status)) {
    result.signal = WTERMSIG(status);
  }
  return result;
}

}  // namespace octoray::batch::detail
