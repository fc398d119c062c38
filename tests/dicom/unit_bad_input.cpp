// Bad input found by a black-box sweep (issue 14): each case must end in one octoray::Error
// naming the file and the problem, quickly, with nothing else on stderr. Every call runs under
// a deadline, so a regression to a hang fails instead of stalling the suite.

#include <gdcmReader.h>
#include <gdcmSequenceOfItems.h>
#include <gdcmWriter.h>
#include <gtest/gtest.h>

#include <tuple>

#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <future>
#include <thread>

#include <fmt/format.h>
#include <fmt/ranges.h>

#include "format_test_helpers.h"
#include "octoray/core/error.h"
#include "octoray/dicom/dicom_decode.h"
#include "octoray/dicom/dicom_series.h"
#include "octoray/dicom/dicom_volume.h"
#include "octoray/dicom/formats.h"
#include "octoray/dicom/synthetic_series.h"
#include "test_paths.h"

namespace octoray {
namespace {

namespace fs = std::filesystem;
using namespace formats_test;
using namespace std::chrono_literals;

constexpr auto kDeadline = 5s;

// Runs `call` on its own thread and returns the message of the octoray::Error it throws
// ("" when it returns normally). Past the deadline the call is taken to hang: the thread
// cannot be stopped (and may be eating memory), so the failure is reported and the suite ends.
template <typename F>
std::string errorOf(F&& call, const std::string& what, std::chrono::seconds deadline = kDeadline) {
  std::packaged_task<std::string()> task([call = std::forward<F>(call)]() mutable {
    try {
      call();
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string();
  });
  auto result = task.get_future();
  std::thread(std::move(task)).detach();
  if (result.wait_for(deadline) != std::future_status::ready) {
    // On stdout: stderr may be captured by the caller at this point.
    std::printf("FAILED: %s did not finish within %lld s (hang regressed)\n", what.c_str(),
                static_cast<long long>(deadline.count()));
    std::fflush(stdout);
    std::_Exit(1);
  }
  return result.get();
}

// Expects `call` to throw an octoray::Error mentioning every one of `mentions`, in time, and
// to print nothing itself (libraries' own reports, object dumps) on stderr.
template <typename F>
void expectCleanError(F&& call, const std::vector<std::string>& mentions, const std::string& what) {
  testing::internal::CaptureStderr();
  const std::string message = errorOf(std::forward<F>(call), what);
  const std::string printed = testing::internal::GetCapturedStderr();
  ASSERT_FALSE(message.empty()) << what << ": no octoray::Error thrown";
  for (const auto& mention : mentions) {
    EXPECT_NE(message.find(mention), std::string::npos)
        << what << ": '" << message << "' does not mention '" << mention << "'";
  }
  EXPECT_EQ(printed, "") << what << ": printed on stderr besides the error";
}

// ---- NIfTI ----------------------------------------------------------------------------------

// A 4x4x4 int16 NIfTI-1 file (348-byte header, 4 bytes of extension flag, samples), in either
// byte order.
std::string niftiBytes(int16_t datatype, int16_t bitpix, int16_t ndim = 3, bool bigEndian = false) {
  std::string bytes(352, '\0');
  const auto put = [&](std::size_t offset, auto value) {
    char b[sizeof value];
    std::memcpy(b, &value, sizeof value);
    if (bigEndian != (std::endian::native == std::endian::big)) std::reverse(b, b + sizeof value);
    std::memcpy(bytes.data() + offset, b, sizeof value);
  };
  put(0, int32_t{348});
  const int16_t dim[8] = {ndim, 4, 4, 4, 1, 1, 1, 1};
  for (int i = 0; i < 8; ++i) put(40 + 2 * i, dim[i]);
  put(70, datatype);
  put(72, bitpix);
  for (int i = 0; i < 8; ++i) put(76 + 4 * i, 1.0f);  // pixdim
  put(108, 352.0f);                                   // vox_offset
  put(112, 1.0f);                                     // scl_slope
  std::memcpy(bytes.data() + 344, "n+1\0", 4);
  return bytes + std::string(4 * 4 * 4 * 2, '\0');
}

TEST(BadInputNifti, UnknownDatatypeIsRefusedBeforeVtkReadsIt) {
  const auto dir = test::freshTempDir("bad_nifti_datatype");
  writeFile(dir / "good.nii", niftiBytes(4, 16));
  EXPECT_EQ(openNifti((dir / "good.nii").string())->info().dims, (std::array<int64_t, 3>{4, 4, 4}));
  writeFile(dir / "big.nii", niftiBytes(4, 16, 3, true));
  EXPECT_EQ(openNifti((dir / "big.nii").string())->info().dims, (std::array<int64_t, 3>{4, 4, 4}));

  // Unknown to NIfTI and to VTK: vtkNIFTIImageReader used to leave no header, and we crashed.
  writeFile(dir / "unknown.nii", niftiBytes(12345, 16));
  expectCleanError([&] { openNifti((dir / "unknown.nii").string()); },
                   {"unknown.nii", "unsupported NIfTI datatype 12345"}, "datatype 12345");
  writeFile(dir / "swapped.nii", niftiBytes(12345, 16, 3, true));
  expectCleanError([&] { openNifti((dir / "swapped.nii").string()); },
                   {"swapped.nii", "unsupported NIfTI datatype 12345"}, "datatype 12345, swapped");
  writeFile(dir / "unknown.nii.gz", gzipBytes(niftiBytes(12345, 16)));
  expectCleanError([&] { openVolume((dir / "unknown.nii.gz").string()); },
                   {"unknown.nii.gz", "unsupported NIfTI datatype 12345"}, "datatype 12345, .gz");
  // Known but not a scalar type.
  writeFile(dir / "rgb.nii", niftiBytes(128, 24));
  expectCleanError([&] { openNifti((dir / "rgb.nii").string()); },
                   {"rgb.nii", "unsupported NIfTI datatype 128"}, "datatype 128");
}

TEST(BadInputNifti, BitpixMustMatchTheDatatype) {
  const auto dir = test::freshTempDir("bad_nifti_bitpix");
  writeFile(dir / "bitpix.nii", niftiBytes(4, 32));
  expectCleanError([&] { openNifti((dir / "bitpix.nii").string()); },
                   {"bitpix.nii", "bitpix 32 does not match datatype 4"}, "bitpix");
}

TEST(BadInputNifti, InvalidDimsGiveOneMessageWithoutVtkDumps) {
  const auto dir = test::freshTempDir("bad_nifti_dims");
  // dim[0] = 9 in either byte order: VTK's pipeline used to print an object dump first.
  writeFile(dir / "dims.nii", niftiBytes(4, 16, 9));
  expectCleanError([&] { openNifti((dir / "dims.nii").string()); }, {"dims.nii", "dim[0] = 9"},
                   "dim[0]");
  std::string zero = niftiBytes(4, 16);
  zero[42] = zero[43] = 0;  // dim[1] = 0
  writeFile(dir / "zero.nii", zero);
  expectCleanError([&] { openNifti((dir / "zero.nii").string()); }, {"zero.nii", "dim[1] = 0"},
                   "dim[1]");
}

// ---- MetaImage ------------------------------------------------------------------------------

TEST(BadInputMetaImage, FieldsOfTheWrongSizeOrKindAreNamed) {
  const auto dir = test::freshTempDir("bad_meta_fields");
  writeFile(dir / "v.raw", std::string(4 * 4 * 4 * 2, '\0'));
  const auto header = [](const std::string& fields) {
    return "ObjectType = Image\nNDims = 3\n" + fields + "ElementDataFile = v.raw\n";
  };
  const std::string ok = "DimSize = 4 4 4\nElementType = MET_SHORT\n";
  // Each header, and what its one message must say.
  const std::vector<std::pair<std::string, std::string>> cases = {
      {header("DimSize = 4 4\nElementType = MET_SHORT\n"),
       "DimSize = '4 4': 3 positive integers expected"},
      {header("DimSize = 4 0 4\nElementType = MET_SHORT\n"),
       "DimSize = '4 0 4': 3 positive integers expected"},
      {header("DimSize = 4 4 9223372036854775807\nElementType = MET_SHORT\n"),
       "DimSize = '4 4 9223372036854775807': 3 positive integers expected"},
      {header("DimSize = 1099511627776 1099511627776 4\nElementType = MET_SHORT\n"), "too large"},
      {header(ok + "ElementSpacing = 1 nan 1\n"),
       "ElementSpacing = '1 nan 1': 3 finite numbers expected"},
      {header(ok + "TransformMatrix = 1 0 0 0 1 0\n"),
       "TransformMatrix = '1 0 0 0 1 0': 9 finite numbers expected"},
      {header(ok + "BinaryDataByteOrderMSB = maybe\n"),
       "BinaryDataByteOrderMSB = 'maybe': True or False expected"},
      {header(ok + "HeaderSize = -7\n"), "HeaderSize = '-7': -1 or more expected"},
      {header("DimSize = 4 4 4\nElementType = MET_LONG_LONG\n"),
       "unsupported ElementType 'MET_LONG_LONG'"},
      {header(ok + "DimSize = 4 4 4\n"), "field 'DimSize' appears twice in the header"},
      {header("DimSize = 4 4 4\n"), "lacks the required field(s) ElementType"},
      {"ObjectType = Image\nNDims = 3\n" + ok, "has no ElementDataFile field"},
      {header(ok + "ObjectType = Mesh\n"), "field 'ObjectType' appears twice"},
      // A binary line, and a field name MetaIO copied into a 255-byte buffer unchecked (found
      // by fuzz_volume_headers): not a header line, whatever follows.
      {header(ok + "Element\x03Type = MET_SHORT\n"), "line 5 is not a field ('Name = value')"},
      {header(ok + std::string(300, 'A') + " = 1\n"), "line 5 is not a field ('Name = value')"}};
  for (const auto& [text, message] : cases) {
    writeFile(dir / "f.mhd", text);
    expectCleanError([&] { openMetaImage((dir / "f.mhd").string()); }, {"f.mhd", message},
                     message);
  }
  writeFile(dir / "mesh.mhd", "ObjectType = Mesh\nNDims = 3\n" + ok + "ElementDataFile = v.raw\n");
  expectCleanError([&] { openMetaImage((dir / "mesh.mhd").string()); },
                   {"mesh.mhd", "ObjectType = 'Mesh': only images are read"}, "ObjectType");
  // Spelled in other cases, with ElementSize for the spacing and Origin for the offset, as
  // MetaIO reads them; an unknown field is a warning.
  writeFile(dir / "case.mhd", "objecttype = Image\nndims = 3\ndimsize = 4 4 4\n"
                              "elementtype = MET_SHORT\nElementSize = 0.5 0.5 2\n"
                              "Origin = 1 2 3\nMyField = 1\nelementdatafile = v.raw\n");
  auto source = openMetaImage((dir / "case.mhd").string());
  expectAffineNear(source->info().patientFromIndex,
                   Mat4::fromColumns({0.5, 0, 0}, {0, 0.5, 0}, {0, 0, 2}, {1, 2, 3}), 1e-12);
  EXPECT_EQ(source->info().warnings, std::vector<std::string>{"unknown field 'MyField'"});
}

TEST(BadInputMetaImage, NDimsOutOfRangeIsRefused) {
  const auto dir = test::freshTempDir("bad_meta_ndims");
  writeFile(dir / "v.raw", std::string(4 * 4 * 4 * 2, '\0'));
  const auto header = [](const std::string& nDimsLine) {
    return "ObjectType = Image\n" + nDimsLine +
           "\nDimSize = 4 4 4\nElementSpacing = 0.8 0.9 1.5\nElementType = MET_SHORT\n"
           "ElementDataFile = v.raw\n";
  };
  // -4 made MetaIO read doubles for ever (found by fuzz_volume_headers in CI); 11 is past
  // MetaIO's fixed arrays of 10; 1 and a non-number are not images we read.
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"NDims = -4", "-4"},  {"NDims = 11", "11"},     {"NDims = 1", "1"},
      {"NDims = 3x", "3x"},  {"  ndims=-2", "-2"},     {"NDims = 100000", "100000"}};
  for (const auto& [line, value] : cases) {
    writeFile(dir / "n.mhd", header(line));
    expectCleanError([&] { openMetaImage((dir / "n.mhd").string()); },
                     {"n.mhd", "NDims = '" + value + "': only 2D and 3D images are supported"},
                     line);
  }
  // After ElementDataFile come a .mha's samples, not header fields: its last 10 of 128 bytes
  // spell "NDims = -4".
  std::string local = header("NDims = 3");
  local.replace(local.find("v.raw"), 5, "LOCAL");
  writeFile(dir / "ok.mha", local + std::string(4 * 4 * 4 * 2 - 10, '\0') + "NDims = -4");
  auto source = openMetaImage((dir / "ok.mha").string());
  EXPECT_EQ(source->info().dims, (std::array<int64_t, 3>{4, 4, 4}));
}

TEST(BadInputMetaImage, DataFileMustStayInTheHeadersFolder) {
  const auto dir = test::freshTempDir("bad_meta_escape");
  fs::create_directories(dir / "h");
  writeFile(dir / "outside.raw", std::string(4 * 4 * 4 * 2, '\0'));
  const std::string header =
      "ObjectType = Image\nNDims = 3\nDimSize = 4 4 4\nElementType = MET_SHORT\n"
      "ElementDataFile = ";
  writeFile(dir / "h" / "up.mhd", header + "../outside.raw\n");
  expectCleanError([&] { openMetaImage((dir / "h" / "up.mhd").string()); },
                   {"up.mhd", "ElementDataFile '../outside.raw' is outside the header's folder"},
                   "ElementDataFile ..");
}

// ---- NRRD -----------------------------------------------------------------------------------

const std::string kNrrdFields = "type: int16\ndimension: 3\nsizes: 4 4 4\nendian: little\n";

TEST(BadInputNrrd, HeaderWithoutFinalNewlineEnds) {
  const auto dir = test::freshTempDir("bad_nrrd_newline");
  // vtkNrrdReader looped forever on these: std::getline at the end kept the last line.
  writeFile(dir / "m.nrrd", "NRRD0004\ntype: int16");
  expectCleanError([&] { openNrrd((dir / "m.nrrd").string()); },
                   {"m.nrrd", "lacks the required field(s) dimension, sizes, encoding"},
                   "missing final newline");
  writeFile(dir / "complete.nrrd", "NRRD0004\n" + kNrrdFields + "encoding: raw");
  expectCleanError([&] { openNrrd((dir / "complete.nrrd").string()); },
                   {"complete.nrrd", "no 'data file' and no blank line"},
                   "complete header, no newline");
}

TEST(BadInputNrrd, BinaryAfterTheMagicIsNotAHeaderLine) {
  const auto dir = test::freshTempDir("bad_nrrd_binary");
  std::string junk = "NRRD0004\n";
  for (int i = 0; i < 4096; ++i) junk += static_cast<char>((i * 131 + 7) % 256);
  writeFile(dir / "junk.nrrd", junk);
  expectCleanError([&] { openNrrd((dir / "junk.nrrd").string()); },
                   {"junk.nrrd", "header line 2 is not a field"}, "random bytes");
}

TEST(BadInputNrrd, HeaderAndLinesAreLimitedTo1MiB) {
  const auto dir = test::freshTempDir("bad_nrrd_long");
  // 8 MB on one line: vtkNrrdReader's 4 MB buffer cut it and fell into the endless loop.
  writeFile(dir / "line.nrrd", "NRRD0004\n# " + std::string(8 << 20, 'x') + "\n" + kNrrdFields);
  expectCleanError([&] { openNrrd((dir / "line.nrrd").string()); },
                   {"line.nrrd", "limited to 1 MiB"}, "8 MB line");
  std::string many = "NRRD0004\n";
  while (many.size() < (2u << 20)) many += "# a comment line of an overlong header\n";
  writeFile(dir / "many.nhdr", many + kNrrdFields + "encoding: raw\ndata file: v.raw\n");
  expectCleanError([&] { openNrrd((dir / "many.nhdr").string()); },
                   {"many.nhdr", "limited to 1 MiB"}, "2 MB header");
}

TEST(BadInputNrrd, SizesAreStrictPositive64BitIntegers) {
  const auto dir = test::freshTempDir("bad_nrrd_sizes");
  writeFile(dir / "v.raw", std::string(4 * 4 * 4 * 2, '\0'));
  const auto header = [](const std::string& sizes) {
    return "NRRD0004\ntype: int16\ndimension: 3\nsizes: " + sizes +
           "\nendian: little\nencoding: raw\ndata file: v.raw\n";
  };
  // Read before as 32x32x1 (a "vector" axis of -5) and 1x1x1 (atoi("1e10")).
  for (const std::string bad : {"-5", "1e10", "0", "2.5", "99999999999999999999"}) {
    writeFile(dir / "s.nhdr", header(bad + " 4 4"));
    expectCleanError([&] { openNrrd((dir / "s.nhdr").string()); },
                     {"s.nhdr", fmt::format("'{}' is not a positive integer", bad)},
                     "sizes " + bad);
  }
  writeFile(dir / "count.nhdr", header("4 4"));
  expectCleanError([&] { openNrrd((dir / "count.nhdr").string()); },
                   {"count.nhdr", "'sizes' gives 2 value(s) for 'dimension: 3'"}, "sizes count");
  // 2^32 samples: the message keeps all 64 bits (8589934592 bytes of int16).
  writeFile(dir / "wide.nhdr", header("4294967296 1 1"));
  expectCleanError([&] { openNrrd((dir / "wide.nhdr").string()); },
                   {"v.raw", "expected 8589934592 bytes"}, "sizes 2^32");
  writeFile(dir / "huge.nhdr", header("4294967296 4294967296 4294967296"));
  expectCleanError([&] { openNrrd((dir / "huge.nhdr").string()); }, {"huge.nhdr", "too large"},
                   "sizes overflowing");
}

TEST(BadInputNrrd, SpacingsAreHonouredInAnyFieldOrder) {
  const auto dir = test::freshTempDir("bad_nrrd_spacings");
  writeFile(dir / "v.raw", std::string(4 * 4 * 4 * 2, '\0'));
  // vtkNrrdReader dropped "spacings" given before "dimension".
  writeFile(dir / "v.nhdr",
            "NRRD0004\nspacings: 0.7 0.8 2.5\ntype: int16\ndimension: 3\nsizes: 4 4 4\n"
            "endian: little\nencoding: raw\ndata file: v.raw\n");
  const auto source = openNrrd((dir / "v.nhdr").string());
  const Vec3 spacing = source->info().spacingMm();
  EXPECT_NEAR(spacing.x, 0.7, 1e-12);
  EXPECT_NEAR(spacing.y, 0.8, 1e-12);
  EXPECT_NEAR(spacing.z, 2.5, 1e-12);
  writeFile(dir / "bad.nhdr",
            "NRRD0004\n" + kNrrdFields + "spacings: 1 one 1\nencoding: raw\ndata file: v.raw\n");
  expectCleanError([&] { openNrrd((dir / "bad.nhdr").string()); },
                   {"bad.nhdr", "'one' is not a number"}, "spacings word");
}

TEST(BadInputNrrd, DataFileMustStayInTheHeadersFolder) {
  const auto dir = test::freshTempDir("bad_nrrd_escape");
  fs::create_directories(dir / "h" / "sub");
  const std::string samples(4 * 4 * 4 * 2, '\0');
  writeFile(dir / "outside.raw", samples);
  writeFile(dir / "h" / "sub" / "inside.raw", samples);
  const auto header = [&](const std::string& dataFile) {
    return "NRRD0004\n" + kNrrdFields + "encoding: raw\ndata file: " + dataFile + "\n";
  };
  for (const std::string& escape :
       {std::string("../outside.raw"), std::string("sub/../../outside.raw"),
        (dir / "outside.raw").string(), std::string("/etc/passwd")}) {
    writeFile(dir / "h" / "v.nhdr", header(escape));
    expectCleanError(
        [&] { openNrrd((dir / "h" / "v.nhdr").string()); },
        {"v.nhdr", fmt::format("data file '{}' is outside the header's folder", escape)},
        "data file " + escape);
  }
  // The header's folder and below are fine, relative or absolute.
  for (const std::string& inside :
       {std::string("sub/inside.raw"), std::string("./sub/../sub/inside.raw"),
        (dir / "h" / "sub" / "inside.raw").string()}) {
    writeFile(dir / "h" / "v.nhdr", header(inside));
    EXPECT_EQ(openNrrd((dir / "h" / "v.nhdr").string())->info().dims,
              (std::array<int64_t, 3>{4, 4, 4}))
        << inside;
  }
  // A file-name pattern of two billion files: refused, not expanded.
  writeFile(dir / "h" / "v.nhdr", header("slice%03d.raw 0 2000000000 1"));
  expectCleanError([&] { openNrrd((dir / "h" / "v.nhdr").string()); },
                   {"v.nhdr", "data split over several files is not supported"}, "pattern");
}

// ---- DICOM ----------------------------------------------------------------------------------

// Sets one element of a DICOM file to a string value (padded to even length).
void rewriteElement(const fs::path& path, const gdcm::Tag& tag, const gdcm::VR& vr,
                    std::string text) {
  gdcm::Reader reader;
  reader.SetFileName(path.c_str());
  ASSERT_TRUE(reader.Read()) << path;
  gdcm::DataElement element(tag);
  element.SetVR(vr);
  if (text.size() % 2) text += ' ';
  element.SetByteValue(text.data(), static_cast<uint32_t>(text.size()));
  reader.GetFile().GetDataSet().Replace(element);
  gdcm::Writer writer;
  writer.SetFileName(path.c_str());
  writer.SetFile(reader.GetFile());
  ASSERT_TRUE(writer.Write()) << path;
}

// Scans `dir` and checks that the scan ends without an error, skips exactly `damaged`, by name,
// with a reason that contains `reasonPart`, and keeps the rest as one series of `framesLeft`
// frames. Callers wrap it in ASSERT_NO_FATAL_FAILURE when they go on to use `*scanOut`.
void expectOnlySkipped(const fs::path& dir, const fs::path& damaged, const std::string& reasonPart,
                       std::size_t framesLeft, dicom::DicomScan* scanOut = nullptr) {
  dicom::DicomScan scan;
  EXPECT_EQ(errorOf([&] { scan = dicom::scanDicom(dir); }, "scanDicom"), "");
  ASSERT_EQ(scan.skipped.size(), 1u);
  EXPECT_EQ(scan.skipped[0].path, damaged.string());
  EXPECT_NE(scan.skipped[0].reason.find(reasonPart), std::string::npos) << scan.skipped[0].reason;
  ASSERT_EQ(scan.series.size(), 1u);
  EXPECT_EQ(scan.series[0].frames.size(), framesLeft);
  if (scanOut) *scanOut = std::move(scan);
}

// Little-endian bytes of a 16- and a 32-bit value, and of a tag, for hand-made data sets.
std::string le16(uint16_t v) { return std::string{char(v & 0xff), char(v >> 8)}; }
std::string le32(uint32_t v) { return le16(uint16_t(v & 0xffff)) + le16(uint16_t(v >> 16)); }
std::string tag(uint16_t group, uint16_t element) { return le16(group) + le16(element); }

// Scans the DICOMDIR in `media` and checks that its records are given up with a warning naming
// `reason` ("DICOMDIR could not be parsed: ..."), and that the folder search then finds its one
// image, IMG1.
void expectDicomdirSearchedInstead(const fs::path& media, const std::string& reason) {
  dicom::DicomScan scan;
  EXPECT_EQ(errorOf([&] { scan = dicom::scanDicom(media / "DICOMDIR"); }, "scanDicom"), "");
  const auto& warnings = scan.warnings;
  const bool named = std::any_of(warnings.begin(), warnings.end(), [&](const std::string& w) {
    return w.find("DICOMDIR could not be parsed") != std::string::npos &&
           w.find(reason) != std::string::npos;
  });
  EXPECT_TRUE(named) << fmt::format("{}", fmt::join(warnings, "\n"));
  ASSERT_EQ(scan.series.size(), 1u);  // IMG1, found by the search
  ASSERT_EQ(scan.series[0].frames.size(), 1u);
  EXPECT_EQ(scan.series[0].frames[0].path, (media / "IMG1").string());
}

// Scans `dir` and checks that no file is skipped and that it holds one series of `frames` frames.
void expectNothingSkipped(const fs::path& dir, std::size_t frames) {
  dicom::DicomScan scan;
  EXPECT_EQ(errorOf([&] { scan = dicom::scanDicom(dir); }, "scanDicom"), "");
  for (const auto& skipped : scan.skipped) {
    ADD_FAILURE() << skipped.path << ": " << skipped.reason;
  }
  ASSERT_EQ(scan.series.size(), 1u);
  EXPECT_EQ(scan.series[0].frames.size(), frames);
}

TEST(BadInputDicom, NumberOfFramesBeyondThePixelDataIsRefusedBeforeAllocating) {
  const auto dir = test::freshTempDir("bad_dicom_frames");
  dicom::SyntheticSeriesSpec spec;
  spec.sliceCount = 6;
  const dicom::SyntheticSeries written = dicom::writeSyntheticSeries(dir, spec);
  const fs::path damaged = written.slices().front().path;
  // One billion frames of 16x16 int16: half a terabyte the file does not hold.
  rewriteElement(damaged, gdcm::Tag(0x0028, 0x0008), gdcm::VR::IS, "1000000000");

  expectOnlySkipped(dir, damaged, "1000000000 frames", 5);

  expectCleanError([&] { dicom::decodeDicomFile(damaged.string()); },
                   {damaged.string(), "1000000000 frames"}, "decodeDicomFile");
  for (const std::string bad : {"1e12", "-3", "2.5"}) {
    rewriteElement(damaged, gdcm::Tag(0x0028, 0x0008), gdcm::VR::IS, bad);
    const dicom::DicomScan again = dicom::scanDicom(dir);
    ASSERT_EQ(again.skipped.size(), 1u) << bad;
    EXPECT_NE(again.skipped[0].reason.find("invalid NumberOfFrames"), std::string::npos)
        << bad << ": " << again.skipped[0].reason;
  }
}

TEST(BadInputDicom, SliceSpacingThatWouldMakeMillionsOfSlicesIsRefused) {
  const auto dir = test::freshTempDir("bad_dicom_spacing");
  dicom::SyntheticSeriesSpec spec;
  spec.sliceCount = 8;
  spec.sliceSpacingMm = 1.25;
  dicom::writeSyntheticSeries(dir, spec);
  const dicom::DicomScan scan = dicom::scanDicom(dir);
  ASSERT_EQ(scan.series.size(), 1u);
  const dicom::DicomSeries& series = scan.series[0];
  const std::string first = series.frames.front().path;

  // 8.75 mm at 1e-6 mm: 8.75 million slices, which reading never finished.
  expectCleanError([&] { dicom::openDicomSeries(series, {1e-6}); },
                   {first, "--slice-spacing", "8750001 slices"}, "--slice-spacing 1e-6");
  expectCleanError([&] { dicom::resolveStack(series, {std::nan("")}); },
                   {first, "--slice-spacing", "not a finite number"}, "--slice-spacing nan");
  // Finer than the series but sane: accepted.
  EXPECT_EQ(dicom::resolveStack(series, {0.125}).outputSlices, 71);
}

// PixelSpacing 1e308 (or a position near 1e300) in every file: the stack is refused where it
// is formed, so --inspect, --export, -o, the viewer and the validator all refuse it (import
// used to write a store that octoray-validate then rejected).
TEST(BadInputDicom, HugeSpacingOrPositionIsRefusedWhereTheStackIsFormed) {
  for (const auto& [tag, vr, value] :
       {std::tuple{gdcm::Tag(0x0028, 0x0030), gdcm::VR::DS, std::string("1e308\\1e308")},
        std::tuple{gdcm::Tag(0x0020, 0x0032), gdcm::VR::DS, std::string("1e300\\0\\0")}}) {
    SCOPED_TRACE(value);
    const auto dir = test::freshTempDir("bad_dicom_huge");
    dicom::SyntheticSeriesSpec spec;
    spec.sliceCount = 4;
    const dicom::SyntheticSeries written = dicom::writeSyntheticSeries(dir, spec);
    for (const auto& image : written.slices()) rewriteElement(image.path, tag, vr, value);
    const dicom::DicomScan scan = dicom::scanDicom(dir);
    ASSERT_EQ(scan.series.size(), 1u);
    expectCleanError([&] { dicom::resolveStack(scan.series[0]); },
                     {scan.series[0].frames.front().path, "the geometry is not usable"}, "resolveStack");
  }
}

// A value length running past the end of the file is refused by name before GDCM sees the
// file: GDCM allocates and clears a buffer of the declared size first (1 GiB here, in a
// sequence item of a 1 KiB-header file; found by fuzz_dicomdir as a DICOMDIR). Without the
// check the file is skipped as unparsable after that allocation, with no length named.
TEST(BadInputDicom, LengthPastTheEndOfTheFileIsRefusedBeforeGdcmAllocates) {
  const auto dir = test::freshTempDir("bad_dicom_length");
  dicom::SyntheticSeriesSpec spec;
  spec.sliceCount = 6;
  const dicom::SyntheticSeries written = dicom::writeSyntheticSeries(dir, spec);
  const fs::path damaged = written.slices()[2].path;
  const std::string marker = "OCTORAYLENGTHMRK";  // 16 bytes, an OB value in an item
  {
    gdcm::Reader reader;
    reader.SetFileName(damaged.c_str());
    ASSERT_TRUE(reader.Read());
    gdcm::DataSet item;
    gdcm::DataElement creator(gdcm::Tag(0x0029, 0x0010));
    creator.SetVR(gdcm::VR::LO);
    creator.SetByteValue("OCTORAY ", 8);
    item.Insert(creator);
    gdcm::DataElement value(gdcm::Tag(0x0029, 0x1010));
    value.SetVR(gdcm::VR::OB);
    value.SetByteValue(marker.data(), static_cast<uint32_t>(marker.size()));
    item.Insert(value);
    gdcm::Item wrapped;
    wrapped.SetNestedDataSet(item);
    gdcm::SmartPointer<gdcm::SequenceOfItems> sequence = new gdcm::SequenceOfItems;
    sequence->AddItem(wrapped);
    gdcm::DataElement referenced(gdcm::Tag(0x0008, 0x1140));
    referenced.SetVR(gdcm::VR::SQ);
    referenced.SetValue(*sequence);
    reader.GetFile().GetDataSet().Replace(referenced);
    gdcm::Writer writer;
    writer.SetFileName(damaged.c_str());
    writer.SetFile(reader.GetFile());
    ASSERT_TRUE(writer.Write());
  }
  // The four bytes before the value are its length, in explicit and implicit VR alike.
  std::string bytes = readFile(damaged);
  const std::size_t at = bytes.find(marker);
  ASSERT_NE(at, std::string::npos);
  ASSERT_GE(at, 4u);
  const uint32_t length = uint32_t(1) << 30;
  std::memcpy(bytes.data() + at - 4, &length, 4);  // little endian, as the series is written
  writeFile(damaged, bytes);

  const std::string reason = "element (0029,1010) declares 1073741824 bytes but the file holds";
  expectOnlySkipped(dir, damaged, reason, 5);
  expectCleanError([&] { dicom::decodeDicomFile(damaged.string()); }, {damaged.string(), reason},
                   "decodeDicomFile");

  // The same bytes as a DICOMDIR: its records cannot be read, the folder is searched instead.
  const auto media = test::freshTempDir("bad_dicomdir_length");
  fs::copy_file(damaged, media / "DICOMDIR");
  fs::copy_file(written.slices()[0].path, media / "IMG1");
  expectDicomdirSearchedInstead(media, reason);
}

// A DICOMDIR without preamble or meta group whose first element carries a VR code: GDCM
// reads it as a bare data set, so the length walk must too. Found by fuzz_dicomdir: 100 bytes
// starting (0004,1200) UL, then an element without a VR code declaring 4 GiB, which GDCM
// allocated and cleared (a libFuzzer timeout and out-of-memory) because the walk had
// skipped every file not starting in group 0000, 0002 or 0008.
TEST(BadInputDicom, BareDicomdirWithAVrCodeIsWalkedForDeclaredLengths) {
  std::string bytes = tag(0x0004, 0x1200) + "UL" + le16(4) + le32(0) +  // offset of the first record
                      tag(0x0004, 0x1202) + "UL" + le16(4) + le32(0) +  // offset of the last record
                      tag(0x0004, 0x1400) + le32(uint32_t(1) << 30);    // no VR code: implicit, 1 GiB
  bytes += std::string(64, '\0');
  const std::string reason = "element (0004,1400) declares 1073741824 bytes but the file holds 64";

  const auto media = test::freshTempDir("bare_dicomdir_length");
  writeFile(media / "DICOMDIR", bytes);
  dicom::SyntheticSeriesSpec spec;
  spec.sliceCount = 2;
  const auto series = test::freshTempDir("bare_dicomdir_series");
  const dicom::SyntheticSeries written = dicom::writeSyntheticSeries(series, spec);
  fs::copy_file(written.slices()[0].path, media / "IMG1");
  expectDicomdirSearchedInstead(media, reason);
  const std::string file = (media / "DICOMDIR").string();
  expectCleanError([&] { dicom::decodeDicomFile(file); }, {file, reason}, "decodeDicomFile");

  // Bytes with no sign of DICOM are not walked, but the length GDCM reads first is checked:
  // 132 bytes starting (FF00,0000) made GDCM allocate the 1.7 GB their next four bytes say
  // (fuzz_dicomdir). Such files, and text, are refused as not DICOM, never as a damaged element.
  std::string junk = std::string("\0\xff\0\0??\0", 7) + std::string(124, 'i') + "\xbf";
  writeFile(media / "junk.bin", junk);
  writeFile(media / "notes.txt", "not an image, only notes about the study\n");
  for (const auto* name : {"junk.bin", "notes.txt"}) {
    const std::string path = (media / name).string();
    expectCleanError([&] { dicom::decodeDicomFile(path); }, {path, "not a DICOM file"}, name);
    EXPECT_EQ(errorOf([&] { dicom::decodeDicomFile(path); }, name).find("declares"), std::string::npos);
  }
}

// Two bytes where an explicit VR belongs that are no VR code: GDCM 3.0 reads two printable
// characters as UN (a 4-byte length after two reserved bytes), and on other bytes goes on from
// that element with its 16-bit reader (a 2-byte length after them). Both files below made GDCM
// (gdcmdump) allocate the 1 GiB they declare, seen under gdb in gdcm::ByteValue::SetLength;
// the walk had read both elements as implicit VR, whose lengths fit. Found by fuzz_dicomdir
// (project CI: a libFuzzer timeout on 161 bytes making GDCM allocate 1.16 GB, twice).
TEST(BadInputDicom, DeclaredLengthsAreWalkedAsGdcmReadsBytesThatAreNoVr) {
  const std::string head = tag(0x0008, 0x0005) + "CS" + le16(10) + "ISO_IR 100" +
                           tag(0x0008, 0x0020) + "DA" + le16(8) + "20261205";
  const std::string declares1GiB = std::string("\0\0", 2) + le32(uint32_t(1) << 30);
  // "XY" read as UN: 1 GiB. Read as implicit VR its length is 0x5958, which the file holds.
  const std::string printable =
      head + tag(0x0008, 0x1030) + "XY" + declares1GiB + std::string(24 * 1024, '\0');
  // (0008,1030) has no VR: GDCM's 16-bit reader finds a length of 0 and reads (0008,103E) "XY"
  // next, 1 GiB. Read as implicit VR, (0008,1030) is 16 bytes long and holds (0008,103E).
  const std::string noVr = head + tag(0x0008, 0x1030) + std::string("\x10\0\0\0", 4) +
                           tag(0x0008, 0x103e) + "XY" + declares1GiB + std::string(4 + 64, '\0');
  const auto dir = test::freshTempDir("lengths_no_vr");
  const std::vector<std::tuple<std::string, std::string, std::string>> files = {
      {"printable.dcm", printable, "(0008,1030)"}, {"no_vr.dcm", noVr, "(0008,103E)"}};
  for (const auto& [name, bytes, element] : files) {
    const std::string file = (dir / name).string();
    writeFile(file, bytes);
    const std::string reason = fmt::format("element {} declares 1073741824 bytes", element);
    expectCleanError([&] { dicom::decodeDicomFile(file); }, {file, reason}, name);
  }
  // pydicom's SC_rgb_jpeg.dcm: an implicit-VR body under a JPEG (explicit-VR) transfer syntax.
  // GDCM's 16-bit reading of it allocated 1.3 GB before it read the file another way (4.7 s).
  const fs::path rgb = test::pydicomTestFiles() / "SC_rgb_jpeg.dcm";
  if (!fs::exists(rgb)) GTEST_SKIP() << "skipped: " << rgb << " is absent (python3-pydicom)";
  expectCleanError([&] { dicom::decodeDicomFile(rgb.string()); },
                   {rgb.string(), "element (0008,0008) at byte 356 has no VR",
                    "element (4544,4952) declares 1329808723 bytes"},
                   "SC_rgb_jpeg.dcm");
}

// A file whose meta group is implicit VR (as old GE workstations wrote them): GDCM rereads the
// group its own way, never with its 16-bit reader, and reads the file; so must the walk, which
// follows that reader only from a body element with no VR (a review found it starting in the
// meta group; with the memory budget below which that reading is not refused, this file
// passed even so).
TEST(BadInputDicom, ImplicitMetaGroupIsNotWalkedAsGdcmsSixteenBitReading) {
  const auto dir = test::freshTempDir("implicit_meta");
  dicom::SyntheticSeriesSpec spec;
  spec.sliceCount = 4;
  spec.rows = spec.columns = 128;
  const dicom::SyntheticSeries written = dicom::writeSyntheticSeries(dir, spec);
  const fs::path file = written.slices()[1].path;
  std::string bytes = readFile(file);
  ASSERT_EQ(bytes.compare(128, 4, "DICM"), 0);
  // Each explicit meta element again as tag + 4-byte length + value.
  std::string meta;
  std::size_t at = 132;
  while (at + 8 <= bytes.size() && bytes[at] == 2 && bytes[at + 1] == 0) {
    const std::string vr = bytes.substr(at + 4, 2);
    const bool longLength = vr == "OB" || vr == "UN" || vr == "SQ" || vr == "UT";
    const std::size_t header = longLength ? 12 : 8;
    uint32_t length = 0;
    if (longLength) {
      std::memcpy(&length, bytes.data() + at + 8, 4);
    } else {
      uint16_t shortLength = 0;
      std::memcpy(&shortLength, bytes.data() + at + 6, 2);
      length = shortLength;
    }
    const bool groupLength = bytes[at + 2] == 0 && bytes[at + 3] == 0;
    if (!groupLength) meta += bytes.substr(at, 4) + le32(length) + bytes.substr(at + header, length);
    at += header + length;
  }
  ASSERT_GT(meta.size(), 40u);
  bytes = bytes.substr(0, 132) + tag(0x0002, 0x0000) + le32(4) + le32(uint32_t(meta.size())) + meta +
          bytes.substr(at);
  writeFile(file, bytes);
  expectNothingSkipped(dir, 4);
  EXPECT_EQ(errorOf([&] { dicom::decodeDicomFile(file.string()); }, "decodeDicomFile"), "");
}

// A DICOMDIR found by fuzz_dicomdir (kept in fuzz/regressions): explicit VR, an empty sequence
// followed by a bare item. GDCM's last reading of it, explicit/implicit, takes the item's length
// for a tag and the next tag for a 338 MB length, which it allocated and cleared for these
// 1,162 bytes (1 s here; 6 s under ASan, in the vetting child and again in the parent). The
// vetting child's address-space limit fails that allocation at once, and the file is refused
// without the parent parsing it. Under the sanitizers their allocator aborts the child instead.
TEST(BadInputDicom, FileGdcmWouldAllocateFarMoreThanItHoldsForIsRefused) {
  const fs::path source = fs::path(OCTORAY_SOURCE_DIR) /
                          "fuzz/regressions/fuzz_dicomdir/slow-5fdd5c33cab1bf7b4a7dec6715c9d4805b5e86c5";
  const auto dir = test::freshTempDir("bad_dicom_allocation");
  const fs::path file = dir / "DICOMDIR";
  fs::copy_file(source, file);
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
  const std::string reason = "the GDCM parser aborted on it";
#else
  const std::string reason =
      "the GDCM parser asked for more than the 128 MiB a file of 1162 bytes may take";
#endif
  const auto start = std::chrono::steady_clock::now();
  expectCleanError([&] { dicom::decodeDicomFile(file.string()); }, {file.string(), reason},
                   "decodeDicomFile");
#if !defined(__SANITIZE_ADDRESS__) && !defined(__SANITIZE_THREAD__)
  // GDCM's two reads of the file took 3.1 s with the allocation; without it 0.2 s, most of it
  // starting the vetting child.
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(), 1.0);
#else
  (void)start;
#endif
}

// Valid files the length walk must follow without refusing them (review of the walk): an
// explicit-VR file whose private UN of undefined length holds implicit-VR content (CP-246),
// with an implicit length whose low bytes spell a VR code ("DA"), read as explicit it would
// run into a value declaring 2 GiB; and an implicit-VR file whose pixel data starts with the
// bytes of an item tag and a 2 GiB item length (pixel data is never a sequence).
TEST(BadInputDicom, DeclaredLengthsFollowImplicitContentAndPixelDataLikeAnItem) {
  {
    const auto dir = test::freshTempDir("lengths_un_implicit");
    dicom::SyntheticSeriesSpec spec;
    spec.sliceCount = 6;
    const dicom::SyntheticSeries written = dicom::writeSyntheticSeries(dir, spec);
    const fs::path file = written.slices()[2].path;
    std::string bytes = readFile(file);
    std::string value(16708, '\0');  // 0x4144: "DA" in its two low bytes
    const std::string trap = std::string("\xff\xff\xff\x7f", 4) + "OB" + std::string(2, '\0') +
                             le32(0x7fffffff);
    value.replace(0, trap.size(), trap);
    bytes += tag(0x7fe1, 0x0010) + "LO" + le16(8) + "OCTORAY ";
    bytes += tag(0x7fe1, 0x1010) + "UN" + std::string(2, '\0') + le32(0xffffffff);
    bytes += tag(0xfffe, 0xe000) + le32(0xffffffff);
    bytes += tag(0x0008, 0x0100) + le32(16708) + value;  // implicit VR
    bytes += tag(0xfffe, 0xe00d) + le32(0) + tag(0xfffe, 0xe0dd) + le32(0);
    writeFile(file, bytes);
    expectNothingSkipped(dir, 6);
    EXPECT_EQ(errorOf([&] { dicom::decodeDicomFile(file.string()); }, "decodeDicomFile"), "");
  }
  {
    const auto dir = test::freshTempDir("lengths_pixels_like_item");
    dicom::SyntheticSeriesSpec spec;
    spec.sliceCount = 6;
    spec.transferSyntax = dicom::SyntheticTransferSyntax::ImplicitVRLittleEndian;
    const dicom::SyntheticSeries written = dicom::writeSyntheticSeries(dir, spec);
    const fs::path file = written.slices()[2].path;
    std::string bytes = readFile(file);
    const std::size_t at = bytes.rfind(tag(0x7fe0, 0x0010));
    ASSERT_NE(at, std::string::npos);
    bytes.replace(at + 8, 8, tag(0xfffe, 0xe000) + le32(0x7fffffff));
    writeFile(file, bytes);
    expectNothingSkipped(dir, 6);
    EXPECT_EQ(errorOf([&] { dicom::decodeDicomFile(file.string()); }, "decodeDicomFile"), "");
  }
}

// A file whose data set is two empty elements of group 0000, the first with no valid VR and
// the second cut off after its tag (found by fuzz_dicomdir): GDCM's full read accepts it, its
// header read (ReadUpToTag) switches to its explicit/implicit element reader and asserts on
// the missing VR, which aborted the whole process. The vetter now parses the file the ways
// the scanner does, and the file is skipped by name while the rest of the series loads.
TEST(BadInputDicom, FileOnlyGdcmsHeaderReadAbortsOnIsSkippedByName) {
  const auto dir = test::freshTempDir("bad_dicom_header_read_aborts");
  dicom::SyntheticSeriesSpec spec;
  spec.sliceCount = 6;
  const dicom::SyntheticSeries written = dicom::writeSyntheticSeries(dir, spec);
  const fs::path damaged = written.slices()[3].path;
  std::string bytes = readFile(damaged);
  // Preamble, "DICM", (0002,0000) UL 4 and the meta group it measures; the data set replaced.
  ASSERT_GE(bytes.size(), 144u);
  ASSERT_EQ(bytes.substr(128, 4), "DICM");
  ASSERT_EQ(bytes.substr(132, 6), std::string("\x02\x00\x00\x00UL", 6));
  uint32_t metaLength = 0;
  std::memcpy(&metaLength, bytes.data() + 140, 4);
  ASSERT_LE(144u + metaLength, bytes.size());
  bytes.resize(144u + metaLength);
  bytes += std::string(12, '\0') + "O";
  writeFile(damaged, bytes);

  expectOnlySkipped(dir, damaged, "the GDCM parser aborted on it", 5);
}

// A file GDCM takes too long on is refused as a hang, by name, and the rest of the folder
// loads. A valid image with a private sequence of 1.5 million small items stands in for a file
// GDCM hangs on: GDCM's ImageReader took 3.9 s on a million such items here (Release), above
// the 2 s limit set below. A second look at the same file (a
// DICOMDIR walk, then the header read) is refused at once instead of waiting again, a touched
// file is parsed again, and a limit that is not a usable number of seconds is named rather
// than ignored. Starting the vetting children (seconds under the sanitizers) is not counted
// against the limit, so the deadline of each call is generous: the limit is what is checked.
TEST(BadInputDicom, FileGdcmDoesNotFinishInTimeIsRefusedByNameOnce) {
  const auto dir = test::freshTempDir("bad_dicom_parse_timeout");
  dicom::SyntheticSeriesSpec spec;
  spec.sliceCount = 5;
  const dicom::SyntheticSeries written = dicom::writeSyntheticSeries(dir, spec);
  const fs::path slow = dir / "slow.dcm";
  {
    std::string bytes = readFile(written.slices()[4].path);
    fs::remove(written.slices()[4].path);
    const std::string item =
        tag(0xfffe, 0xe000) + le32(12) + tag(0x0008, 0x0100) + "SH" + le16(4) + "ABCD";
    bytes += tag(0x7fe1, 0x0010) + "LO" + le16(8) + "OCTORAY ";
    bytes += tag(0x7fe1, 0x1010) + "SQ" + std::string(2, '\0') + le32(0xffffffff);
    bytes.reserve(bytes.size() + 1'500'000 * item.size() + 8);
    for (int i = 0; i < 1'500'000; ++i) bytes += item;
    bytes += tag(0xfffe, 0xe0dd) + le32(0);
    writeFile(slow, bytes);
  }
  using Clock = std::chrono::steady_clock;
  const auto secondsSince = [](Clock::time_point start) {
    return std::chrono::duration<double>(Clock::now() - start).count();
  };
  const auto patientOf = [](const fs::path& file) {
    return errorOf([&] { (void)dicom::readPatientIdentity(file.string()); }, "readPatientIdentity", 60s);
  };

  ASSERT_EQ(::setenv("OCTORAY_DICOM_PARSE_TIMEOUT", "2", 1), 0);
  dicom::DicomScan scan;
  EXPECT_EQ(errorOf([&] { scan = dicom::scanDicom(dir); }, "scanDicom", 60s), "");
  ASSERT_EQ(scan.skipped.size(), 1u);
  EXPECT_EQ(scan.skipped[0].path, slow.string());
  EXPECT_EQ(scan.skipped[0].reason,
            "the GDCM parser did not finish reading it in 2 s (OCTORAY_DICOM_PARSE_TIMEOUT sets the limit)");
  ASSERT_EQ(scan.series.size(), 1u);
  EXPECT_EQ(scan.series[0].frames.size(), 4u);

  auto start = Clock::now();
  const std::string again = patientOf(slow);
  EXPECT_LT(secondsSince(start), 1.0) << "the second look waited for the parser again";
  EXPECT_NE(again.find(slow.string()), std::string::npos) << again;
  EXPECT_NE(again.find("did not finish reading it in 2 s"), std::string::npos) << again;

  fs::last_write_time(slow, fs::last_write_time(slow) + 1s);
  start = Clock::now();
  const std::string touched = patientOf(slow);
  EXPECT_GE(secondsSince(start), 2.0) << "a touched file was refused from memory";
  EXPECT_NE(touched.find("did not finish reading it in 2 s"), std::string::npos) << touched;

  const fs::path image = written.slices()[0].path;
  for (const char* bad : {"0", "-3", "abc", "1.5s", " 2", "nan", "inf", "1e-9"}) {
    ASSERT_EQ(::setenv("OCTORAY_DICOM_PARSE_TIMEOUT", bad, 1), 0);
    const std::string message = patientOf(image);
    EXPECT_NE(message.find(image.string()), std::string::npos) << message;
    EXPECT_NE(message.find(fmt::format("OCTORAY_DICOM_PARSE_TIMEOUT is '{}', not a number of seconds", bad)),
              std::string::npos) << message;
  }
  ASSERT_EQ(::setenv("OCTORAY_DICOM_PARSE_TIMEOUT", "0.001", 1), 0);  // the smallest accepted
  EXPECT_EQ(patientOf(slow).find("not a number of seconds"), std::string::npos);
  ASSERT_EQ(::unsetenv("OCTORAY_DICOM_PARSE_TIMEOUT"), 0);
  EXPECT_EQ(patientOf(image), "");
}

// One image whose orientation differs is split off into another part of the series; the
// volume built from the main part names it.
TEST(BadInputDicom, ImageSplitOffFromTheSeriesIsNamed) {
  const auto dir = test::freshTempDir("bad_dicom_split");
  dicom::SyntheticSeriesSpec spec;
  spec.sliceCount = 6;
  const dicom::SyntheticSeries written = dicom::writeSyntheticSeries(dir, spec);
  const fs::path odd = written.slices()[3].path;
  rewriteElement(odd, gdcm::Tag(0x0020, 0x0037), gdcm::VR::DS, "1\\0\\0\\0\\0\\1");
  const dicom::DicomScan scan = dicom::scanDicom(dir);
  ASSERT_EQ(scan.series.size(), 2u);
  const std::size_t chosen = dicom::defaultSeriesIndex(scan, dir.string());
  EXPECT_EQ(scan.series[chosen].frames.size(), 5u);
  const std::vector<std::string> warnings = dicom::filesLeftOut(scan, chosen);
  ASSERT_EQ(warnings.size(), 1u);
  EXPECT_NE(warnings[0].find(odd.string()), std::string::npos) << warnings[0];
  EXPECT_NE(warnings[0].find("differ in orientation"), std::string::npos) << warnings[0];
}

// RescaleSlope 0 turns every pixel into the intercept, NaN every pixel into NaN: the file is
// refused by name (and the volume built without it says a slice is missing), never read as a
// silently flat or NaN slice.
TEST(BadInputDicom, UnusableRescaleRefusesTheFileByName) {
  for (const auto& [tag, value, mention] :
       {std::tuple{gdcm::Tag(0x0028, 0x1053), std::string("0"), std::string("RescaleSlope is 0")},
        std::tuple{gdcm::Tag(0x0028, 0x1053), std::string("NaN"), std::string("not a finite number")},
        std::tuple{gdcm::Tag(0x0028, 0x1052), std::string("inf"), std::string("not a finite number")}}) {
    SCOPED_TRACE(value);
    const auto dir = test::freshTempDir("bad_dicom_rescale");
    dicom::SyntheticSeriesSpec spec;
    spec.sliceCount = 6;
    const dicom::SyntheticSeries written = dicom::writeSyntheticSeries(dir, spec);
    const fs::path damaged = written.slices()[2].path;
    rewriteElement(damaged, tag, gdcm::VR::DS, value);
    dicom::DicomScan scan;
    ASSERT_NO_FATAL_FAILURE(expectOnlySkipped(dir, damaged, mention, 5, &scan));
    const auto source = dicom::openDicomSeries(scan.series[0], {});
    const auto& warnings = source->info().warnings;
    EXPECT_TRUE(std::any_of(warnings.begin(), warnings.end(),
                            [](const std::string& w) { return w.find("missing") != std::string::npos; }));
  }
}

}  // namespace
}  // namespace octoray
