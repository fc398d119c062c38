// writePhantomNrrd: the phantom as a detached NRRD header and raw int16 little-endian data,
// generated slab by slab (the next slab is computed while the previous one is written) through
// temporary names renamed on success, so a failed write leaves nothing behind.

#include <algorithm>
#include <array>
#include <bit>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <future>
#include <span>
#include <system_error>
#include <vector>

#include <fmt/format.h>
#include <unistd.h>

#include "octoray/core/error.h"
#include "octoray/volume/phantom.h"

namespace octoray::volume {

namespace {

namespace fs = std::filesystem;

int16_t toLittleEndian(int16_t v) {
  if constexpr (std::endian::native == std::endian::big) {
    const auto u = static_cast<uint16_t>(v);
    return static_cast<int16_t>(static_cast<uint16_t>((u >> 8) | (u << 8)));
  }
  return v;
}

// Deletes the temporary files unless the write was committed.
class TemporaryFiles {
 public:
  explicit TemporaryFiles(std::vector<fs::path> paths) : paths_(std::move(paths)) {}
  TemporaryFiles(const TemporaryFiles&) = delete;
  TemporaryFiles& operator=(const TemporaryFiles&) = delete;
  ~TemporaryFiles() {
    std::error_code ignored;
    for (const fs::path& path : paths_) fs::remove(path, ignored);
  }
  void commit() { paths_.clear(); }

 private:
  std::vector<fs::path> paths_;
};

// A FILE* that reports every failure as an octoray::Error naming the final file.
class OutputFile {
 public:
  OutputFile(const fs::path& tempPath, std::string reportedPath)
      : reportedPath_(std::move(reportedPath)), file_(std::fopen(tempPath.c_str(), "wb")) {
    if (file_ == nullptr) fail("cannot create");
  }
  OutputFile(const OutputFile&) = delete;
  OutputFile& operator=(const OutputFile&) = delete;
  ~OutputFile() {
    if (file_ != nullptr) std::fclose(file_);
  }

  void write(const void* data, std::size_t bytes) {
    if (bytes > 0 && std::fwrite(data, 1, bytes, file_) != bytes) fail("cannot write");
  }
  void close() {
    const int flushed = std::fflush(file_);
    const int flushErrno = errno;
    const int closed = std::fclose(file_);
    file_ = nullptr;
    if (flushed != 0 || closed != 0) {
      errno = flushed != 0 ? flushErrno : errno;
      fail("cannot write");
    }
  }

 private:
  [[noreturn]] void fail(const char* what) const {
    throw Error(reportedPath_, fmt::format("{} ({})", what, std::strerror(errno)));
  }

  std::string reportedPath_;
  std::FILE* file_;
};

std::string nrrdHeader(const PhantomOptions& options, const VolumeInfo& info,
                       const std::string& dataFileName) {
  const Vec3 s = options.spacingMm;
  const Vec3 origin = info.patientFromIndex.column(3);
  return fmt::format(
      "NRRD0004\n"
      "# {}\n"
      "type: int16\n"
      "dimension: 3\n"
      "space: left-posterior-superior\n"
      "sizes: {} {} {}\n"
      "space directions: ({},0,0) (0,{},0) (0,0,{})\n"
      "kinds: domain domain domain\n"
      "endian: little\n"
      "encoding: raw\n"
      "sample units: HU\n"
      "space origin: ({},{},{})\n"
      "data file: {}\n",
      info.description, options.dims[0], options.dims[1], options.dims[2], s.x, s.y, s.z, origin.x,
      origin.y, origin.z, dataFileName);
}

constexpr double kGiB = double(uint64_t{1} << 30);

// Refuses a phantom whose data would not fit on the output's file system, or whose slab
// buffers (floats, and two int16 copies: 8 bytes per sample) would take more than 3/4 of this
// machine's memory: one message before anything is written, not a full disk or "out of memory".
void checkRoomFor(const std::array<int64_t, 3>& dims, int64_t slabSamples, const fs::path& raw) {
  const double dataBytes = 2.0 * static_cast<double>(dims[0]) * static_cast<double>(dims[1]) *
                           static_cast<double>(dims[2]);
  std::error_code ec;
  const fs::path folder = raw.parent_path().empty() ? fs::path(".") : raw.parent_path();
  const fs::space_info space = fs::space(folder, ec);
  if (!ec && dataBytes > static_cast<double>(space.available)) {
    throw Error(raw.string(), fmt::format("the {}x{}x{} phantom needs {:.1f} GiB, but this file "
                                          "system has {:.1f} GiB free",
                                          dims[0], dims[1], dims[2], dataBytes / kGiB,
                                          static_cast<double>(space.available) / kGiB));
  }
  const double bufferBytes = 8.0 * static_cast<double>(slabSamples);
  const long pages = sysconf(_SC_PHYS_PAGES), pageSize = sysconf(_SC_PAGE_SIZE);
  const double memoryBytes = static_cast<double>(pages) * static_cast<double>(pageSize);
  if (pages > 0 && pageSize > 0 && bufferBytes > 0.75 * memoryBytes) {
    throw Error(raw.string(),
                fmt::format("slices of {}x{} samples need {:.1f} GiB of buffers, "
                            "more than 3/4 of this machine's {:.1f} GiB",
                            dims[0], dims[1], bufferBytes / kGiB, memoryBytes / kGiB));
  }
}

}  // namespace

void writePhantomNrrd(
    const PhantomOptions& options, const std::string& path,
    const std::function<void(int64_t slicesDone, int64_t slicesTotal)>& progress) {
  const fs::path headerPath(path);
  const std::string extension = headerPath.extension().string();
  if (extension != ".nhdr" && extension != ".nrrd") {
    throw Error(path, "the header name must end in .nhdr or .nrrd");
  }
  fs::path rawPath = headerPath;
  rawPath.replace_extension(".raw");
  const fs::path headerTemp = fs::path(path + ".partial");
  const fs::path rawTemp = fs::path(rawPath.string() + ".partial");
  TemporaryFiles temporaries({headerTemp, rawTemp});

  const std::unique_ptr<VolumeSource> phantom = makePhantom(options);  // checks the options
  const VolumeInfo& info = phantom->info();
  const int64_t sliceSamples = options.dims[0] * options.dims[1];
  const int64_t slices = options.dims[2];
  // Slabs of about 8 M samples (16 MB): one being generated while the previous one is written.
  const int64_t slabSlices = std::clamp<int64_t>((int64_t{1} << 23) / sliceSamples, 1, slices);
  checkRoomFor(options.dims, slabSlices * sliceSamples, rawPath);

  {
    OutputFile raw(rawTemp, rawPath.string());
    std::vector<float> samples(static_cast<std::size_t>(slabSlices * sliceSamples));
    std::array<std::vector<int16_t>, 2> buffers;
    for (auto& buffer : buffers) buffer.resize(static_cast<std::size_t>(slabSlices * sliceSamples));
    std::future<void> pendingWrite;
    int64_t slicesWritten = 0;
    const auto waitForWrite = [&] {
      if (!pendingWrite.valid()) return;
      pendingWrite.get();
      if (progress) progress(slicesWritten, slices);
    };
    for (int64_t first = 0, slab = 0; first < slices; first += slabSlices, ++slab) {
      const int64_t count = std::min(slabSlices, slices - first);
      const std::size_t slabSamples = static_cast<std::size_t>(count * sliceSamples);
      phantom->readSlab(first, count, std::span<float>(samples).first(slabSamples));
      // The samples are integers in [-1024, 3071]: exact in int16. The other buffer may still
      // be being written.
      std::vector<int16_t>& buffer = buffers[slab % 2];
      std::transform(samples.begin(), samples.begin() + static_cast<std::ptrdiff_t>(slabSamples),
                     buffer.begin(),
                     [](float v) { return toLittleEndian(static_cast<int16_t>(v)); });
      waitForWrite();
      slicesWritten = first + count;
      const std::size_t bytes = slabSamples * sizeof(int16_t);
      pendingWrite = std::async(std::launch::async,
                                [&raw, data = buffer.data(), bytes] { raw.write(data, bytes); });
    }
    waitForWrite();
    raw.close();
  }
  {
    OutputFile header(headerTemp, path);
    const std::string text = nrrdHeader(options, info, rawPath.filename().string());
    header.write(text.data(), text.size());
    header.close();
  }

  // The data first, the header last: a header that exists always describes complete data.
  std::error_code ec;
  fs::rename(rawTemp, rawPath, ec);
  if (ec) throw Error(rawPath.string(), "cannot rename from temporary file: " + ec.message());
  fs::rename(headerTemp, headerPath, ec);
  if (ec) {
    std::error_code ignored;
    fs::remove(rawPath, ignored);
    throw Error(path, "cannot rename from temporary file: " + ec.message());
  }
  temporaries.commit();
}

}  // namespace octoray::volume
