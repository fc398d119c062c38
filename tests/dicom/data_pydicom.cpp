// decodeDicomFile on every file of Debian's pydicom test set (real images in many transfer
// syntaxes, DICOMDIRs, deliberately malformed files, and files that are not DICOM at all),
// against pydicom's own stored values written by pydicom_reference.py.
//
// Rules, per file:
//  - pydicom decodes a monochrome image: we must decode it too, with the same shape and the
//    same stored values: exactly for lossless syntaxes; for lossy JPEG (.50/.51) and lossy
//    JPEG 2000 (.91) two conforming decoders may round the inverse transform differently,
//    so the largest difference may be kLossyBound stored units. A rejection fails the test
//    unless kGenuinelyInvalid names the file and says why.
//  - colour (SamplesPerPixel > 1) or no pixel data: we must reject it with octoray::Error
//    whose message names the file.
//  - pydicom cannot decode the pixel data: either outcome may be right (pydicom lacks the
//    codec, or the file is damaged); kMustReject and kSameImageAs pin the cases we know.
//  - Nothing may crash, hang or throw anything but octoray::Error: each file is decoded in a
//    child process with a time limit, so one crash is reported as that file's failure.

#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "octoray/dicom/dicom_decode.h"
#include "octoray/core/error.h"
#include "test_paths.h"

namespace octoray {
namespace {

namespace fs = std::filesystem;

// Lossy decoders: ISO 10918-2 lets conforming JPEG decoders differ by one unit after the
// IDCT; the 9/7 wavelet of JPEG 2000 is floating point and rounds the same way, at most one
// unit per output sample. Two units leaves room for one rounding in colour-free level shift.
constexpr double kLossyBound = 2.0;

// Every file here is under 1 MB: decoding takes milliseconds; far longer is a hang.
constexpr double kTimeoutSeconds = 20.0;

bool isLossySyntax(const std::string& uid) {
  return uid == "1.2.840.10008.1.2.4.50" || uid == "1.2.840.10008.1.2.4.51" ||
         uid == "1.2.840.10008.1.2.4.91";
}

// Monochrome files pydicom decodes that we may reject, and why rejecting them is right.
const std::map<std::string, std::string> kGenuinelyInvalid = {};

// Valid files GDCM cannot turn into an image: Debian's GDCM 3.0.21 (built with assertions)
// aborts in gdcm::ImageReader on single-frame RT Dose objects without NumberOfFrames (the
// Multi-frame module is conditional, so the files are valid). decodeDicomFile vets every file
// in a child process and rejects these cleanly instead of crashing; the rejection is the
// expected outcome until GDCM handles them.
const std::map<std::string, std::string> kGdcmCannotDecode = {
    {"rtdose_1frame.dcm", "GDCM aborts on RT Dose without NumberOfFrames"},
    {"rtdose_expb_1frame.dcm", "GDCM aborts on RT Dose without NumberOfFrames"},
    {"rtdose_rle_1frame.dcm", "GDCM aborts on RT Dose without NumberOfFrames"},
};

// Files pydicom cannot decode that we must reject, and why.
const std::map<std::string, std::string> kMustReject = {
    {"MR_truncated.dcm", "pixel data is shorter than Rows x Columns x BitsAllocated"},
};

// Files pydicom cannot decode (no codec in Debian's pydicom) whose pixels are those of
// another file in the set (pydicom's own tests compare them so).
const std::map<std::string, std::string> kSameImageAs = {
    {"MR_small_jpeg_ls_lossless.dcm", "MR_small.dcm"},
};

struct Reference {
  std::string path;
  std::string syntax;
  bool decoded = false;
  bool colour = false;
  bool noPixelData = false;
  std::string reason;
  int frames = 0, rows = 0, columns = 0;
  std::vector<double> values;
};

std::vector<double> readFloat64(const fs::path& path) {
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  const auto bytes = static_cast<std::size_t>(in.tellg());
  std::vector<double> values(bytes / sizeof(double));
  in.seekg(0);
  in.read(reinterpret_cast<char*>(values.data()), static_cast<std::streamsize>(bytes));
  return values;
}

std::vector<Reference> readReferences(const fs::path& dir) {
  std::ifstream in(dir / "index.json");
  const auto index = nlohmann::json::parse(in);
  std::vector<Reference> references;
  for (const auto& file : index.at("files")) {
    Reference r;
    r.path = file.at("path").get<std::string>();
    r.syntax = file.value("syntax", "");
    r.decoded = file.at("decoded").get<bool>();
    r.reason = file.value("reason", "");
    r.colour = std::stoi(file.value("SamplesPerPixel", "1")) > 1;
    r.noPixelData = r.reason == "no pixel data element" || r.reason.rfind("dcmread:", 0) == 0;
    if (r.decoded) {
      r.frames = file.at("frames").get<int>();
      r.rows = file.at("rows").get<int>();
      r.columns = file.at("columns").get<int>();
      r.values = readFloat64(dir / file.at("values").get<std::string>());
    }
    references.push_back(std::move(r));
  }
  return references;
}

// Our outcome for one file.
struct Outcome {
  std::optional<dicom::DecodedImage> image;
  std::string error;  // octoray::Error message when rejected, or how the decoder failed
  bool crashed = false;         // died, hung, or threw something other than octoray::Error
  double seconds = 0;
};

// Decodes `path` in a child process, so that a crash (an abort inside a codec) or a hang is
// one failed file rather than the end of the test run. The child sends back the outcome as
// a small binary message through a file: 'E' + message, or 'D' + shape + values.
Outcome decodeIsolated(const std::string& path, const fs::path& scratch, double timeoutSeconds) {
  Outcome o;
  const auto start = std::chrono::steady_clock::now();
  const fs::path message = scratch / "outcome.bin";
  fs::remove(message);
  std::cout.flush();
  const pid_t child = fork();
  if (child == 0) {
    std::ofstream out(message, std::ios::binary);
    try {
      const dicom::DecodedImage image = dicom::decodeDicomFile(path);
      const int32_t shape[3] = {image.format.frames, image.format.rows, image.format.columns};
      const uint64_t count = image.stored.size();
      out.put('D');
      out.write(reinterpret_cast<const char*>(shape), sizeof shape);
      out.write(reinterpret_cast<const char*>(&count), sizeof count);
      out.write(reinterpret_cast<const char*>(image.stored.data()),
                static_cast<std::streamsize>(count * sizeof(double)));
    } catch (const Error& e) {
      out.put('E');
      out << e.what();
    } catch (const std::exception& e) {
      out.put('X');
      out << "non-octoray exception: " << e.what();
    }
    out.close();
    _exit(out ? 0 : 3);
  }
  int status = 0;
  bool finished = false;
  while (!finished) {
    const pid_t done = waitpid(child, &status, WNOHANG);
    o.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    if (done == child) {
      finished = true;
    } else if (o.seconds > timeoutSeconds) {
      kill(child, SIGKILL);
      waitpid(child, &status, 0);
      o.crashed = true;
      o.error = fmt::format("hung: killed after {:.0f} s", timeoutSeconds);
      return o;
    } else {
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
  }
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    o.crashed = true;
    o.error = WIFSIGNALED(status) ? fmt::format("crashed: signal {} ({})", WTERMSIG(status),
                                                strsignal(WTERMSIG(status)))
                                  : fmt::format("child exited with {}", WEXITSTATUS(status));
    return o;
  }
  std::ifstream in(message, std::ios::binary);
  const int kind = in.get();
  if (kind == 'D') {
    int32_t shape[3];
    uint64_t count = 0;
    in.read(reinterpret_cast<char*>(shape), sizeof shape);
    in.read(reinterpret_cast<char*>(&count), sizeof count);
    dicom::DecodedImage image;
    image.format.frames = shape[0];
    image.format.rows = shape[1];
    image.format.columns = shape[2];
    image.stored.resize(count);
    in.read(reinterpret_cast<char*>(image.stored.data()),
            static_cast<std::streamsize>(count * sizeof(double)));
    o.image = std::move(image);
  } else {
    o.error.assign(std::istreambuf_iterator<char>(in), {});
    o.crashed = kind != 'E';
  }
  return o;
}

// Largest absolute difference, or nullopt when the shapes differ (with `why` set).
std::optional<double> compare(const dicom::DecodedImage& ours, int frames, int rows, int columns,
                              const std::vector<double>& values, std::string& why) {
  if (ours.format.frames != frames || ours.format.rows != rows ||
      ours.format.columns != columns || ours.stored.size() != values.size()) {
    why = fmt::format("shape {}x{}x{} ({} values), reference {}x{}x{} ({} values)",
                      ours.format.frames, ours.format.rows, ours.format.columns,
                      ours.stored.size(), frames, rows, columns, values.size());
    return std::nullopt;
  }
  double worst = 0;
  for (std::size_t i = 0; i < values.size(); ++i) {
    const double difference = std::abs(ours.stored[i] - values[i]);
    if (difference > 0 && worst == 0) {
      why = fmt::format("first difference at sample {}: ours {}, reference {}", i,
                        ours.stored[i], values[i]);
    }
    worst = std::max(worst, difference);
  }
  return worst;
}

TEST(PydicomTestFiles, DecodeAgreesWithPydicomOrRejectsCleanly) {
  const fs::path input = test::pydicomTestFiles();
  OCTORAY_REQUIRE_PATH(input);
  if (std::system("/usr/bin/python3 -c 'import pydicom, numpy' > /dev/null 2>&1") != 0) {
    GTEST_SKIP() << "skipped: /usr/bin/python3 with pydicom and numpy is not available";
  }
  const fs::path out = test::freshTempDir("pydicom");
  const fs::path script = fs::path(OCTORAY_SOURCE_DIR) / "tests/dicom/pydicom_reference.py";
  const std::string command =
      fmt::format("/usr/bin/python3 -W ignore '{}' '{}' '{}' > '{}' 2>&1", script.string(),
                  input.string(), out.string(), (out / "python.log").string());
  ASSERT_EQ(std::system(command.c_str()), 0) << command << "; see " << (out / "python.log");
  const std::vector<Reference> references = readReferences(out);
  ASSERT_GT(references.size(), 50u);

  std::map<std::string, const Reference*> byName;
  for (const Reference& r : references) {
    if (r.decoded) byName[fs::path(r.path).filename().string()] = &r;
  }

  std::cout << fmt::format("{:<58} {:<24} {:<10} {}\n", "file", "transfer syntax", "pydicom",
                           "octoray");
  int exact = 0, lossyWithinBound = 0, rejected = 0, unverified = 0, crashed = 0;
  for (const Reference& r : references) {
    const std::string name = fs::path(r.path).filename().string();
    const std::string shown = fs::relative(r.path, input).string();
    SCOPED_TRACE(r.path);
    const Outcome ours = decodeIsolated(r.path, out, kTimeoutSeconds);
    std::string result;

    EXPECT_LT(ours.seconds, kTimeoutSeconds) << "decoding took " << ours.seconds << " s";
    if (ours.crashed) {
      ++crashed;
      result = "CRASHED: " + ours.error;
      ADD_FAILURE() << "decodeDicomFile did not return or throw octoray::Error: " << ours.error;
    } else if (!ours.image) {
      ++rejected;
      result = "rejected: " + ours.error.substr(std::min(ours.error.size(), r.path.size() + 2));
      EXPECT_NE(ours.error.find(r.path), std::string::npos)
          << "the message does not name the file: " << ours.error;
      if (kGdcmCannotDecode.contains(name)) {
        EXPECT_NE(ours.error.find("aborted"), std::string::npos) << ours.error;
      }
      if (r.decoded && !kGenuinelyInvalid.contains(name) && !kGdcmCannotDecode.contains(name)) {
        ADD_FAILURE() << "pydicom decodes this " << r.rows << "x" << r.columns << "x"
                      << r.frames << " monochrome image (" << r.syntax
                      << ") but decodeDicomFile rejects it: " << ours.error;
      }
    } else if (r.colour || r.noPixelData) {
      result = "DECODED";
      ADD_FAILURE() << (r.colour ? "colour image" : "file without pixel data")
                    << " was not rejected";
    } else if (kMustReject.contains(name)) {
      result = "DECODED";
      ADD_FAILURE() << "must be rejected: " << kMustReject.at(name);
    } else {
      // What to compare with: pydicom's values, or those of the same image in another file.
      const Reference* reference = r.decoded ? &r : nullptr;
      if (!reference && kSameImageAs.contains(name) && byName.contains(kSameImageAs.at(name))) {
        reference = byName.at(kSameImageAs.at(name));
      }
      if (!reference) {
        ++unverified;
        result = "decoded, no reference (pydicom: " + r.reason.substr(0, 40) + ")";
      } else {
        std::string why;
        const auto worst = compare(*ours.image, reference->frames, reference->rows,
                                   reference->columns, reference->values, why);
        EXPECT_TRUE(worst) << why;
        if (worst && *worst == 0) {
          ++exact;
          result = reference == &r ? "equal" : "equal to " + kSameImageAs.at(name);
        } else if (worst && isLossySyntax(r.syntax)) {
          EXPECT_LE(*worst, kLossyBound) << "lossy decoders differ by more than the bound";
          ++lossyWithinBound;
          result = fmt::format("lossy, max difference {}", *worst);
        } else if (worst) {
          ADD_FAILURE() << "lossless syntax " << r.syntax << " but values differ by up to "
                        << *worst << "; " << why;
          result = fmt::format("DIFFERS by up to {}", *worst);
        } else {
          result = "SHAPE DIFFERS: " + why;
        }
      }
    }
    const std::string pydicomResult =
        r.decoded ? "values" : (r.colour ? "colour" : (r.noPixelData ? "no pixels" : "fails"));
    std::cout << fmt::format("{:<58} {:<24} {:<10} {}\n", shown,
                             r.syntax.empty() ? "-" : r.syntax, pydicomResult, result);
  }
  std::cout << fmt::format("{} files: {} equal, {} lossy within {}, {} rejected, {} decoded "
                           "without a reference, {} crashed or hung\n",
                           references.size(), exact, lossyWithinBound, kLossyBound, rejected,
                           unverified, crashed);
}

}  // namespace
}  // namespace octoray
