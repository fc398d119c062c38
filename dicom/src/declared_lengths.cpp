// Declared value lengths against the file. GDCM sizes a value's buffer from the length its
// element declares and clears it before reading: a 1 KiB file declaring a 1 GiB value inside
// a sequence item made it allocate and clear 1 GiB, twice (found by fuzz_dicomdir). So the
// elements are walked first, seeking over every value, and a defined length that runs past
// the end of the file refuses the file by name before GDCM sees it.
//
// The walk follows PS3.5 §7: explicit VR (2- or 4-byte lengths by VR), implicit VR, items and
// delimiters, sequences of defined or undefined length, encapsulated pixel data (whose items
// are fragments to skip), the file meta group in explicit little endian and a big-endian body.
// Where an explicit-VR file breaks the standard it follows GDCM 3.0's readers instead:
//   - two printable characters that are no VR code are read as UN (a 4-byte length after two
//     reserved bytes);
//   - two other bytes (no VR at all) make GDCM go on from that element with its 16-bit reader
//     (a 2-byte length after them), and where that fails, start again with its
//     explicit/implicit reader (a 4-byte length right after the tag).
// Both of those readings are walked, since GDCM may allocate what either declares. It only
// ever refuses a length that cannot fit in the file; what it cannot follow (a deflated body)
// it leaves to GDCM.

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cstdint>
#include <cstring>
#include <string>
#include <string_view>
#include <vector>

#include <fmt/format.h>

#include "gdcm_support.h"
#include "octoray/core/error.h"

namespace octoray::dicom::detail {
namespace {

constexpr uint32_t kUndefinedLength = 0xffffffffu;

bool isVr(char a, char b) {
  static constexpr std::array<std::string_view, 34> kVrs = {
      "AE", "AS", "AT", "CS", "DA", "DS", "DT", "FD", "FL", "IS", "LO", "LT",
      "OB", "OD", "OF", "OL", "OV", "OW", "PN", "SH", "SL", "SQ", "SS", "ST",
      "SV", "TM", "UC", "UI", "UL", "UN", "UR", "US", "UT", "UV"};
  for (const auto vr : kVrs) {
    if (vr[0] == a && vr[1] == b) return true;
  }
  return false;
}

// How GDCM reads the two bytes where an explicit VR belongs (gdcm::VR::GetVRTypeFromFile): a
// VR code, two printable characters it takes for UN, or no VR.
enum class VrBytes { Code, ReadAsUn, None };

VrBytes classifyVr(char a, char b) {
  if (isVr(a, b)) return VrBytes::Code;
  const auto printable = [](char c) { return c >= ' ' && c <= '~'; };
  return printable(a) && printable(b) ? VrBytes::ReadAsUn : VrBytes::None;
}

// What GDCM makes of an element with no VR in an explicit-VR data set, in the reading walked.
enum class NoVr {
  SixteenBit,  // its VR16 reader, which goes on in place: a 2-byte length after the bytes
  Implicit,    // its explicit/implicit reader, from the start: a 4-byte length after the tag
};

// Explicit VRs whose length field has 4 bytes (after 2 reserved ones).
bool hasLongLength(char a, char b) {
  static constexpr std::array<std::string_view, 13> kLong = {
      "OB", "OD", "OF", "OL", "OV", "OW", "SQ", "SV", "UC", "UN", "UR", "UT", "UV"};
  for (const auto vr : kLong) {
    if (vr[0] == a && vr[1] == b) return true;
  }
  return false;
}

uint16_t u16(const unsigned char* p, bool big) {
  return big ? static_cast<uint16_t>(p[0] << 8 | p[1]) : static_cast<uint16_t>(p[1] << 8 | p[0]);
}

uint32_t u32(const unsigned char* p, bool big) {
  return big ? uint32_t(p[0]) << 24 | uint32_t(p[1]) << 16 | uint32_t(p[2]) << 8 | p[3]
             : uint32_t(p[3]) << 24 | uint32_t(p[2]) << 16 | uint32_t(p[1]) << 8 | p[0];
}

class File {
 public:
  explicit File(const std::string& path)
      : path_(path), fd_(::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK)) {
    if (fd_ < 0) throw Error(path, std::string("cannot be opened: ") + std::strerror(errno));
    struct stat status {};
    if (::fstat(fd_, &status) != 0 || !S_ISREG(status.st_mode)) {
      ::close(fd_);
      throw Error(path, "not a regular file");  // a FIFO or device would block or never end
    }
    const off_t end = ::lseek(fd_, 0, SEEK_END);
    if (end < 0) {
      ::close(fd_);
      throw Error(path, std::string("cannot be read: ") + std::strerror(errno));
    }
    size_ = static_cast<uint64_t>(end);
  }
  ~File() { ::close(fd_); }
  File(const File&) = delete;
  File& operator=(const File&) = delete;

  uint64_t size() const { return size_; }
  // Reads n bytes at `at`; false where the file ends before. Small reads come from a window of
  // the file read ahead: the walk reads every element's header, and a file of millions of
  // small elements took seconds at one system call each.
  bool read(uint64_t at, unsigned char* out, std::size_t n) const {
    if (at > size_ || size_ - at < n) return false;
    if (n > kWindow) return readDirect(at, out, n);
    if (at < windowStart_ || at + n > windowStart_ + window_.size()) {
      window_.resize(static_cast<std::size_t>(std::min<uint64_t>(kWindow, size_ - at)));
      if (!readDirect(at, window_.data(), window_.size())) {
        window_.clear();
        return false;
      }
      windowStart_ = at;
    }
    std::memcpy(out, window_.data() + (at - windowStart_), n);
    return true;
  }

 private:
  static constexpr std::size_t kWindow = 64 * 1024;

  bool readDirect(uint64_t at, unsigned char* out, std::size_t n) const {
    std::size_t done = 0;
    while (done < n) {
      const ssize_t got = ::pread(fd_, out + done, n - done, static_cast<off_t>(at + done));
      if (got < 0 && errno == EINTR) continue;
      if (got < 0) throw Error(path_, std::string("cannot be read: ") + std::strerror(errno));
      if (got == 0) return false;
      done += static_cast<std::size_t>(got);
    }
    return true;
  }

  std::string path_;
  int fd_;
  uint64_t size_ = 0;
  mutable std::vector<unsigned char> window_;
  mutable uint64_t windowStart_ = 0;
};

std::string tagName(uint16_t group, uint16_t element) {
  return fmt::format("({:04X},{:04X})", group, element);
}

// `detour`, where not empty, names the element without a VR from which GDCM's 16-bit reader
// went on: the length is one GDCM would allocate there, more than the vetting child's memory
// budget for the file's size, before failing and reading the file another way.
[[noreturn]] void refuse(const std::string& path, uint16_t group, uint16_t element,
                         uint64_t declared, uint64_t remaining, const std::string& detour = {},
                         uint64_t fileBytes = 0) {
  const std::string what = group == 0x7fe0 && element == 0x0010 ? "pixel data"
                           : group == 0xfffe               ? "item " + tagName(group, element)
                                                           : "element " + tagName(group, element);
  if (!detour.empty()) {
    throw Error(path, fmt::format("{} has no VR in an explicit-VR data set, and read on from there "
                                  "as GDCM first reads it, {} declares {} bytes; the file holds {} "
                                  "after it, and GDCM would allocate them (more than the {} MiB a "
                                  "file of its size may take): refused as corrupt",
                                  detour, what, declared, remaining, memoryBudgetBytes(fileBytes) >> 20));
  }
  throw Error(path, fmt::format("{} declares {} bytes but the file holds {} after it (file "
                                "truncated or corrupt)",
                                what, declared, remaining));
}

// Walks the elements from `pos` (the meta group or the body's first element), refusing the
// file where a defined length runs past its end. True where an element in explicit VR had no
// VR at all, so that GDCM may read the file the other way `noVr` names.
bool walkDeclaredLengths(const File& file, const std::string& path, uint64_t pos, NoVr noVr) {
  const uint64_t size = file.size();
  unsigned char b[12];
  bool sawNoVr = false;
  std::string detour;  // in the 16-bit reading: the element it went on from
  // The body's encoding: from the transfer syntax where the meta group names one.
  std::string syntax;
  bool big = false;
  bool bodyStarted = false;
  bool implicitBody = false;  // implicit VR: lengths never follow a VR code
  // The sequences and encapsulated pixel data the walk is inside: where each ends (its
  // delimiter, or a position), whether its content is implicit VR (an explicit UN of undefined
  // length holds implicit content, CP-246) and whether its items are fragments.
  struct Context {
    uint64_t end;
    bool implicit;
    bool fragments;
  };
  constexpr uint64_t kToDelimiter = ~uint64_t(0);
  constexpr std::size_t kMaxDepth = 1024;  // deeper nesting is walked in the innermost context
  std::vector<Context> open;
  while (pos < size && size - pos >= 8) {
    while (!open.empty() && open.back().end != kToDelimiter && pos >= open.back().end) {
      open.pop_back();
    }
    if (!file.read(pos, b, 8)) break;
    const bool meta = !bodyStarted && u16(b, false) == 0x0002;
    if (!meta && !bodyStarted) {
      bodyStarted = true;
      // Deflated bodies (GDCM inflates the plain one; the JPIP ones it does not read).
      for (const char* deflated :
           {"1.2.840.10008.1.2.1.99", "1.2.840.10008.1.2.4.95", "1.2.840.10008.1.2.4.205"}) {
        if (syntax == deflated) return false;
      }
      big = syntax == "1.2.840.10008.1.2.2";
      if (syntax.empty()) {
        // No meta group: a big-endian body shows in the first tag's group.
        big = u16(b, false) > 0x00ff && u16(b, true) <= 0x00ff;
      }
      // Implicit where labelled so, or where nothing is labelled, unless the first element
      // carries a VR code: then it is explicit in fact (GDCM reads such files so).
      implicitBody = (syntax == "1.2.840.10008.1.2" || syntax.empty()) &&
                     !isVr(char(b[4]), char(b[5]));
    }
    const bool implicitHere = !meta && (open.empty() ? implicitBody : open.back().implicit);
    // Bytes that are no VR where the body has explicit VR: GDCM's 16-bit reader takes over at
    // this element, outside any sequence it was in, and reads little endian from there on
    // whatever the byte order. (A meta group without VRs GDCM rereads as implicit VR, its
    // own way, never with that reader.)
    const VrBytes vr = implicitHere ? VrBytes::None : classifyVr(char(b[4]), char(b[5]));
    const bool item = u16(b, false) == 0xfffe || u16(b, true) == 0xfffe;  // no VR field
    const bool startsDetour = !implicitHere && !meta && !item && vr == VrBytes::None && !sawNoVr;
    if (startsDetour) {
      sawNoVr = true;
      if (noVr == NoVr::SixteenBit) open.clear();
    }
    const bool detourHere = noVr == NoVr::SixteenBit && sawNoVr;
    const bool bigHere = big && !meta && !detourHere;
    const bool inFragments = !open.empty() && open.back().fragments;
    const uint16_t group = u16(b, bigHere), element = u16(b + 2, bigHere);
    const uint64_t remainingAfter8 = size - pos - 8;
    if (startsDetour && noVr == NoVr::SixteenBit) {
      detour = fmt::format("element {} at byte {}", tagName(group, element), pos);
    }

    if (group == 0xfffe) {  // item, item delimiter, sequence delimiter: tag and 4-byte length
      const uint32_t length = u32(b + 4, bigHere);
      pos += 8;
      if (element == 0xe0dd && !open.empty() && open.back().end == kToDelimiter) open.pop_back();
      if (element != 0xe000 || length == kUndefinedLength) continue;
      if (length > remainingAfter8) {
        // GDCM's 16-bit reading fails here and GDCM reads the file another way (walked too):
        // a file is refused for it only where the allocation would be beyond the budget.
        if (detourHere && length <= memoryBudgetBytes(size)) break;
        refuse(path, group, element, length, remainingAfter8, detourHere ? detour : "", size);
      }
      if (inFragments) pos += length;  // a fragment: raw bytes; an item's elements follow
      continue;
    }

    uint64_t header = 8;
    uint32_t length = 0;
    const bool sixteenBit = detourHere && !implicitHere && vr == VrBytes::None;
    const bool explicitVr = !implicitHere && (vr != VrBytes::None || sixteenBit);
    bool sequence = false, unknown = false;
    if (sixteenBit) {
      // No VR: a 2-byte length after the two bytes, except pixel data's 4-byte one after two
      // more (GDCM's "OX" hack).
      if (group == 0x7fe0 && element == 0x0010) {
        if (!file.read(pos + 8, b + 8, 4)) break;
        header = 12;
        length = u32(b + 8, bigHere);
      } else {
        length = u16(b + 6, bigHere);
      }
      unknown = true;
    } else if (vr == VrBytes::ReadAsUn) {
      if (!file.read(pos + 8, b + 8, 4)) break;
      header = 12;
      length = u32(b + 8, bigHere);
      unknown = true;
    } else if (explicitVr) {
      if (hasLongLength(char(b[4]), char(b[5]))) {
        if (!file.read(pos + 8, b + 8, 4)) break;
        header = 12;
        length = u32(b + 8, bigHere);
      } else {
        length = u16(b + 6, bigHere);
      }
      sequence = b[4] == 'S' && b[5] == 'Q';
      unknown = b[4] == 'U' && b[5] == 'N';
    } else {
      length = u32(b + 4, bigHere);
      unknown = true;  // no VR: a sequence shows by its first item
    }
    if (meta && element == 0x0010 && length <= 64 && header + length <= size - pos) {
      std::string value(length, '\0');
      if (file.read(pos + header, reinterpret_cast<unsigned char*>(value.data()), length)) {
        while (!value.empty() && (value.back() == '\0' || value.back() == ' ')) value.pop_back();
        syntax = value;
      }
    }
    pos += header;
    const bool pixelData = group == 0x7fe0 && element == 0x0010;
    // Content of an undefined-length UN is implicit VR; of any other sequence, as around it.
    const bool contentImplicit = implicitHere || (explicitVr && unknown);
    if (length == kUndefinedLength) {
      // A sequence (or UN holding one) or encapsulated pixel data: its items follow.
      if (open.size() < kMaxDepth) open.push_back({kToDelimiter, contentImplicit, pixelData});
      continue;
    }
    const uint64_t remaining = size - pos;
    if (length > remaining) {
      if (detourHere && length <= memoryBudgetBytes(size)) break;
      refuse(path, group, element, length, remaining, detourHere ? detour : "", size);
    }
    // A value without a VR saying what it is holds a sequence where it starts with an item
    // whose length fits in the value (GDCM never reads pixel data so).
    if (unknown && !pixelData && length >= 8 && file.read(pos, b, 8) &&
        u16(b, bigHere) == 0xfffe && u16(b + 2, bigHere) == 0xe000) {
      const uint32_t first = u32(b + 4, bigHere);
      sequence = first == kUndefinedLength || first <= length - 8;
    }
    if (sequence) {  // its items are walked in place, up to its end
      if (open.size() < kMaxDepth) open.push_back({pos + length, contentImplicit, false});
    } else {
      pos += length;
    }
  }
  return sawNoVr;
}

}  // namespace

void checkDeclaredLengths(const std::string& path) {
  const File file(path);
  const uint64_t size = file.size();
  unsigned char b[12];

  // A Part 10 file: 128-byte preamble, "DICM", then the meta group in explicit little endian.
  uint64_t pos = 0;
  if (file.read(128, b, 4) && std::memcmp(b, "DICM", 4) == 0) {
    pos = 132;
  } else {
    // A bare data set: walked wherever GDCM would read one. GDCM reads a file without a
    // preamble as DICOM when its first element is in the command, meta or identifying group
    // (in either byte order), is a private creator (element 0x0010), or carries a VR code
    // (a DICOMDIR's (0004,1200) UL, say: found by fuzz_dicomdir, whose 100-byte bare
    // DICOMDIR then declared a 4 GiB implicit value). Anything else is not walked: a length
    // read from text would name a meaningless element.
    if (!file.read(0, b, 6)) return;
    const uint16_t little = u16(b, false), big = u16(b, true);
    const auto plausible = [](uint16_t group) { return group == 0 || group == 2 || group == 8; };
    const bool privateCreator = u16(b + 2, false) == 0x0010;
    if (!plausible(little) && !plausible(big) && !privateCreator && !isVr(char(b[4]), char(b[5]))) {
      // Not DICOM by any of those signs. GDCM still reads the first element as implicit VR
      // little endian before it gives up, and on some such files (one starting (FF00,0000),
      // found by fuzz_dicomdir) then allocates what its length says: 1.7 GB for 132 bytes.
      // That one length is checked; the rest is GDCM's to refuse.
      const uint32_t length = u32(b + 4, false);
      if (length != kUndefinedLength && length > size - 8) {
        throw Error(path, fmt::format("not a DICOM file (no preamble; read as a bare data set, "
                                      "its first element {} would declare {} bytes, the file "
                                      "holds {} after it)",
                                      tagName(u16(b, false), u16(b + 2, false)), length, size - 8));
      }
      return;
    }
  }

  // Elements with no VR read as implicit VR, as GDCM's explicit/implicit reader does; where
  // there are such elements, also as its 16-bit reader, which it tries first, goes on.
  if (walkDeclaredLengths(file, path, pos, NoVr::Implicit)) {
    walkDeclaredLengths(file, path, pos, NoVr::SixteenBit);
  }
}

}  // namespace octoray::dicom::detail
