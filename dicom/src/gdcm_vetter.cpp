// Vetting files with GDCM in child processes. Debian's GDCM is built with assertions, and a
// truncated or malformed file can make it abort() the process that parses it. Each file is
// therefore first parsed by a long-lived child (one start serves many files: starting a
// process costs far more than a parse); when the child dies on a file, that file is reported
// and a new child is started for the next one.
//
// The child is this same program started afresh (posix_spawn of /proc/self/exe) with
// OCTORAY_GDCM_VETTER naming its socket: a constructor below turns it into the vetter before
// main() runs. A fork() would copy a multithreaded process whose other threads may hold locks
// (the allocator's, GDCM's, TBB's) and could deadlock the child.
//
// GDCM sizes a value's buffer from the length its element declares, before reading it, in each
// of the readings it tries on a malformed file. The length walk (declared_lengths.cpp) refuses
// lengths past the end of the file in the readings it follows; for the others the child parses
// under an address-space limit: 128 MiB plus 32 times the file's size. An allocation beyond it
// fails at once, instead of GDCM clearing up to 4 GiB for a 1 KiB file (found by fuzz_dicomdir:
// 338 MB in its explicit/implicit reading), and the file is refused without the parent
// parsing it. Under the sanitizers their allocator aborts the child instead, and the file is
// refused as one GDCM aborted on.
//
// A file GDCM does not finish parsing in time (OCTORAY_DICOM_PARSE_TIMEOUT seconds, 120 by
// default: a valid image with 1.5 million sequence items took the child 1.5-2.5 s here on
// 2026-12-06) is refused as a hang: its child is killed, and the parent never parses it, since
// it would hang too. The limit runs from the moment the path is sent: a child reports ready
// once started, so loading its libraries (seconds under the sanitizers) is not counted against
// the first file.

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <gdcmImageReader.h>
#include <spawn.h>
#include <fmt/format.h>
#include <gdcmReader.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <memory>
#include <mutex>
#include <new>
#include <set>
#include <vector>

#include "gdcm_support.h"
#include "octoray/core/error.h"

namespace octoray::dicom::detail {
namespace {

constexpr const char* kVetterVariable = "OCTORAY_GDCM_VETTER";
constexpr int kChildFd = 3;
constexpr const char* kTimeoutVariable = "OCTORAY_DICOM_PARSE_TIMEOUT";
constexpr double kDefaultTimeoutSeconds = 120.0;
constexpr double kStartTimeoutSeconds = 120.0;  // loading the libraries, before the first file

// What the child's address space may grow by while GDCM parses a file of `fileBytes`: enough
// for its data set, a 32-fold inflated deflate body included, and for GDCM's objects of a
// file of millions of small elements (240 MB for a 20 MB file here).
constexpr uint64_t kMemoryBaseBytes = uint64_t(128) << 20;
constexpr uint64_t kMemoryBytesPerFileByte = 32;

// Seconds the child may take on one file: the variable where it holds a number from 0.001 on.
double parseTimeoutSeconds(const std::string& path) {
  const char* text = std::getenv(kTimeoutVariable);
  if (!text || !*text) return kDefaultTimeoutSeconds;
  const char* end = text + std::strlen(text);
  double seconds = 0.0;
  const auto [stop, error] = std::from_chars(text, end, seconds);  // no locale, no spaces
  if (error != std::errc() || stop != end || !std::isfinite(seconds) || seconds < 0.001) {
    throw Error(path, fmt::format("{} is '{}', not a number of seconds (0.001 or more) for how "
                                  "long GDCM may parse one DICOM file", kTimeoutVariable, text));
  }
  return seconds;
}

// Waits until `fd` is readable (data or end of file) or `seconds` (at most 1e7: about 4 months)
// have passed: false on timeout.
bool readableWithin(int fd, double seconds) {
  using Clock = std::chrono::steady_clock;
  const auto deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                           std::chrono::duration<double>(std::min(seconds, 1e7)));
  while (true) {
    const auto left = std::chrono::ceil<std::chrono::milliseconds>(deadline - Clock::now()).count();
    if (left <= 0) return false;
    pollfd p{fd, POLLIN, 0};
    const int n = ::poll(&p, 1, static_cast<int>(std::min<long long>(left, 1 << 30)));
    if (n > 0) return true;
    if (n < 0 && errno != EINTR) return true;  // the read that follows reports the failure
  }
}

bool sendAll(int fd, const void* data, std::size_t bytes) {
  const auto* p = static_cast<const char*>(data);
  while (bytes > 0) {
    const ssize_t n = ::send(fd, p, bytes, MSG_NOSIGNAL);  // a dead peer must not SIGPIPE us
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    p += n;
    bytes -= static_cast<std::size_t>(n);
  }
  return true;
}

bool receiveAll(int fd, void* data, std::size_t bytes) {
  auto* p = static_cast<char*>(data);
  while (bytes > 0) {
    const ssize_t n = ::recv(fd, p, bytes, 0);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    p += n;
    bytes -= static_cast<std::size_t>(n);
  }
  return true;
}

// In the child: parse as the real readers will: the image model, pixel data fragments
// included, or the plain data set of a non-image (Read). Where GDCM reports that it could not
// read the file to its end, also as the header reads of the scanner and the DICOMDIR probe do
// (ReadUpToTag up to the pixel data, up to (0008,0005)): those may take another path through
// the same broken bytes, and GDCM's explicit/implicit element reader asserts where a tag ends
// the file without its VR (found by fuzz_dicomdir; a full read only reports failure there).
// Where a full read succeeds, a header read parses a prefix of what it parsed, in the same
// order of attempts, and is not repeated: some files cost GDCM seconds per read (pydicom's
// SC_rgb_jpeg.dcm cost 5-7 s and 1.3 GB each, its implicit body labelled explicit, until the
// length walk refused such files before GDCM sees them).
// 0 = parsed, 1 = GDCM reported failure (2, set by the caller: an allocation was refused).
uint8_t parseInChild(const std::string& path) {
  bool parsed = false;
  try {
    gdcm::ImageReader image;
    image.SetFileName(path.c_str());
    parsed = image.Read();
    if (!parsed) {
      gdcm::Reader plain;
      plain.SetFileName(path.c_str());
      parsed = plain.Read();
    }
  } catch (...) {
    parsed = false;
  }
  if (parsed) return 0;
  const gdcm::Tag pixelData(0x7fe0, 0x0010);
  const std::pair<gdcm::Tag, std::set<gdcm::Tag>> headerReads[] = {
      {pixelData, {pixelData}}, {gdcm::Tag(0x0008, 0x0005), {}}};
  for (const auto& [stop, skipped] : headerReads) {
    try {
      gdcm::Reader upTo;
      upTo.SetFileName(path.c_str());
      (void)upTo.ReadUpToTag(stop, skipped);
    } catch (...) {
      // a failure the parent's reader reports in its turn
    }
  }
  return 1;
}

// Set in the child when operator new could not allocate within the limit.
volatile bool gAllocationRefused = false;
void refuseAllocation() {
  gAllocationRefused = true;
  throw std::bad_alloc();
}

// The child's address space now, from /proc/self/statm (0 where it cannot be read).
uint64_t addressSpaceBytes() {
  std::FILE* statm = std::fopen("/proc/self/statm", "r");
  if (!statm) return 0;
  unsigned long long pages = 0;
  const bool read = std::fscanf(statm, "%llu", &pages) == 1;
  std::fclose(statm);
  return read ? pages * static_cast<uint64_t>(::sysconf(_SC_PAGESIZE)) : 0;
}

// Parses `path` with the address space limited to what it has now plus the file's budget.
uint8_t parseWithinMemoryBudget(const std::string& path) {
  struct stat status {};
  const uint64_t fileBytes = ::stat(path.c_str(), &status) == 0 ? uint64_t(status.st_size) : 0;
  rlimit original{};
  const uint64_t now = addressSpaceBytes();
  const bool limited = now > 0 && ::getrlimit(RLIMIT_AS, &original) == 0;
  if (limited) {
    rlimit narrowed = original;
    const uint64_t budget = memoryBudgetBytes(fileBytes);
    const uint64_t cap = now > ~uint64_t(0) - budget ? ~uint64_t(0) : now + budget;
    if (original.rlim_cur == RLIM_INFINITY || cap < original.rlim_cur) narrowed.rlim_cur = cap;
    ::setrlimit(RLIMIT_AS, &narrowed);
  }
  gAllocationRefused = false;
  uint8_t result = parseInChild(path);
  if (limited) ::setrlimit(RLIMIT_AS, &original);
  if (gAllocationRefused) result = 2;
  return result;
}

[[noreturn]] void childLoop(int fd) {
  const int devNull = ::open("/dev/null", O_WRONLY);
  if (devNull >= 0) ::dup2(devNull, STDERR_FILENO);  // GDCM's assertion text is not ours to print
  std::set_new_handler(refuseAllocation);
  const uint8_t ready = 1;  // the parent's time limit is for parsing, not for starting
  if (!sendAll(fd, &ready, 1)) ::_exit(0);
  while (true) {
    uint32_t length = 0;
    if (!receiveAll(fd, &length, sizeof length) || length > (1u << 20)) ::_exit(0);
    std::string path(length, '\0');
    if (!receiveAll(fd, path.data(), length)) ::_exit(0);
    const uint8_t status = parseWithinMemoryBudget(path);
    if (!sendAll(fd, &status, 1)) ::_exit(0);
  }
}

// Runs before main(): a process started as a vetter serves its parent and never returns.
__attribute__((constructor)) void becomeVetterIfAsked() {
  const char* fd = std::getenv(kVetterVariable);
  if (fd && *fd) childLoop(std::atoi(fd));
}

class Vetter {
 public:
  ~Vetter() { stop(); }

  // A process forked from the one that started the child must not share its conversation.
  bool ownedByThisProcess() const { return owner_ == ::getpid(); }
  void abandon() {
    if (fd_ >= 0) ::close(fd_);  // our copy only; the child belongs to another process
    fd_ = -1;
    pid_ = -1;
  }

  enum class Outcome { Survived, Died, TimedOut, NeedsTooMuchMemory };

  // Whether GDCM survives parsing `path` (whether or not it understood it) within `seconds`.
  Outcome parse(const std::string& path, double seconds) {
    if (pid_ < 0) start(path);
    const auto length = static_cast<uint32_t>(path.size());
    uint8_t status = 0;
    if (!sendAll(fd_, &length, sizeof length) || !sendAll(fd_, path.data(), path.size())) {
      stop();  // the child died; the next call starts a fresh one
      return Outcome::Died;
    }
    if (!readableWithin(fd_, seconds)) {
      ::kill(pid_, SIGKILL);  // stuck in GDCM: it cannot be asked to stop
      stop();
      return Outcome::TimedOut;
    }
    if (receiveAll(fd_, &status, 1)) return status == 2 ? Outcome::NeedsTooMuchMemory : Outcome::Survived;
    stop();  // the child died on this file; the next call starts a fresh one
    return Outcome::Died;
  }

 private:
  void start(const std::string& path) {
    int fds[2];
    if (::socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, fds) != 0) {
      throw Error(path, std::string("cannot create a socket to vet the file: ") + std::strerror(errno));
    }
    // The child gets its end as descriptor 3 (dup2 clears close-on-exec) and nothing else.
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_adddup2(&actions, fds[1], kChildFd);
    std::vector<std::string> environment{std::string(kVetterVariable) + "=" + std::to_string(kChildFd)};
    for (char** e = environ; *e; ++e) {
      if (std::strncmp(*e, kVetterVariable, std::strlen(kVetterVariable)) != 0) environment.emplace_back(*e);
    }
    std::vector<char*> envp;
    for (auto& e : environment) envp.push_back(e.data());
    envp.push_back(nullptr);
    char name[] = "octoray-gdcm-vetter";
    char* argv[] = {name, nullptr};
    pid_t pid = -1;
    const int error = ::posix_spawn(&pid, "/proc/self/exe", &actions, nullptr, argv, envp.data());
    posix_spawn_file_actions_destroy(&actions);
    ::close(fds[1]);
    if (error != 0) {
      ::close(fds[0]);
      throw Error(path, std::string("cannot start the vetting process: ") + std::strerror(error));
    }
    pid_ = pid;
    fd_ = fds[0];
    owner_ = ::getpid();
    uint8_t ready = 0;
    const bool answered = readableWithin(fd_, kStartTimeoutSeconds);
    if (!answered || !receiveAll(fd_, &ready, 1)) {
      ::kill(pid_, SIGKILL);
      stop();
      throw Error(path, answered ? std::string("the process that vets the file with GDCM ended while starting")
                                 : fmt::format("the process that vets the file with GDCM did not start in {:g} s",
                                               kStartTimeoutSeconds));
    }
  }

  void stop() {
    if (fd_ >= 0) ::close(fd_);  // the child reads end-of-file and exits
    fd_ = -1;
    if (pid_ > 0) {
      int status = 0;
      while (::waitpid(pid_, &status, 0) < 0 && errno == EINTR) {
      }
    }
    pid_ = -1;
  }

  pid_t pid_ = -1;
  pid_t owner_ = -1;
  int fd_ = -1;
};

// Idle vetters, one per thread that is vetting at the same time.
std::mutex gPoolMutex;
std::vector<std::unique_ptr<Vetter>>& pool() {
  static auto* idle = new std::vector<std::unique_ptr<Vetter>>();  // children end with us
  return *idle;
}

// Files that timed out, so that a second look at one (the DICOMDIR walk, then the header read)
// does not wait out the limit again; keyed by path, size and modification time.
struct TimedOutFile {
  std::uintmax_t size = 0;
  std::filesystem::file_time_type modified;
  double seconds = 0.0;
};
std::map<std::string, TimedOutFile>& timedOut() {
  static auto* files = new std::map<std::string, TimedOutFile>();
  return *files;
}

std::optional<TimedOutFile> stamp(const std::string& path, double seconds) {
  std::error_code error;
  TimedOutFile file{std::filesystem::file_size(path, error), {}, seconds};
  if (error) return std::nullopt;
  file.modified = std::filesystem::last_write_time(path, error);
  if (error) return std::nullopt;
  return file;
}

std::string timeoutReason(double seconds) {
  return fmt::format("the GDCM parser did not finish reading it in {:g} s ({} sets the limit)",
                     seconds, kTimeoutVariable);
}

}  // namespace

uint64_t memoryBudgetBytes(uint64_t fileBytes) {
  const uint64_t most = (~uint64_t(0) - kMemoryBaseBytes) / kMemoryBytesPerFileByte;
  return fileBytes > most ? ~uint64_t(0) : kMemoryBaseBytes + kMemoryBytesPerFileByte * fileBytes;
}

void vetWithGdcm(const std::string& path) {
  checkDeclaredLengths(path);
  const double seconds = parseTimeoutSeconds(path);
  const std::optional<TimedOutFile> now = stamp(path, seconds);
  {
    std::lock_guard lock(gPoolMutex);
    const auto before = timedOut().find(path);
    if (before != timedOut().end() && now && before->second.size == now->size &&
        before->second.modified == now->modified && seconds <= before->second.seconds) {
      throw Error(path, timeoutReason(before->second.seconds));
    }
  }
  std::unique_ptr<Vetter> vetter;
  {
    std::lock_guard lock(gPoolMutex);
    if (!pool().empty()) {
      vetter = std::move(pool().back());
      pool().pop_back();
    }
  }
  if (vetter && !vetter->ownedByThisProcess()) {
    vetter->abandon();
    vetter.reset();
  }
  if (!vetter) vetter = std::make_unique<Vetter>();
  const Vetter::Outcome outcome = vetter->parse(path, seconds);
  {
    std::lock_guard lock(gPoolMutex);
    pool().push_back(std::move(vetter));
  }
  if (outcome == Vetter::Outcome::Died) {
    throw Error(path, "malformed or truncated DICOM (the GDCM parser aborted on it)");
  }
  if (outcome == Vetter::Outcome::NeedsTooMuchMemory) {
    throw Error(path, fmt::format("malformed DICOM: the GDCM parser asked for more than the {} MiB "
                                  "a file of {} bytes may take (a declared length it cannot hold)",
                                  memoryBudgetBytes(now ? now->size : 0) >> 20,
                                  now ? now->size : 0));
  }
  if (outcome == Vetter::Outcome::TimedOut) {
    if (now) {
      std::lock_guard lock(gPoolMutex);
      timedOut()[path] = *now;
    }
    throw Error(path, timeoutReason(seconds));
  }
}

}  // namespace octoray::dicom::detail
