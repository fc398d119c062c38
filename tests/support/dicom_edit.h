#pragma once
// Edits DICOM files in place for tests that need awkward exams (GDCM reads and writes them).

#include <cstdint>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

namespace octoray::test {

// One element's tag, (group, element).
struct DicomTag {
  uint16_t group = 0, element = 0;
};

// Sets string elements of the DICOM file at `path` (padded to even length, a UI with NUL): an
// element the file has keeps its VR, one it lacks gets the dictionary's. Throws std::runtime_error
// naming the file when it cannot be read or written.
void rewriteDicomStrings(const std::filesystem::path& path, const std::vector<std::pair<DicomTag, std::string>>& values);

}  // namespace octoray::test
