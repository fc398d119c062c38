#pragma once
// Damaging files on purpose: the tests that check a corrupted store is caught, named and
// never crashes anything.

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

namespace octoray::test {

// Flips bits of the byte at `offset` of `file` (XOR 0x5a), in place.
inline void flipByte(const std::filesystem::path& file, std::streamoff offset) {
  std::fstream f(file, std::ios::in | std::ios::out | std::ios::binary);
  f.seekg(offset);
  char byte = 0;
  f.read(&byte, 1);
  byte = static_cast<char>(byte ^ 0x5a);
  f.seekp(offset);
  f.write(&byte, 1);
  ASSERT_TRUE(f.good()) << "could not damage " << file << " at " << offset;
}

}  // namespace octoray::test
