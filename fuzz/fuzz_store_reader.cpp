// libFuzzer target: arbitrary bytes as an octree store file. Every octoray::Error is an
// accepted answer; a crash, a hang, a sanitizer report, an out-of-memory or any other
// exception escaping is a bug (DESIGN.md, "Errors and bad input").
//
// Each input is tried twice: as given, and with its checksums and file size repaired
// ("sealed"), so that mutations reach the checks behind the checksums (layout, node records,
// decompression) instead of stopping at the header checksum almost every time.

#include <fcntl.h>
#include <unistd.h>
#include <xxhash.h>

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <string>
#include <vector>

#include "octoray/core/error.h"
#include "octoray/volume/store_format.h"
#include "octoray/volume/store_reader.h"

namespace {

using octoray::volume::NodeRecord;
using octoray::volume::StoreHeader;
using octoray::volume::StoreReader;

// One scratch file per fuzzing process (libFuzzer may run several with -jobs/-workers).
const std::string& scratchPath() {
  static const std::string path = [] {
    std::filesystem::path dir = std::filesystem::temp_directory_path();
    auto p = dir / ("octoray-fuzz-store-" + std::to_string(::getpid()) + ".octoray");
    std::atexit([] { ::unlink(scratchPath().c_str()); });
    return p.string();
  }();
  return path;
}

void writeScratch(const uint8_t* data, std::size_t size) {
  const int fd = ::open(scratchPath().c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
  if (fd < 0) std::abort();  // the harness itself is broken; not a finding about the reader
  std::size_t done = 0;
  while (done < size) {
    const ssize_t n = ::write(fd, data + done, size - done);
    if (n <= 0) std::abort();
    done += static_cast<std::size_t>(n);
  }
  ::close(fd);
}

// Repairs fileBytes and every checksum the reader verifies, where the offsets allow it.
std::vector<uint8_t> sealed(const uint8_t* data, std::size_t size) {
  std::vector<uint8_t> bytes(data, data + size);
  StoreHeader h;
  std::memcpy(&h, bytes.data(), sizeof h);
  h.fileBytes = size;
  const auto inside = [&](uint64_t offset, uint64_t length) {
    return offset <= size && length <= size - offset;
  };
  if (inside(h.nodeTableOffset, h.nodeTableBytes) && h.nodeTableBytes % sizeof(NodeRecord) == 0) {
    for (uint64_t at = h.nodeTableOffset; at < h.nodeTableOffset + h.nodeTableBytes;
         at += sizeof(NodeRecord)) {
      NodeRecord n;
      std::memcpy(&n, bytes.data() + at, sizeof n);
      const uint64_t payload = uint64_t{n.payloadBytes} + n.gradientBytes;
      if (!inside(n.payloadOffset, payload)) continue;
      n.payloadChecksum = XXH3_64bits(bytes.data() + n.payloadOffset, payload);
      std::memcpy(bytes.data() + at, &n, sizeof n);
    }
    h.nodeTableChecksum = XXH3_64bits(bytes.data() + h.nodeTableOffset, h.nodeTableBytes);
  }
  if (inside(h.provenanceOffset, h.provenanceBytes)) {
    h.provenanceChecksum = XXH3_64bits(bytes.data() + h.provenanceOffset, h.provenanceBytes);
  }
  h.headerChecksum = XXH3_64bits(&h, offsetof(StoreHeader, headerChecksum));
  std::memcpy(bytes.data(), &h, sizeof h);
  return bytes;
}

// Everything a consumer of an untrusted store does: parse, open, read every brick.
void exercise(const uint8_t* data, std::size_t size) {
  try {
    octoray::volume::parseStoreHeader(data, size, size, "fuzz-input");
  } catch (const octoray::Error&) {
  }
  writeScratch(data, size);
  try {
    const StoreReader reader(scratchPath());
    volatile double sink = reader.physical(1.0);
    sink = reader.patientFromIndex().m[0][0];
    for (int64_t id = 0; id < static_cast<int64_t>(reader.nodes().size()); ++id) {
      try {
        const auto brick = reader.readBrick(id);
        sink = brick.u16.empty() ? 0.0 : brick.u16.front();
        sink = reader.node(id).maxValue;
      } catch (const octoray::Error&) {
        // A damaged brick must not stop the others from being read.
      }
    }
    (void)sink;
  } catch (const octoray::Error&) {
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  exercise(data, size);
  if (size >= sizeof(StoreHeader) &&
      std::memcmp(data, octoray::volume::kStoreMagic, sizeof octoray::volume::kStoreMagic) == 0) {
    const std::vector<uint8_t> repaired = sealed(data, size);
    exercise(repaired.data(), repaired.size());
  }
  return 0;
}
