// Raw, NRRD and MetaImage inputs: exact round trips from known functions, oblique geometry,
// and bad input that must give octoray::Error naming the file, never a crash. (NIfTI, export,
// TIFF and openVolume are in unit_formats_nifti_tiff.cpp.)

#include <gtest/gtest.h>

#include <filesystem>

#include <fmt/format.h>

#include "format_test_helpers.h"
#include "octoray/core/error.h"
#include "octoray/dicom/formats.h"
#include "test_paths.h"

namespace octoray {
namespace {

namespace fs = std::filesystem;
using namespace formats_test;

// ---- sample types and raw volumes -----------------------------------------------------------

TEST(FormatsSampleType, ParsesOwnNrrdAndMetaImageSpellings) {
  EXPECT_EQ(parseSampleType("uint8"), SampleType::UInt8);
  EXPECT_EQ(parseSampleType("signed char"), SampleType::Int8);
  EXPECT_EQ(parseSampleType("unsigned short"), SampleType::UInt16);
  EXPECT_EQ(parseSampleType(" short "), SampleType::Int16);
  EXPECT_EQ(parseSampleType("MET_SHORT"), SampleType::Int16);
  EXPECT_EQ(parseSampleType("MET_ULONG"), SampleType::UInt32);
  EXPECT_EQ(parseSampleType("int"), SampleType::Int32);
  EXPECT_EQ(parseSampleType("Float32"), SampleType::Float32);
  EXPECT_EQ(parseSampleType("double"), SampleType::Float64);
  EXPECT_THROW(parseSampleType("int64"), Error);
  EXPECT_THROW(parseSampleType(""), Error);
  EXPECT_EQ(sampleBytes(SampleType::Int8), 1u);
  EXPECT_EQ(sampleBytes(SampleType::UInt16), 2u);
  EXPECT_EQ(sampleBytes(SampleType::Float32), 4u);
  EXPECT_EQ(sampleBytes(SampleType::Float64), 8u);
}

TEST(RawVolume, EveryTypeAndByteOrderRoundTripsExactly) {
  const auto dir = test::freshTempDir("raw_round_trip");
  const std::array<int64_t, 3> sizes[] = {{1, 1, 1}, {33, 17, 5}, {3, 2, 7}};
  for (SampleType type : kAllTypes) {
    for (bool bigEndian : {false, true}) {
      for (const auto& dims : sizes) {
        const uint64_t headerBytes = dims[0] == 33 ? 13 : 0;
        const auto file =
            dir / fmt::format("v{}_{}_{}.raw", static_cast<int>(type), bigEndian, dims[0]);
        writeFile(file, std::string(headerBytes, 'H') + encodeAs(type, dims, bigEndian));
        RawOptions options;
        options.dims = dims;
        options.sampleType = type;
        options.bigEndian = bigEndian;
        options.headerBytes = headerBytes;
        options.spacingMm = {0.5, 0.75, 2};
        options.originMm = {-10, 20, 30};
        auto source = openRawVolume(file.string(), options);
        const VolumeInfo& info = source->info();
        EXPECT_EQ(info.dims, dims);
        EXPECT_EQ(info.format, "raw");
        EXPECT_EQ(info.integerValues, type != SampleType::Float32 && type != SampleType::Float64);
        EXPECT_EQ(info.patientFromIndex.m[1][1], 0.75);
        EXPECT_EQ(info.patientFromIndex.m[0][3], -10);
        SCOPED_TRACE(file.string());
        for (int64_t slab : {1, 2, 3, 1000}) {
          expectValues(*source, slab,
                       [&](int64_t i, int64_t j, int64_t k) { return expectedAs(type, i, j, k); });
        }
      }
    }
  }
}

TEST(RawVolume, ReadsSlabsInAnyOrder) {
  const auto dir = test::freshTempDir("raw_any_order");
  const std::array<int64_t, 3> dims{5, 4, 9};
  writeFile(dir / "v.raw", encode<int16_t>(dims, false));
  RawOptions options;
  options.dims = dims;
  auto source = openRawVolume((dir / "v.raw").string(), options);
  for (int64_t first : {8, 0, 5, 2, 7}) {
    std::vector<float> slab(20 * 2);
    const int64_t count = std::min<int64_t>(2, 9 - first);
    slab.resize(static_cast<std::size_t>(20 * count));
    source->readSlab(first, count, slab);
    for (int64_t n = 0; n < 20 * count; ++n) {
      ASSERT_EQ(slab[static_cast<std::size_t>(n)],
                typedValue<int16_t>(n % 5, (n / 5) % 4, first + n / 20));
    }
  }
}

// More data than the dimensions and type need: read, but said (a wrong --raw-type or a slice
// count too small would otherwise pass unnoticed); exactly enough says nothing.
TEST(RawVolume, DataBeyondTheVolumeIsAWarning) {
  const auto dir = test::freshTempDir("raw_longer");
  const std::array<int64_t, 3> dims{5, 4, 9};
  writeFile(dir / "v.raw", encode<int16_t>(dims, false));
  RawOptions options;
  options.dims = dims;
  EXPECT_TRUE(openRawVolume((dir / "v.raw").string(), options)->info().warnings.empty());
  options.sampleType = SampleType::UInt8;
  auto bytes = openRawVolume((dir / "v.raw").string(), options);
  ASSERT_EQ(bytes->info().warnings.size(), 1u);
  EXPECT_EQ(bytes->info().warnings[0],
            (dir / "v.raw").string() + " holds 360 bytes of data, the volume needs 180: the rest is "
                                       "ignored (are the dimensions and the sample type right?)");
}

TEST(RawVolume, TruncatedFileNamesFileAndSizes) {
  const auto dir = test::freshTempDir("raw_truncated");
  const auto file = dir / "short.raw";
  writeFile(file, std::string(100, 'x'));
  RawOptions options;
  options.dims = {10, 10, 2};
  options.headerBytes = 16;
  expectErrorMentioning([&] { openRawVolume(file.string(), options); }, file.string());
  expectErrorMentioning([&] { openRawVolume(file.string(), options); },
                        "expected 400 bytes of data after a 16-byte header, file has 100");
}

TEST(RawVolume, BadRequestsAndOptionsThrow) {
  const auto dir = test::freshTempDir("raw_bad");
  writeFile(dir / "v.raw", encode<uint8_t>({4, 4, 4}, false));
  RawOptions options;
  options.dims = {4, 4, 4};
  options.sampleType = SampleType::UInt8;
  auto source = openRawVolume((dir / "v.raw").string(), options);
  std::vector<float> slab(16);
  EXPECT_THROW(source->readSlab(4, 1, slab), Error);
  EXPECT_THROW(source->readSlab(-1, 1, slab), Error);
  EXPECT_THROW(source->readSlab(0, 2, slab), Error);  // buffer too small
  RawOptions bad = options;
  bad.dims = {4, 0, 4};
  EXPECT_THROW(openRawVolume((dir / "v.raw").string(), bad), Error);
  bad = options;
  bad.dims = {int64_t{1} << 40, int64_t{1} << 40, 4};
  EXPECT_THROW(openRawVolume((dir / "v.raw").string(), bad), Error);
  bad = options;
  bad.spacingMm = {1, 0, 1};
  EXPECT_THROW(openRawVolume((dir / "v.raw").string(), bad), Error);
  EXPECT_THROW(openRawVolume((dir / "missing.raw").string(), options), Error);
}

// ---- NRRD -----------------------------------------------------------------------------------

std::string nrrdHeader(const std::string& type, const std::array<int64_t, 3>& dims,
                       const std::string& extra) {
  return fmt::format("NRRD0004\n# written by the test\ntype: {}\ndimension: 3\nsizes: {} {} {}\n{}",
                     type, dims[0], dims[1], dims[2], extra);
}

TEST(NrrdFormat, AttachedObliqueBigEndianShort) {
  const auto dir = test::freshTempDir("nrrd_oblique");
  // Small first axis (5): vtkNrrdReader would take it for vector components.
  for (const std::array<int64_t, 3> dims : {std::array<int64_t, 3>{5, 4, 3}, {11, 6, 2}}) {
    const auto file = dir / fmt::format("v{}.nrrd", dims[0]);
    writeFile(file, nrrdHeader("short", dims,
                               "space: left-posterior-superior\n"
                               "space directions: (0.6,0.8,0) (-1.6,1.2,0) (0,0,2.5)\n"
                               "kinds: domain domain domain\nendian: big\nencoding: raw\n"
                               "space origin: (10,-20,30.5)\n\n") +
                        encode<int16_t>(dims, true));
    auto source = openNrrd(file.string());
    const VolumeInfo& info = source->info();
    EXPECT_EQ(info.dims, dims);
    EXPECT_EQ(info.format, "nrrd");
    EXPECT_EQ(info.description, file.filename().string());
    EXPECT_TRUE(info.integerValues);
    const Mat4 expected =
        Mat4::fromColumns({0.6, 0.8, 0}, {-1.6, 1.2, 0}, {0, 0, 2.5}, {10, -20, 30.5});
    expectAffineNear(info.patientFromIndex, expected, 1e-12);
    expectValues(*source, 2, [](int64_t i, int64_t j, int64_t k) {
      return static_cast<float>(typedValue<int16_t>(i, j, k));
    });
  }
}

// NRRD's 'sample units' field: Hounsfield units (any case, quoted or not) make the volume CT;
// another unit is named in a warning and the values stay unlabelled; without it, nothing.
TEST(NrrdFormat, SampleUnitsInHounsfieldMakeTheVolumeCt) {
  const auto dir = test::freshTempDir("nrrd_sample_units");
  const std::array<int64_t, 3> dims{4, 3, 2};
  const auto open = [&](const std::string& name, const std::string& extra) {
    writeFile(dir / name, nrrdHeader("short", dims, extra + "space: LPS\nspace directions: (1,0,0) (0,1,0) (0,0,1)\n"
                                                            "endian: little\nencoding: raw\n\n") +
                              encode<int16_t>(dims, false));
    return openNrrd((dir / name).string());
  };
  for (const std::string units : {"HU", "hu", "\"HU\"", "Hounsfield Units"}) {
    const auto source = open("hu.nrrd", "sample units: " + units + "\n");
    EXPECT_EQ(source->info().unit, "HU") << units;
    EXPECT_TRUE(source->info().warnings.empty()) << units << ": " << source->info().warnings.front();
  }
  const auto other = open("mu.nrrd", "sample units: 1/cm\n");
  EXPECT_EQ(other->info().unit, "");
  ASSERT_EQ(other->info().warnings.size(), 1u);
  EXPECT_EQ(other->info().warnings[0],
            "sample units '1/cm' are not Hounsfield units: the values are shown as they are, not as CT");
  const auto none = open("none.nrrd", "");
  EXPECT_EQ(none->info().unit, "");
}

TEST(NrrdFormat, RasSpaceIsConvertedToLps) {
  const auto dir = test::freshTempDir("nrrd_ras");
  const std::array<int64_t, 3> dims{12, 3, 2};
  writeFile(dir / "v.nrrd", nrrdHeader("float", dims,
                                       "space: RAS\nspace directions: (1,0,0) (0,2,0) (0,0,3)\n"
                                       "endian: little\nencoding: raw\nspace origin: (5,6,7)\n\n") +
                                encode<float>(dims, false));
  auto source = openNrrd((dir / "v.nrrd").string());
  expectAffineNear(source->info().patientFromIndex,
                   Mat4::fromColumns({-1, 0, 0}, {0, -2, 0}, {0, 0, 3}, {-5, -6, 7}), 1e-12);
  EXPECT_FALSE(source->info().integerValues);
  expectValues(*source, 1,
               [](int64_t i, int64_t j, int64_t k) { return typedValue<float>(i, j, k); });
}

TEST(NrrdFormat, DetachedGzipDataReadsForwardAndBackward) {
  const auto dir = test::freshTempDir("nrrd_gzip");
  const std::array<int64_t, 3> dims{40, 30, 6};
  writeFile(dir / "data.raw.gz", gzipBytes(encode<uint16_t>(dims, false)));
  writeFile(dir / "v.nhdr", nrrdHeader("ushort", dims,
                                       "spacings: 0.5 0.5 1.25\nendian: little\nencoding: gzip\n"
                                       "data file: data.raw.gz\n"));
  auto source = openNrrd((dir / "v.nhdr").string());
  EXPECT_NEAR(source->info().spacingMm().z, 1.25, 1e-12);
  auto expected = [](int64_t i, int64_t j, int64_t k) {
    return static_cast<float>(typedValue<uint16_t>(i, j, k));
  };
  expectValues(*source, 4, expected);
  expectValues(*source, 1, expected);  // starts over from slice 0: the stream is rewound
}

// A flipped byte in stored (level 0) deflate data still inflates; only the trailer's checksum
// (gzip's CRC-32, zlib's Adler-32) can tell, so the last slab's read checks it. So must a
// trailer that is missing although every sample is there.
TEST(NrrdFormat, CompressedDataIsCheckedAgainstItsChecksum) {
  const auto dir = test::freshTempDir("nrrd_checksum");
  const std::array<int64_t, 3> dims{16, 16, 8};
  const std::string samples = encode<int16_t>(dims, false);
  const auto readAll = [&](const std::string& header) {
    auto source = openNrrd((dir / header).string());
    std::vector<float> slab(16 * 16 * 2);
    for (int64_t k = 0; k < 8; k += 2) source->readSlab(k, 2, slab);
  };
  const auto write = [&](const std::string& name, const std::string& data,
                         const std::string& encoding) {
    writeFile(dir / (name + ".gz"), data);
    writeFile(dir / (name + ".nhdr"),
              nrrdHeader("short", dims,
                         "endian: little\nencoding: " + encoding + "\ndata file: " + name + ".gz\n"));
  };

  const std::string good = gzipBytes(samples, 0);
  write("good", good, "gzip");
  EXPECT_NO_THROW(readAll("good.nhdr"));

  std::string flipped = good;
  flipped[flipped.size() / 2] ^= 0x55;  // a sample byte in the middle of the stored block
  write("flipped", flipped, "gzip");
  expectErrorMentioning([&] { readAll("flipped.nhdr"); }, "flipped.gz: corrupt compressed data");

  std::string zlibFlipped = zlibBytes(samples, 0);
  zlibFlipped[zlibFlipped.size() / 2] ^= 0x55;
  write("zflipped", zlibFlipped, "gzip");  // NRRD's gzip reader takes zlib streams too
  expectErrorMentioning([&] { readAll("zflipped.nhdr"); }, "zflipped.gz: corrupt compressed data");

  write("notrailer", good.substr(0, good.size() - 8), "gzip");  // CRC-32 and length cut off
  expectErrorMentioning([&] { readAll("notrailer.nhdr"); },
                        "notrailer.gz: compressed data ends before its checksum");

  // Cut inside the samples: the message says how many bytes the stream holds.
  write("short", gzipBytes(samples.substr(0, 1000), 0), "gzip");
  expectErrorMentioning([&] { readAll("short.nhdr"); },
                        "expected 4096 bytes of samples, the stream holds 1000");
}

TEST(NrrdFormat, TruncatedDataAndBadHeadersThrow) {
  const auto dir = test::freshTempDir("nrrd_bad");
  const std::array<int64_t, 3> dims{16, 16, 4};
  writeFile(dir / "short.raw", std::string(100, '\0'));
  writeFile(dir / "v.nhdr",
            nrrdHeader("short", dims, "endian: little\nencoding: raw\ndata file: short.raw\n"));
  expectErrorMentioning([&] { openNrrd((dir / "v.nhdr").string()); }, (dir / "short.raw").string());
  // gzip data cut in half: found when the slab is read, naming the file.
  writeFile(dir / "cut.gz", gzipBytes(encode<int16_t>(dims, false)).substr(0, 200));
  writeFile(dir / "cut.nhdr",
            nrrdHeader("short", dims, "endian: little\nencoding: gzip\ndata file: cut.gz\n"));
  expectErrorMentioning(
      [&] {
        auto source = openNrrd((dir / "cut.nhdr").string());
        std::vector<float> all(16 * 16 * 4);
        source->readSlab(0, 4, all);
      },
      "cut.gz");
  writeFile(dir / "junk.nrrd", "this is not a nrrd file\n\n\x01\x02");
  EXPECT_THROW(openNrrd((dir / "junk.nrrd").string()), Error);
  writeFile(dir / "type.nrrd", nrrdHeader("complex", dims, "encoding: raw\n\n"));
  EXPECT_THROW(openNrrd((dir / "type.nrrd").string()), Error);
  writeFile(dir / "vec.nrrd",
            "NRRD0004\ntype: float\ndimension: 4\nsizes: 3 4 4 4\n"
            "encoding: raw\n\n" +
                std::string(3 * 64 * 4, '\0'));
  EXPECT_THROW(openNrrd((dir / "vec.nrrd").string()), Error);
  writeFile(dir / "empty.nrrd", "");
  EXPECT_THROW(openNrrd((dir / "empty.nrrd").string()), Error);
}

// ---- MetaImage ------------------------------------------------------------------------------

std::string metaHeader(const std::array<int64_t, 3>& dims, const std::string& type,
                       const std::string& extra, const std::string& dataFile) {
  return fmt::format(
      "ObjectType = Image\nNDims = 3\nBinaryData = True\n{}"
      "DimSize = {} {} {}\nElementType = {}\nElementDataFile = {}\n",
      extra, dims[0], dims[1], dims[2], type, dataFile);
}

TEST(MetaImageFormat, LocalObliqueMsbShort) {
  const auto dir = test::freshTempDir("meta_local");
  const std::array<int64_t, 3> dims{7, 5, 3};
  const double c = 0.8, s = 0.6;
  writeFile(
      dir / "v.mha",
      metaHeader(dims, "MET_SHORT",
                 fmt::format("BinaryDataByteOrderMSB = True\nTransformMatrix = {} {} 0 {} {} 0 "
                             "0 0 1\nOffset = -1.5 2.5 100\nElementSpacing = 0.5 0.25 3\n",
                             c, s, -s, c),
                 "LOCAL") +
          encode<int16_t>(dims, true));
  auto source = openMetaImage((dir / "v.mha").string());
  const VolumeInfo& info = source->info();
  EXPECT_EQ(info.dims, dims);
  EXPECT_EQ(info.format, "metaimage");
  expectAffineNear(info.patientFromIndex,
                   Mat4::fromColumns({0.5 * c, 0.5 * s, 0}, {-0.25 * s, 0.25 * c, 0}, {0, 0, 3},
                                     {-1.5, 2.5, 100}),
                   1e-12);
  expectValues(*source, 2, [](int64_t i, int64_t j, int64_t k) {
    return static_cast<float>(typedValue<int16_t>(i, j, k));
  });
}

TEST(MetaImageFormat, DetachedAndCompressedData) {
  const auto dir = test::freshTempDir("meta_detached");
  const std::array<int64_t, 3> dims{9, 8, 5};
  writeFile(dir / "v.raw", encode<float>(dims, false));
  writeFile(dir / "v.mhd", metaHeader(dims, "MET_FLOAT", "ElementSpacing = 1 1 2\n", "v.raw"));
  auto detached = openMetaImage((dir / "v.mhd").string());
  EXPECT_FALSE(detached->info().integerValues);
  auto floats = [](int64_t i, int64_t j, int64_t k) { return typedValue<float>(i, j, k); };
  expectValues(*detached, 3, floats);

  writeFile(dir / "z.mha", metaHeader(dims, "MET_UCHAR", "CompressedData = True\n", "LOCAL") +
                               zlibBytes(encode<uint8_t>(dims, false)));
  auto compressed = openMetaImage((dir / "z.mha").string());
  expectValues(*compressed, 2, [](int64_t i, int64_t j, int64_t k) {
    return static_cast<float>(typedValue<uint8_t>(i, j, k));
  });

  // HeaderSize = -1: the samples are the last bytes of the data file.
  writeFile(dir / "tail.raw", std::string(37, '#') + encode<float>(dims, false));
  writeFile(dir / "tail.mhd", metaHeader(dims, "MET_FLOAT", "HeaderSize = -1\n", "tail.raw"));
  expectValues(*openMetaImage((dir / "tail.mhd").string()), 5, floats);
}

TEST(MetaImageFormat, BadInputsThrow) {
  const auto dir = test::freshTempDir("meta_bad");
  const std::array<int64_t, 3> dims{9, 8, 5};
  writeFile(dir / "short.raw", std::string(10, '\0'));
  writeFile(dir / "v.mhd", metaHeader(dims, "MET_SHORT", "", "short.raw"));
  expectErrorMentioning([&] { openMetaImage((dir / "v.mhd").string()); }, "short.raw");
  writeFile(dir / "rgb.mhd",
            metaHeader(dims, "MET_UCHAR", "ElementNumberOfChannels = 3\n", "short.raw"));
  EXPECT_THROW(openMetaImage((dir / "rgb.mhd").string()), Error);
  writeFile(dir / "junk.mha", "\x89PNG garbage\n\x00\x01");
  EXPECT_THROW(openMetaImage((dir / "junk.mha").string()), Error);
  writeFile(dir / "neg.mhd", metaHeader({-3, 8, 5}, "MET_SHORT", "", "short.raw"));
  EXPECT_THROW(openMetaImage((dir / "neg.mhd").string()), Error);
  writeFile(dir / "list.mhd", metaHeader(dims, "MET_SHORT", "", "LIST"));
  EXPECT_THROW(openMetaImage((dir / "list.mhd").string()), Error);
}

}  // namespace
}  // namespace octoray
