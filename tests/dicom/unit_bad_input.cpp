// Bad input found by a black-box sweep (issue 14): each case must end in one octoray::Error
// naming the file and the problem, quickly, with nothing else on stderr. Every call runs under
// a deadline, so a regression to a hang fails instead of stalling the suite.
//
// This file: NIfTI, MetaImage and NRRD headers, damaged TIFF pages, and DICOM series whose frames,
// geometry or rescale cannot make a volume. unit_bad_input_dicom_parsing.cpp: DICOM files that must
// not reach GDCM's parser, or not for long (declared lengths, bytes that are no VR, the vetting
// child's memory and time limits).

#include <gdcmReader.h>
#include <gdcmWriter.h>
#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include <tuple>

#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>

#include <fmt/format.h>

#include "bad_input_helpers.h"
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
using namespace bad_input_test;
using namespace formats_test;
using namespace std::chrono_literals;

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
  // A negative spacing keeps the geometry as written (x runs against its direction) and says
  // so: ITK does not support it.
  writeFile(dir / "negative.mhd", header(ok + "ElementSpacing = -1 0.5 0.5\n"));
  auto negative = openMetaImage((dir / "negative.mhd").string());
  expectAffineNear(negative->info().patientFromIndex,
                   Mat4::fromColumns({-1, 0, 0}, {0, 0.5, 0}, {0, 0, 0.5}, {0, 0, 0}), 1e-12);
  EXPECT_EQ(negative->info().warnings,
            std::vector<std::string>{"ElementSpacing -1 0.5 0.5 has a negative value: each such "
                                     "index axis runs against its TransformMatrix direction"});
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

// ---- TIFF -----------------------------------------------------------------------------------

// A 64 x 64 grey page in one strip, made by hand (tiffBytes puts the IFD before the samples, so
// cutting the file cuts samples, not the directory). `changes` replace or add tags.
std::string tiffPage(const std::vector<TiffEntry>& changes, std::string samples = {}) {
  std::vector<TiffEntry> tags = {{256, 4, {64}}, {257, 4, {64}}, {258, 3, {16}}, {259, 3, {1}},
                                 {262, 3, {1}},  {277, 3, {1}},  {278, 4, {64}}};
  for (const auto& change : changes) {
    const auto at = std::find_if(tags.begin(), tags.end(),
                                 [&](const TiffEntry& t) { return t.tag == change.tag; });
    if (at != tags.end()) {
      *at = change;
    } else {
      tags.push_back(change);
    }
  }
  if (samples.empty()) samples.assign(64 * 64 * 2, '\x11');
  return tiffBytes(tags, {samples}, false, false);
}

// libtiff reports a damaged page through the handle octoray opens it with: one octoray::Error
// names the file and the problem, and nothing reaches stderr. (Read through OpenCV, a damaged
// strip printed two lines of OpenCV's own before the error.)
TEST(BadInputTiff, DamagedPagesEndInOneMessageNamingTheFile) {
  const auto dir = test::freshTempDir("bad_tiff");
  const auto readAll = [](const fs::path& path) {
    auto source = openTiffStack(path.string());
    std::vector<float> all(
        static_cast<std::size_t>(source->info().sliceSamples() * source->info().dims[2]));
    source->readSlab(0, source->info().dims[2], all);
  };
  const auto expectRefused = [&](const std::string& name, const std::string& bytes,
                                 const std::vector<std::string>& mentions) {
    writeFile(dir / name, bytes);
    expectCleanError([&] { readAll(dir / name); }, mentions, name);
  };

  // A stack whose second file is cut 100 bytes short inside its samples; and cut shorter than
  // its samples could be.
  fs::create_directories(dir / "cut");
  writeFile(dir / "cut" / "s000.tif", tiffPage({}));
  const std::string whole = tiffPage({});
  writeFile(dir / "cut" / "s001.tif", whole.substr(0, whole.size() - 100));
  expectCleanError(
      [&] { readAll(dir / "cut"); },
      {"s001.tif: cannot decode the strip of rows 0 to 63: Read error; got 8092 bytes, expected "
       "8192"},
      "stack cut short");
  writeFile(dir / "cut" / "s001.tif", whole.substr(0, whole.size() - 3000));
  expectCleanError([&] { readAll(dir / "cut"); },
                   {"s001.tif: declares 64x64 uncompressed samples of 2 bytes (8192 bytes), but "
                    "the file holds 5314 bytes"},
                   "stack cut shorter");

  expectRefused("deflate.tif", tiffPage({{259, 3, {8}}}, std::string(100, '\x5A')),
                {"deflate.tif: cannot decode the strip of rows 0 to 63"});
  expectRefused("junk.tif", std::string("II*\0garbage", 11), {"junk.tif: not a readable TIFF"});
  expectRefused("codec.tif", tiffPage({{259, 3, {60000}}}),
                {"codec.tif: uses compression 60000, which this build of libtiff cannot decode"});
  expectRefused("palette.tif",
                tiffPage({{258, 3, {8}}, {262, 3, {3}}, {320, 3, std::vector<uint32_t>(768, 0)}},
                         std::string(64 * 64, '\x01')),
                {"palette.tif: has photometric interpretation 3 (a palette)"});
  expectRefused("bits12.tif", tiffPage({{258, 3, {12}}}, std::string(64 * 64 * 3 / 2, '\x01')),
                {"bits12.tif: unsupported sample type (12 bits"});
  // Declared sizes are refused before they size anything: a page over 2^30 pixels; an
  // uncompressed page larger than its file; a strip over 1 GiB.
  const auto sized = [](uint32_t side, uint32_t compression) {
    return tiffPage(
        {{256, 4, {side}}, {257, 4, {side}}, {278, 4, {side}}, {259, 3, {compression}}});
  };
  expectRefused("huge.tif", sized(100000, 8),
                {"huge.tif: is 100000x100000 pixels, more than the 1073741824 a page may have"});
  expectRefused("large.tif", sized(30000, 1),
                {"large.tif: declares 30000x30000 uncompressed samples of 2 bytes (1800000000 "
                 "bytes), but the file holds 8314 bytes"});
  expectRefused("large-deflate.tif", sized(30000, 8),
                {"large-deflate.tif: a strip of 1716 MiB is more than the 1024 MiB decoded at "
                 "once"});

  // A multi-page file whose first page points past the file's end for the next.
  std::vector<cv::Mat> pages(3, cv::Mat(8, 8, CV_16U, cv::Scalar(7)));
  ASSERT_TRUE(cv::imwrite((dir / "chain.tif").string(), pages));
  std::string chain = readFile(dir / "chain.tif");
  ASSERT_EQ(chain.substr(0, 2), "II");
  uint32_t ifd = 0;
  uint16_t entries = 0;
  std::memcpy(&ifd, chain.data() + 4, 4);
  std::memcpy(&entries, chain.data() + ifd, 2);
  const uint32_t past = static_cast<uint32_t>(chain.size()) + 1000;
  std::memcpy(chain.data() + ifd + 2 + 12 * entries, &past, 4);
  expectRefused("chain.tif", chain, {"chain.tif: the chain of pages is damaged"});
  // The first page points back to itself: libtiff counts one page and only warns; the two
  // pages after it are not silently dropped.
  std::string loop = chain;
  std::memcpy(loop.data() + ifd + 2 + 12 * entries, &ifd, 4);
  expectRefused("loop.tif", loop,
                {"loop.tif: the chain of pages is damaged: TIFF directory 0 has IFD looping"});
}

// ---- DICOM ----------------------------------------------------------------------------------

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

// Geometry attributes that are present but not numbers: the series has no geometry, and the
// import says which attribute and why (it said only "no volumetric image series found"). Where
// no series is found at all, the first file left out is named with its reason.
TEST(BadInputDicom, UnusableGeometryOrAnUnreadableFileIsNamedWhereNoVolumeIsFound) {
  for (const auto& [tag, value, said] :
       {std::tuple{gdcm::Tag(0x0028, 0x0030), std::string("nan\\nan"),
                   std::string("PixelSpacing 'nan\\nan' is not 2 finite numbers")},
        std::tuple{gdcm::Tag(0x0020, 0x0037), std::string("1\\0\\0\\0\\1"),
                   std::string("ImageOrientationPatient '1\\0\\0\\0\\1' is not 6 finite "
                               "numbers")}}) {
    SCOPED_TRACE(value);
    const auto dir = test::freshTempDir("bad_dicom_geometry");
    dicom::SyntheticSeriesSpec spec;
    spec.sliceCount = 4;
    const dicom::SyntheticSeries written = dicom::writeSyntheticSeries(dir, spec);
    for (const auto& image : written.slices()) rewriteElement(image.path, tag, gdcm::VR::DS, value);
    expectCleanError([&] { openVolume(dir.string()); },
                     {dir.string() +
                      ": no volumetric image series found (1 series, 0 files "
                      "skipped): series 1 is no-geometry (" +
                      said + ")"},
                     value);
  }
  const auto dir = test::freshTempDir("bad_dicom_one_file");
  dicom::SyntheticSeriesSpec spec;
  spec.sliceCount = 1;
  const dicom::SyntheticSeries written = dicom::writeSyntheticSeries(dir, spec);
  const std::string path = written.slices().front().path;
  const std::string bytes = readFile(path);
  writeFile(path, bytes.substr(0, bytes.size() - 100));
  expectCleanError([&] { dicom::defaultSeriesIndex(dicom::scanDicom(path), path); },
                   {"(0 series, 1 files skipped): " + fs::path(path).filename().string() +
                    ": pixel data declares 512 bytes but the file holds 412 after it"},
                   "a truncated file");
}

// A DICOM folder with a preview TIFF beside its images is DICOM; with its images all damaged,
// it keeps its DICOM error (not a one-slice TIFF "volume" of the preview).
TEST(BadInputDicom, PreviewTiffBesideDicomImagesIsNotTheVolume) {
  const auto dir = test::freshTempDir("dicom_with_preview");
  dicom::SyntheticSeriesSpec spec;
  spec.sliceCount = 4;
  const dicom::SyntheticSeries written = dicom::writeSyntheticSeries(dir, spec);
  ASSERT_TRUE(cv::imwrite((dir / "preview.tif").string(), cv::Mat(8, 8, CV_8U, cv::Scalar(9))));
  EXPECT_EQ(openVolume(dir.string())->info().format, "dicom");
  for (const auto& image : written.slices()) {
    const std::string bytes = readFile(image.path);
    writeFile(image.path, bytes.substr(0, bytes.size() - 100));
  }
  expectCleanError([&] { openVolume(dir.string()); },
                   {dir.string() + ": no DICOM image series found"}, "damaged, with a preview");
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

// 16-bit pixel data under BitsAllocated 8: decoded as 8-bit samples it would be a slice of
// garbage. BitsStored above BitsAllocated says so; where BitsStored and HighBit are made
// consistent too, the pixel data's length (twice what 8 bits fill) still does.
TEST(BadInputDicom, BitsAllocatedThatDoesNotDescribeThePixelDataIsRefused) {
  const auto dir = test::freshTempDir("bad_dicom_bits");
  dicom::SyntheticSeriesSpec spec;
  spec.sliceCount = 3;
  const dicom::SyntheticSeries written = dicom::writeSyntheticSeries(dir, spec);
  const fs::path damaged = written.slices()[1].path;
  rewriteElement(damaged, gdcm::Tag(0x0028, 0x0100), gdcm::VR::US, le16(8));
  expectCleanError([&] { dicom::decodeDicomFile(damaged.string()); },
                   {damaged.string(), "exceeds BitsAllocated 8"}, "decodeDicomFile");
  rewriteElement(damaged, gdcm::Tag(0x0028, 0x0101), gdcm::VR::US, le16(8));
  rewriteElement(damaged, gdcm::Tag(0x0028, 0x0102), gdcm::VR::US, le16(7));
  expectCleanError([&] { dicom::decodeDicomFile(damaged.string()); },
                   {damaged.string(), "the header does not describe the data"}, "decodeDicomFile");
  EXPECT_NO_THROW(dicom::decodeDicomFile(written.slices()[0].path.string()));
  // A sign that is neither, or a high bit beyond the allocated bits: refused by name (both
  // were read, the first as unsigned samples).
  const fs::path sign = written.slices()[2].path;
  rewriteElement(sign, gdcm::Tag(0x0028, 0x0103), gdcm::VR::US, le16(7));
  expectCleanError([&] { dicom::decodeDicomFile(sign.string()); },
                   {sign.string(), "PixelRepresentation 7 is neither 0 (unsigned) nor 1 (signed)"},
                   "PixelRepresentation");
  rewriteElement(sign, gdcm::Tag(0x0028, 0x0103), gdcm::VR::US, le16(1));
  rewriteElement(sign, gdcm::Tag(0x0028, 0x0102), gdcm::VR::US, le16(40));
  expectCleanError([&] { dicom::decodeDicomFile(sign.string()); },
                   {sign.string(), "HighBit 40 is outside BitsAllocated 16"}, "HighBit");
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
