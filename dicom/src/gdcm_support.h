#pragma once
// Small helpers over GDCM's data set API shared by the scanner and the decoder (internal).

#include <gdcmDataSet.h>
#include <gdcmFile.h>
#include <gdcmTag.h>

#include <optional>
#include <cstdint>
#include <string>
#include <vector>

namespace octoray::dicom::detail {

// Silences GDCM's own stderr chatter once per process: we report problems ourselves.
void quietGdcm();

// The value of a string-VR element with trailing spaces and NULs removed ("" if absent).
std::string stringValue(const gdcm::DataSet& ds, const gdcm::Tag& tag);
// Backslash-separated values of a string-VR element.
std::vector<std::string> stringValues(const gdcm::DataSet& ds, const gdcm::Tag& tag);
// Decimal/integer string values (DS, IS) parsed to doubles; nullopt if absent or malformed.
std::optional<std::vector<double>> numberValues(const gdcm::DataSet& ds, const gdcm::Tag& tag);
std::optional<double> numberValue(const gdcm::DataSet& ds, const gdcm::Tag& tag);
// Vets `path` before GDCM parses it in this process: its declared lengths are checked
// (checkDeclaredLengths), then GDCM parses it in a child process, since Debian's GDCM is built
// with assertions and some truncated or malformed files make it abort() the whole process.
// Throws octoray::Error naming the file when a length runs past its end or the parser dies on
// it; returns normally otherwise (including when GDCM merely reports a parse failure, which
// the caller then sees itself).
void vetWithGdcm(const std::string& path);
// Walks the file's data elements (seeking over their values) and throws octoray::Error naming
// the file and the element when a defined length runs past the end of the file: GDCM would
// allocate and clear a buffer of that size before finding the file too short.
void checkDeclaredLengths(const std::string& path);
// What the vetting child's address space may grow by while GDCM parses a file of `fileBytes`
// (128 MiB plus 32 times the file); an allocation beyond it refuses the file.
uint64_t memoryBudgetBytes(uint64_t fileBytes);

}  // namespace octoray::dicom::detail
namespace octoray::dicom { struct DecodedImage; }
namespace octoray::dicom::detail {
// Where the pixel data value starts in the file (it is skipped, not read); size_t(-1) when
// the file has no pixel data or cannot be parsed. Only call on vetted files.
std::size_t pixelValueOffset(const std::string& path);

// decodeDicomFile without vetting, for files scanDicom has already vetted.
DecodedImage decodeVettedDicomFile(const std::string& path);
// Frames [firstFrame, firstFrame + frameCount) of a vetted multi-frame file (fewer where the file
// ends first), read without the others where GDCM can find them alone, so that the memory a
// multi-frame object takes is that of the frames asked for, not of the whole file.
DecodedImage decodeVettedDicomFrames(const std::string& path, int firstFrame, int frameCount);

// A US (or US/SS) element (GDCM hands values over in host byte order); nullopt if absent.
std::optional<int> unsignedShort(const gdcm::File& file, const gdcm::DataSet& ds,
                                 const gdcm::Tag& tag, bool asSigned = false);
// The items of sequence `tag` (copies: GDCM may parse an undecoded sequence on the fly).
std::vector<gdcm::DataSet> sequenceItems(const gdcm::DataSet& ds, const gdcm::Tag& tag);
// The first item of sequence `tag`, or nullopt when absent or empty.
std::optional<gdcm::DataSet> firstItem(const gdcm::DataSet& ds, const gdcm::Tag& tag);

}  // namespace octoray::dicom::detail
