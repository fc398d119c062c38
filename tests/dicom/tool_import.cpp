// octoray-import as users and scripts run it: the --json documents of docs/import-json.md on a
// synthetic series written by octoray-sample-series (known size, spacing and tilt), the NIfTI
// export read back independently, the store summary, and bad input: one clear line on stderr
// naming the file, exit 1 (2 for command-line mistakes), no output file. Real Philips data
// where ../shared is present.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "octoray/dicom/formats.h"
#include "run_process.h"
#include "test_paths.h"

namespace octoray {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;
using test::ProcessResult;

constexpr double kPi = 3.14159265358979323846;

ProcessResult runTool(const std::string& tool, std::vector<std::string> args) {
  args.insert(args.begin(), test::toolPath(tool).string());
  return test::runProcess(args);
}

ProcessResult runImport(std::vector<std::string> args) {
  return runTool("octoray-import", std::move(args));
}

// A 32x32x12 synthetic CT series (0.5 x 0.5 x 1.25 mm) in a fresh folder `name`.
fs::path writeSeries(const std::string& name, std::vector<std::string> extra = {}) {
  const fs::path dir = test::freshTempDir(name);
  std::vector<std::string> args = {dir.string(), "--size", "32x32x12"};
  args.insert(args.end(), extra.begin(), extra.end());
  const ProcessResult r = runTool("octoray-sample-series", args);
  EXPECT_EQ(r.exitCode, 0) << r.err;
  return dir;
}

json parseJson(const ProcessResult& r) {
  EXPECT_EQ(r.exitCode, 0) << r.err;
  try {
    return json::parse(r.out);
  } catch (const json::exception& e) {
    ADD_FAILURE() << "stdout is not JSON (" << e.what() << "):\n" << r.out;
    return json::object();
  }
}

void expectCommonFields(const json& j, const std::string& path) {
  EXPECT_EQ(j.value("tool", ""), "octoray-import");
  EXPECT_EQ(j.value("schemaVersion", 0), 1);
  EXPECT_EQ(j.value("path", ""), path);
}

std::vector<std::string> lines(const std::string& text) {
  std::vector<std::string> result;
  std::size_t start = 0;
  while (start < text.size()) {
    const std::size_t end = text.find('\n', start);
    const std::string line = text.substr(start, end == std::string::npos ? end : end - start);
    if (!line.empty()) result.push_back(line);
    if (end == std::string::npos) break;
    start = end + 1;
  }
  return result;
}

// A failure on bad input: exit 1, exactly one line "octoray-import: ..." on stderr naming
// `named`, nothing on stdout, no crash or stack trace.
void expectInputError(const ProcessResult& r, const std::string& named) {
  EXPECT_EQ(r.signal, 0) << "killed by signal " << r.signal << "\n" << r.err;
  EXPECT_EQ(r.exitCode, 1) << r.err;
  const auto errLines = lines(r.err);
  ASSERT_EQ(errLines.size(), 1u) << "stderr:\n" << r.err;
  EXPECT_EQ(errLines[0].rfind("octoray-import: ", 0), 0u) << errLines[0];
  EXPECT_NE(errLines[0].find(named), std::string::npos) << "does not name " << named << ": "
                                                        << errLines[0];
  for (const char* trace : {"terminate called", "Aborted", "Segmentation", "#0 ", "what():"}) {
    EXPECT_EQ(r.err.find(trace), std::string::npos) << r.err;
  }
  EXPECT_TRUE(r.out.empty()) << "stdout:\n" << r.out;
}

// A command-line mistake: exit 2, a message naming `named`, no crash.
void expectUsageError(const ProcessResult& r, const std::string& named) {
  EXPECT_EQ(r.signal, 0);
  EXPECT_EQ(r.exitCode, 2) << r.err;
  EXPECT_NE(r.err.find(named), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("terminate called"), std::string::npos) << r.err;
}

// The folder holds nothing but `expected` (no output file, no temporary left behind).
void expectOnly(const fs::path& dir, const std::vector<std::string>& expected) {
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) names.push_back(e.path().filename().string());
  std::sort(names.begin(), names.end());
  std::vector<std::string> want = expected;
  std::sort(want.begin(), want.end());
  EXPECT_EQ(names, want);
}

// ---- JSON documents on a synthetic series -------------------------------------------------

TEST(ToolImport, ListJsonReportsVolumeAndLocalizer) {
  const fs::path dir = writeSeries("series", {"--with-localizer"});
  const json j = parseJson(runImport({"--list", dir.string(), "--json"}));
  expectCommonFields(j, dir.string());
  EXPECT_EQ(j.value("filesExamined", 0), 13);
  ASSERT_EQ(j["series"].size(), 2u) << j.dump(2);
  int volumes = 0, localizers = 0, defaults = 0;
  for (std::size_t n = 0; n < j["series"].size(); ++n) {
    const json& s = j["series"][n];
    EXPECT_EQ(s["index"].get<std::size_t>(), n);
    EXPECT_FALSE(s["seriesUid"].get<std::string>().empty());
    EXPECT_EQ(s["modality"], "CT");
    EXPECT_EQ(s["columns"], 32);
    EXPECT_EQ(s["rows"], 32);
    if (s["default"].get<bool>()) ++defaults;
    if (s["kind"] == "localizer") {
      ++localizers;
      EXPECT_FALSE(s["default"].get<bool>());
      EXPECT_EQ(s["images"], 1);
    } else if (s["kind"] == "volume") {
      ++volumes;
      EXPECT_TRUE(s["default"].get<bool>());
      EXPECT_EQ(s["images"], 12);
      EXPECT_EQ(s["slices"], 12);
      EXPECT_FALSE(s["multiFrame"].get<bool>());
      EXPECT_TRUE(s["uniformSpacing"].get<bool>());
      ASSERT_EQ(s["pixelSpacingMm"].size(), 2u);
      EXPECT_NEAR(s["pixelSpacingMm"][0].get<double>(), 0.5, 1e-6);
      EXPECT_NEAR(s["pixelSpacingMm"][1].get<double>(), 0.5, 1e-6);
      EXPECT_NEAR(s["sliceSpacingMm"].get<double>(), 1.25, 1e-6);
      EXPECT_NEAR(s["tiltDegrees"].get<double>(), 0.0, 1e-6);
    }
    EXPECT_FALSE(s["kindReason"].get<std::string>().empty());
  }
  EXPECT_EQ(volumes, 1);
  EXPECT_EQ(localizers, 1);
  EXPECT_EQ(defaults, 1);
  EXPECT_TRUE(j["skipped"].empty());
}

TEST(ToolImport, InspectJsonKeepsTiltAsShear) {
  const fs::path dir = writeSeries("series", {"--tilt", "12"});
  const json j = parseJson(runImport({"--inspect", dir.string(), "--json"}));
  expectCommonFields(j, dir.string());
  EXPECT_EQ(j["format"], "dicom");
  EXPECT_EQ(j["modality"], "CT");
  EXPECT_EQ(j["dimensions"], json({32, 32, 12}));
  EXPECT_NEAR(j["tiltDegrees"].get<double>(), 12.0, 1e-3);
  EXPECT_FALSE(j["resampled"].get<bool>());
  EXPECT_EQ(j["unit"], "HU");
  EXPECT_TRUE(j["integerValues"].get<bool>());
  EXPECT_EQ(j["nonFiniteSamples"], 0);
  // The window octoray-sample-series writes in every slice (WindowCenter 40, WindowWidth 400).
  EXPECT_EQ(j["windows"], json::parse(R"([{"center": 40.0, "width": 400.0, "explanation": "", "function": ""}])"));

  // Column 2 (the slice step) is sheared along the column direction by tan(tilt).
  const json& m = j["patientFromIndex"];
  ASSERT_EQ(m.size(), 4u);
  EXPECT_EQ(m[3], json({0.0, 0.0, 0.0, 1.0}));
  EXPECT_NEAR(m[0][0].get<double>(), 0.5, 1e-9);
  EXPECT_NEAR(m[1][1].get<double>(), 0.5, 1e-9);
  const double shear = m[1][2].get<double>();
  const double normalStep = m[2][2].get<double>();
  EXPECT_NEAR(std::abs(shear), 1.25 * std::tan(12.0 * kPi / 180.0), 1e-4);
  EXPECT_NEAR(normalStep, 1.25, 1e-6);
  EXPECT_NEAR(j["spacingMm"][2].get<double>(), std::hypot(shear, normalStep), 1e-6);
  EXPECT_NEAR(j["spacingMm"][0].get<double>(), 0.5, 1e-9);

  ASSERT_TRUE(j["valueRange"].is_object());
  EXPECT_LT(j["valueRange"]["min"].get<double>(), j["valueRange"]["max"].get<double>());
  bool mentionsTilt = false;
  for (const auto& w : j["warnings"]) mentionsTilt |= w.get<std::string>().find("tilt") != std::string::npos;
  EXPECT_TRUE(mentionsTilt) << j["warnings"].dump();
  EXPECT_EQ(j["series"]["kind"], "volume");
  EXPECT_EQ(j["seriesUid"], j["series"]["seriesUid"]);
}

TEST(ToolImport, ExportNiftiMatchesTheSeries) {
  const fs::path dir = writeSeries("series", {"--tilt", "12"});
  const fs::path outDir = test::freshTempDir("out");
  const fs::path out = outDir / "out.nii.gz";
  const json inspect = parseJson(runImport({"--inspect", dir.string(), "--json"}));
  const json j = parseJson(runImport({"--export", out.string(), dir.string(), "--json"}));
  expectCommonFields(j, dir.string());
  EXPECT_EQ(j["output"], out.string());
  EXPECT_EQ(j["dimensions"], json({32, 32, 12}));
  ASSERT_TRUE(fs::exists(out));
  expectOnly(outDir, {"out.nii.gz"});

  const auto nifti = openNifti(out.string());
  const auto dicom = openVolume(dir.string());
  const VolumeInfo& info = nifti->info();
  ASSERT_EQ(info.dims, (std::array<int64_t, 3>{32, 32, 12}));
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) {
      EXPECT_NEAR(info.patientFromIndex.m[r][c], inspect["patientFromIndex"][r][c].get<double>(), 1e-4)
          << "patientFromIndex[" << r << "][" << c << "]";
    }
  std::vector<float> fromNifti(static_cast<std::size_t>(info.sampleCount()));
  std::vector<float> fromDicom(fromNifti.size());
  nifti->readSlab(0, info.dims[2], fromNifti);
  dicom->readSlab(0, info.dims[2], fromDicom);
  std::size_t differing = 0;
  for (std::size_t n = 0; n < fromNifti.size(); ++n) differing += fromNifti[n] != fromDicom[n];
  EXPECT_EQ(differing, 0u);
}

TEST(ToolImport, StoreJsonSummary) {
  const fs::path dir = writeSeries("series");
  const fs::path outDir = test::freshTempDir("out");
  const fs::path out = outDir / "out.octoray";
  const json j = parseJson(runImport({dir.string(), "-o", out.string(), "--json"}));
  expectCommonFields(j, dir.string());
  ASSERT_TRUE(fs::exists(out));
  expectOnly(outDir, {"out.octoray"});
  EXPECT_EQ(j["output"], out.string());
  EXPECT_EQ(j["voxels"].get<int64_t>(), 32 * 32 * 12);
  EXPECT_EQ(j["bricks"].get<int64_t>(), 1);  // 32^3 samples fit one brick of the default B = 32
  EXPECT_EQ(j["bytesOnDisk"].get<uint64_t>(), fs::file_size(out));
  const double rss = j["peakRssMiB"].get<double>();
  EXPECT_GT(rss, 1.0);
  EXPECT_LT(rss, 2048.0);
  EXPECT_EQ(j["sampleFormat"], "uint16");
}

// AddressSanitizer's quarantine keeps freed memory resident, which a peak-memory test would
// count as held: the tools it starts run without it while this lives.
class WithoutAsanQuarantine {
 public:
  WithoutAsanQuarantine() {
    const char* options = std::getenv("ASAN_OPTIONS");
    if (options) saved_ = options;
    const std::string separator = saved_ && !saved_->empty() ? ":" : "";
    ::setenv("ASAN_OPTIONS", (saved_.value_or("") + separator + "quarantine_size_mb=0").c_str(), 1);
  }
  ~WithoutAsanQuarantine() {
    if (saved_) {
      ::setenv("ASAN_OPTIONS", saved_->c_str(), 1);
    } else {
      ::unsetenv("ASAN_OPTIONS");
    }
  }
  WithoutAsanQuarantine(const WithoutAsanQuarantine&) = delete;
  WithoutAsanQuarantine& operator=(const WithoutAsanQuarantine&) = delete;

 private:
  std::optional<std::string> saved_;
};

// The VDB export holds neither the grid's values nor its topology: 16 times the slices raise
// the tool's peak memory by far less than the values they add (an export that held the whole
// grid rose by 31.8 MiB here, against 2.0 MiB now). Every sample is active and no two neighbours are equal, so
// every 8x8x8 block is a leaf of 2 KiB. AddressSanitizer's quarantine keeps freed memory
// resident, which would count here as held, so the tool runs without it.
TEST(ToolImportVdb, PeakMemoryGrowsWithTheTopologyNotTheValues) {
  const fs::path dir = test::freshTempDir("vdb_memory");
  const WithoutAsanQuarantine noQuarantine;
  constexpr int64_t kSide = 256;
  auto peakMiB = [&](int64_t slices) {
    const std::string name = fmt::format("v{}", slices);
    std::vector<int16_t> values(static_cast<std::size_t>(kSide * kSide * slices));
    for (std::size_t n = 0; n < values.size(); ++n) {
      values[n] = static_cast<int16_t>(-800 + static_cast<int64_t>((n * 2654435761u) % 2400));
    }
    {
      std::ofstream raw(dir / (name + ".raw"), std::ios::binary);
      raw.write(reinterpret_cast<const char*>(values.data()),
                static_cast<std::streamsize>(values.size() * sizeof(int16_t)));
      std::ofstream header(dir / (name + ".nhdr"));
      header << fmt::format("NRRD0004\ntype: short\ndimension: 3\nsizes: {} {} {}\n"
                            "spacings: 0.5 0.5 0.5\nendian: little\nencoding: raw\n"
                            "data file: {}.raw\n",
                            kSide, kSide, slices, name);
    }
    const json j = parseJson(runImport({"--export", (dir / (name + ".vdb")).string(),
                                        (dir / (name + ".nhdr")).string(), "--json"}));
    EXPECT_EQ(j["activeVoxels"].get<int64_t>(), kSide * kSide * slices);
    return j["peakRssMiB"].get<double>();
  };
  const double thin = peakMiB(8), thick = peakMiB(128);
  const double addedValuesMiB = double(kSide * kSide * 120) * sizeof(float) / (1 << 20);  // 30
  EXPECT_LT(thick - thin, 0.35 * addedValuesMiB)
      << "peak RSS " << thin << " MiB for 8 slices, " << thick << " MiB for 128";
}

// A multi-frame object is decoded a run of frames at a time: 16 times the frames raise the
// tool's peak memory by far less than the values they add. Decoded whole, 240 more frames of
// 256 x 256 rose it by 175 MiB (their doubles, GDCM's copy of the file and its decoded
// buffer); by runs, 34 MiB. AddressSanitizer's quarantine is off, as above.
TEST(ToolImport, MultiFramePeakMemoryGrowsWithARunNotTheObject) {
  const WithoutAsanQuarantine noQuarantine;
  auto peakMiB = [&](int frames) {
    const fs::path dir = test::freshTempDir(fmt::format("frames{}", frames));
    const fs::path series = dir / "series";
    const ProcessResult written =
        runTool("octoray-sample-series",
                {series.string(), "--size", fmt::format("256x256x{}", frames), "--multi-frame"});
    EXPECT_EQ(written.exitCode, 0) << written.err;
    const json j =
        parseJson(runImport({series.string(), "-o", (dir / "out.octoray").string(), "--json"}));
    EXPECT_EQ(j["voxels"].get<int64_t>(), int64_t{256} * 256 * frames);
    return j["peakRssMiB"].get<double>();
  };
  const double thin = peakMiB(16), thick = peakMiB(256);
  const double addedValuesMiB = 240.0 * 256 * 256 * sizeof(double) / (1 << 20);  // 120
  EXPECT_LT(thick - thin, 0.5 * addedValuesMiB)
      << "peak RSS " << thin << " MiB for 16 frames, " << thick << " MiB for 256";
}

// ---- bad input ------------------------------------------------------------------------------

// A file of the series that cannot be read is named in the warnings of every command that
// builds the volume without it (text and --json).
TEST(ToolImportBadInput, UnreadableFileOfTheSeriesIsNamed) {
  const fs::path dir = writeSeries("left_out");
  const fs::path cut = dir / "CT0006.dcm";
  ASSERT_TRUE(fs::exists(cut));
  fs::resize_file(cut, 300);
  const fs::path outDir = test::freshTempDir("left_out_out");
  const json store = parseJson(runImport({dir.string(), "-o", (outDir / "x.octoray").string(), "--json"}));
  const json exported = parseJson(runImport({"--export", (outDir / "x.nii.gz").string(), dir.string(), "--json"}));
  const json inspected = parseJson(runImport({"--inspect", dir.string(), "--json"}));
  for (const json* j : {&store, &exported, &inspected}) {
    EXPECT_NE((*j)["warnings"].dump().find(cut.string()), std::string::npos) << (*j)["warnings"].dump(1);
  }
  const ProcessResult text = runImport({dir.string(), "-o", (outDir / "y.octoray").string()});
  EXPECT_EQ(text.exitCode, 0);
  EXPECT_NE(text.out.find("could not be read"), std::string::npos) << text.out;
  EXPECT_NE(text.out.find(cut.string()), std::string::npos) << text.out;
}

TEST(ToolImportBadInput, NonexistentPath) {
  const fs::path outDir = test::freshTempDir("out");
  const std::string missing = (outDir / "no-such-folder").string();
  expectInputError(runImport({"--inspect", missing}), missing);
  expectInputError(runImport({"--export", (outDir / "x.nii.gz").string(), missing}), missing);
  expectInputError(runImport({missing, "-o", (outDir / "x.octoray").string()}), missing);
  expectOnly(outDir, {});
}

// An output that is one of the files read (by its own name, through a link, or as a
// detached NRRD's data file) is refused before anything is written, and the file is intact.
TEST(ToolImportBadInput, OutputThatIsAnInputIsRefused) {
  const auto bytesOf = [](const fs::path& path) {
    std::ifstream in(path, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), {});
  };
  const fs::path series = writeSeries("self_series");
  const fs::path slice = series / "CT0006.dcm";
  ASSERT_TRUE(fs::exists(slice));
  const std::string sliceBytes = bytesOf(slice);
  expectInputError(runImport({series.string(), "-o", slice.string()}),
                   slice.string() + ": the output is the same file as the input");
  EXPECT_EQ(bytesOf(slice), sliceBytes);

  const fs::path dir = test::freshTempDir("self_nrrd");
  std::ofstream(dir / "v.raw", std::ios::binary) << std::string(16 * 16 * 4 * 2, '\x01');
  std::ofstream(dir / "v.nhdr") << "NRRD0004\ntype: short\ndimension: 3\nsizes: 16 16 4\n"
                                   "encoding: raw\nendian: little\ndata file: v.raw\n";
  fs::create_symlink(dir / "v.raw", dir / "link.raw");
  fs::create_hard_link(dir / "v.raw", dir / "hard.raw");
  const std::string header = (dir / "v.nhdr").string();
  const std::string rawBytes = bytesOf(dir / "v.raw");
  for (const fs::path& out : {dir / "v.nhdr", dir / "v.raw", dir / "link.raw", dir / "hard.raw"}) {
    expectInputError(runImport({header, "-o", out.string()}),
                     out.string() + ": the output is the same file as the input");
  }
  EXPECT_EQ(bytesOf(dir / "v.raw"), rawBytes);
  EXPECT_EQ(bytesOf(dir / "v.nhdr").substr(0, 8), "NRRD0004");

  const std::string nii = (dir / "v.nii").string();
  ASSERT_EQ(runImport({"--export", nii, header}).exitCode, 0);
  const std::string niiBytes = bytesOf(nii);
  expectInputError(runImport({"--export", nii, nii}), nii + ": the output is the same file as the input");
  EXPECT_EQ(bytesOf(nii), niiBytes);

  // A store given as the input is named as one (it was "no volumetric image series found").
  const std::string store = (dir / "v.octoray").string();
  ASSERT_EQ(runImport({header, "-o", store}).exitCode, 0);
  for (const std::vector<std::string>& args :
       {std::vector<std::string>{"--inspect", store}, {store, "-o", (dir / "again.octoray").string()}}) {
    expectInputError(runImport(args), store + ": is an octoray store already");
  }
  // A damaged one says what is wrong with it.
  const std::string damaged = (dir / "damaged.octoray").string();
  std::ofstream(damaged) << std::string(26, 'X');
  expectInputError(runImport({"--inspect", damaged}),
                   damaged + ": header: file too short (26 bytes) to be an octoray store");
}

// --inspect's text names samples that are not numbers (its JSON always did): the value range
// it prints leaves them out.
TEST(ToolImportBadInput, InspectTextCountsNonFiniteSamples) {
  const fs::path dir = test::freshTempDir("nonfinite");
  std::vector<float> samples(4 * 4 * 2, 1.0f);
  samples[5] = std::numeric_limits<float>::quiet_NaN();
  samples[20] = std::numeric_limits<float>::infinity();
  std::ofstream(dir / "v.nrrd", std::ios::binary)
      << "NRRD0004\ntype: float\ndimension: 3\nsizes: 4 4 2\nencoding: raw\nendian: little\n\n"
      << std::string(reinterpret_cast<const char*>(samples.data()), samples.size() * sizeof(float));
  const ProcessResult r = runImport({"--inspect", (dir / "v.nrrd").string()});
  EXPECT_EQ(r.exitCode, 0) << r.err;
  EXPECT_NE(r.out.find("values       1 .. 1"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("not finite   2 samples"), std::string::npos) << r.out;
}

TEST(ToolImportBadInput, EmptyFolder) {
  const fs::path empty = test::freshTempDir("empty");
  const fs::path outDir = test::freshTempDir("out");
  expectInputError(runImport({"--inspect", empty.string()}), empty.string());
  expectInputError(runImport({empty.string(), "-o", (outDir / "x.octoray").string()}),
                   empty.string());
  const ProcessResult list = runImport({"--list", empty.string(), "--json"});
  EXPECT_EQ(list.exitCode, 1) << "no image series found must exit 1";
  EXPECT_EQ(list.err, "octoray-import: " + empty.string() +
                          ": no DICOM image series found (0 files examined, 0 left out): --list "
                          "lists DICOM series, --inspect reads every format\n");
  expectOnly(outDir, {});
}

TEST(ToolImportBadInput, FolderOfTextFiles) {
  const fs::path dir = test::freshTempDir("text");
  for (const char* name : {"notes.txt", "README", "scan.dcm"}) {
    std::ofstream(dir / name) << "not a DICOM file, just text\n";
  }
  const fs::path outDir = test::freshTempDir("out");
  expectInputError(runImport({"--inspect", dir.string()}), dir.string());
  expectInputError(runImport({"--export", (outDir / "x.nii.gz").string(), dir.string()}),
                   dir.string());
  expectOnly(outDir, {});
}

TEST(ToolImportBadInput, TruncatedDicomFileAlone) {
  const fs::path series = writeSeries("series");
  const fs::path dir = test::freshTempDir("truncated");
  const fs::path file = dir / "CT0001.dcm";
  fs::copy_file(series / "CT0001.dcm", file);
  fs::resize_file(file, fs::file_size(file) / 2);  // cut inside the pixel data
  const fs::path outDir = test::freshTempDir("out");
  expectInputError(runImport({"--inspect", file.string()}), file.string());
  expectInputError(runImport({"--export", (outDir / "x.nii.gz").string(), file.string()}),
                   file.string());
  expectInputError(runImport({file.string(), "-o", (outDir / "x.octoray").string()}),
                   file.string());
  expectOnly(outDir, {});
}

TEST(ToolImportBadInput, SeriesOutOfRange) {
  const fs::path dir = writeSeries("series");
  const fs::path outDir = test::freshTempDir("out");
  const ProcessResult r = runImport({"--inspect", dir.string(), "--series", "99"});
  expectInputError(r, dir.string());
  EXPECT_NE(r.err.find("99"), std::string::npos) << r.err;
  expectInputError(
      runImport({"--export", (outDir / "x.nii.gz").string(), dir.string(), "--series", "99"}),
      dir.string());
  expectOnly(outDir, {});
}

TEST(ToolImportBadInput, ConflictingFlagsAreUsageErrors) {
  const fs::path dir = writeSeries("series");
  const fs::path outDir = test::freshTempDir("out");
  const std::string nii = (outDir / "x.nii.gz").string();
  const std::string store = (outDir / "x.octoray").string();
  expectUsageError(runImport({"--list", "--inspect", dir.string()}), "--inspect");
  expectUsageError(runImport({"--export", nii, "-o", store, dir.string()}), "--export");
  expectUsageError(runImport({"--inspect", "--export", nii, dir.string()}), "--export");
  expectUsageError(runImport({dir.string()}), "choose one of");
  expectUsageError(runImport({"--list"}), "path");
  expectUsageError(runImport({dir.string(), "-o", store, "--brick-size", "17"}), "17");
  expectUsageError(runImport({dir.string(), "-o", store, "--slice-spacing", "0"}),
                   "--slice-spacing: must be a number above 0, not 0");
  expectUsageError(runImport({dir.string(), "-o", store, "--raw-header-bytes", "-5"}),
                   "--raw-header-bytes: must be 0 or a number above it, not -5");
  // Not a number as a whole, or not finite: the same check, the same words.
  for (const char* bad : {"2mm", "inf", "nan", ""}) {
    expectUsageError(runImport({dir.string(), "-o", store, "--slice-spacing", bad}),
                     std::string("--slice-spacing: must be a number above 0, not ") + bad);
  }
  expectOnly(outDir, {});
}

TEST(ToolImportBadInput, SpacingThatIsNotThreePositiveNumbersIsRefused) {
  const fs::path outDir = test::freshTempDir("out");
  const fs::path raw = outDir / "zeros.raw";
  std::ofstream(raw, std::ios::binary) << std::string(128, '\0');
  const std::string store = (outDir / "x.octoray").string();
  const auto importWithSpacing = [&](const std::string& spacing) {
    return runImport({raw.string(), "--raw-dims", "4x4x4", "--raw-type", "int16", "--raw-spacing",
                      spacing, "-o", store});
  };
  expectInputError(importWithSpacing("1,nan,1"),
                   "--raw-spacing \"1,nan,1\": \"nan\" is not a positive number");
  expectInputError(importWithSpacing("1,1e999,1"), "\"1e999\" is not a positive number");
  expectInputError(importWithSpacing("1,0.5mm,1"), "\"0.5mm\" is not a positive number");
  expectInputError(importWithSpacing("1,,1"), "\"\" is not a positive number");
  expectInputError(importWithSpacing("1,-2,1"), "\"-2\" is not a positive number");
  expectInputError(importWithSpacing("1,1"), "expected three values separated by ','");
  expectOnly(outDir, {"zeros.raw"});
}

// ---- real Philips data ---------------------------------------------------------------------

// SeriesInstanceUID of S21610/S2010 ("STEREOTAXIS", gantry tilt -18.5 in its headers).
constexpr const char* kTiltedPhilipsUid = "1.3.46.670589.33.1.7303547162003802183.31761132431540865648";

TEST(ToolImportPhilips, ListShowsVolumesAndLocalizers) {
  OCTORAY_REQUIRE_PATH(test::philipsDir());
  const json j = parseJson(runImport({"--list", test::philipsDir().string(), "--json"}));
  int volumes = 0, localizers = 0;
  for (const auto& s : j["series"]) {
    volumes += s["kind"] == "volume";
    localizers += s["kind"] == "localizer";
  }
  EXPECT_EQ(volumes, 4) << j["series"].dump(1);
  EXPECT_GE(localizers, 1);
  // The plain table shows the same kinds.
  const ProcessResult text = runImport({"--list", test::philipsDir().string()});
  EXPECT_EQ(text.exitCode, 0);
  EXPECT_NE(text.out.find("localizer"), std::string::npos) << text.out;
  EXPECT_NE(text.out.find("STEREOTAXIS"), std::string::npos) << text.out;
}

TEST(ToolImportPhilips, InspectTiltedSeriesReportsShear) {
  OCTORAY_REQUIRE_PATH(test::philipsDir() / "S21610/S2010");
  const json j = parseJson(runImport(
      {"--inspect", test::philipsDir().string(), "--series", kTiltedPhilipsUid, "--json"}));
  EXPECT_EQ(j["seriesUid"], kTiltedPhilipsUid);
  EXPECT_NEAR(std::abs(j["tiltDegrees"].get<double>()), 18.5, 0.05);
  const json& m = j["patientFromIndex"];
  // The slice step leaves the slice normal by the tilt: the ratio of its component in the
  // image plane to its component along the normal is tan(18.5 degrees).
  const double c0[3] = {m[0][0], m[1][0], m[2][0]};
  const double c1[3] = {m[0][1], m[1][1], m[2][1]};
  const double c2[3] = {m[0][2], m[1][2], m[2][2]};
  double normal[3] = {c0[1] * c1[2] - c0[2] * c1[1], c0[2] * c1[0] - c0[0] * c1[2],
                      c0[0] * c1[1] - c0[1] * c1[0]};
  const double nl = std::hypot(normal[0], normal[1], normal[2]);
  double along = 0, total = 0;
  for (int a = 0; a < 3; ++a) {
    along += c2[a] * normal[a] / nl;
    total += c2[a] * c2[a];
  }
  const double inPlane = std::sqrt(std::max(0.0, total - along * along));
  EXPECT_NEAR(std::atan2(inPlane, std::abs(along)) * 180.0 / kPi, 18.5, 0.05);
  bool mentionsTilt = false;
  for (const auto& w : j["warnings"]) mentionsTilt |= w.get<std::string>().find("tilt") != std::string::npos;
  EXPECT_TRUE(mentionsTilt) << j["warnings"].dump();
}

}  // namespace
}  // namespace octoray
