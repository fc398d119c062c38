// TIFF stacks through OpenCV: a folder of single-page TIFFs in natural file-name order, or one
// multi-page TIFF. Grey 8/16-bit integer or 32/64-bit float pages; slabs are decoded on demand.

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <limits>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "octoray/core/error.h"
#include "octoray/core/text.h"
#include "octoray/dicom/formats.h"
#include "raw_slab_reader.h"

namespace octoray {

namespace {

bool hasTiffExtension(const std::filesystem::path& file) {
  const std::string ext = asciiLower(file.extension().string());
  return ext == ".tif" || ext == ".tiff";
}

// Numeric-aware order: "slice2" < "slice10"; digit runs compare by value, text without case.
bool naturalLess(const std::string& a, const std::string& b) {
  std::size_t i = 0, j = 0;
  while (i < a.size() && j < b.size()) {
    const auto ca = static_cast<unsigned char>(a[i]), cb = static_cast<unsigned char>(b[j]);
    if (std::isdigit(ca) && std::isdigit(cb)) {
      std::size_t ei = i, ej = j;
      while (ei < a.size() && std::isdigit(static_cast<unsigned char>(a[ei]))) ++ei;
      while (ej < b.size() && std::isdigit(static_cast<unsigned char>(b[ej]))) ++ej;
      std::size_t si = i, sj = j;
      while (si + 1 < ei && a[si] == '0') ++si;  // value: leading zeros do not count
      while (sj + 1 < ej && b[sj] == '0') ++sj;
      if (ei - si != ej - sj) return ei - si < ej - sj;
      const int cmp = a.compare(si, ei - si, b, sj, ej - sj);
      if (cmp != 0) return cmp < 0;
      i = ei;
      j = ej;
    } else {
      const int la = std::tolower(ca), lb = std::tolower(cb);
      if (la != lb) return la < lb;
      ++i;
      ++j;
    }
  }
  if (a.size() - i != b.size() - j) return a.size() - i < b.size() - j;
  return a < b;  // equal up to case and leading zeros: any fixed order
}

// Where the file numbers of a stack named alike ("s000.tif" ... "s007.tif") skip a value the
// others keep to: a slice file is likely missing, and the stack would close the gap silently.
// One warning per jump (the first few); nothing when the names do not follow one pattern.
std::vector<std::string> numberingGaps(const std::vector<std::string>& names) {
  struct Numbered {
    std::string prefix, suffix;
    uint64_t number = 0;
  };
  std::vector<Numbered> numbered;
  for (const std::string& name : names) {
    const std::size_t last = name.find_last_of("0123456789");
    if (last == std::string::npos) return {};
    std::size_t first = last;
    while (first > 0 && std::isdigit(static_cast<unsigned char>(name[first - 1]))) --first;
    if (last - first + 1 > 18) return {};
    Numbered n{name.substr(0, first), name.substr(last + 1),
               std::stoull(name.substr(first, last - first + 1))};
    const bool other = !numbered.empty() && (n.prefix != numbered.front().prefix ||
                                             n.suffix != numbered.front().suffix);
    if (other) return {};
    numbered.push_back(std::move(n));
  }
  if (numbered.size() < 3) return {};
  uint64_t step = std::numeric_limits<uint64_t>::max();
  for (std::size_t i = 1; i < numbered.size(); ++i) {
    if (numbered[i].number <= numbered[i - 1].number) return {};
    step = std::min(step, numbered[i].number - numbered[i - 1].number);
  }
  std::vector<std::string> warnings;
  for (std::size_t i = 1; i < numbered.size() && warnings.size() < 3; ++i) {
    if (numbered[i].number - numbered[i - 1].number != step) {
      warnings.push_back(fmt::format("the file numbers jump from {} to {} ({} to {}): a slice file "
                                     "may be missing, and the stack closes the gap",
                                     numbered[i - 1].number, numbered[i].number, names[i - 1],
                                     names[i]));
    }
  }
  return warnings;
}

// Checks one decoded page; `what` names the file (and page) in messages.
void checkPage(const cv::Mat& page, const std::string& what, int width, int height, int type) {
  if (page.empty()) throw Error(what, "cannot be decoded as an image");
  if (page.channels() != 1) {
    throw Error(
        what, fmt::format("has {} channels: only grey-scale TIFFs are supported", page.channels()));
  }
  const int depth = page.depth();
  if (depth != CV_8U && depth != CV_8S && depth != CV_16U && depth != CV_16S && depth != CV_32F &&
      depth != CV_64F) {
    throw Error(what, "unsupported sample type: only 8/16-bit integer or float pages");
  }
  if (width >= 0 && (page.cols != width || page.rows != height)) {
    throw Error(what, fmt::format("is {}x{} but the first page is {}x{}: all pages must have the "
                                  "same size",
                                  page.cols, page.rows, width, height));
  }
  if (type >= 0 && page.type() != type) {
    throw Error(what, "has a different sample type from the first page");
  }
}

class TiffSource final : public VolumeSource {
 public:
  // `files`: one single-page file per slice; or one multi-page file with `pages` pages.
  TiffSource(std::string path, std::vector<std::string> files, int64_t pages, Vec3 spacingMm)
      : files_(std::move(files)) {
    multiPage_ = files_.size() == 1 && pages > 1;
    const cv::Mat first = decodePages(0, 1).front();
    checkPage(first, files_.front(), -1, -1, -1);
    type_ = first.type();
    info_.dims = {first.cols, first.rows, multiPage_ ? pages : static_cast<int64_t>(files_.size())};
    info_.patientFromIndex =
        Mat4::fromColumns({spacingMm.x, 0, 0}, {0, spacingMm.y, 0}, {0, 0, spacingMm.z}, {});
    detail::checkAffine(info_.patientFromIndex, path);
    info_.format = "tiff";
    info_.sourcePath = path;
    info_.sourceFiles = files_;
    std::sort(info_.sourceFiles.begin(), info_.sourceFiles.end());
    info_.description = std::filesystem::path(path).filename().string();
    info_.integerValues = first.depth() != CV_32F && first.depth() != CV_64F;
    if (first.depth() == CV_8U) {
      info_.valueLowerBound = 0;
      info_.valueUpperBound = 255;
    } else if (first.depth() == CV_16U) {
      info_.valueLowerBound = 0;
      info_.valueUpperBound = 65535;
    } else if (first.depth() == CV_16S) {
      info_.valueLowerBound = -32768;
      info_.valueUpperBound = 32767;
    }
  }

  const VolumeInfo& info() const override { return info_; }
  void addWarnings(const std::vector<std::string>& warnings) {
    info_.warnings.insert(info_.warnings.end(), warnings.begin(), warnings.end());
  }

  void readSlab(int64_t firstSlice, int64_t sliceCount, std::span<float> out) override {
    checkSlabRequest(info_, firstSlice, sliceCount, out.size());
    const auto width = static_cast<int>(info_.dims[0]), height = static_cast<int>(info_.dims[1]);
    const auto pages = decodePages(firstSlice, sliceCount);
    for (int64_t s = 0; s < sliceCount; ++s) {
      const cv::Mat& page = pages[static_cast<std::size_t>(s)];
      checkPage(page, pageName(firstSlice + s), width, height, type_);
      cv::Mat slice(height, width, CV_32F, out.data() + s * info_.sliceSamples());
      page.convertTo(slice, CV_32F);  // writes into `out` in place: the size and type match
    }
  }

 private:
  std::string pageName(int64_t slice) const {
    return multiPage_ ? fmt::format("{} (page {})", files_.front(), slice)
                      : files_[static_cast<std::size_t>(slice)];
  }

  std::vector<cv::Mat> decodePages(int64_t firstSlice, int64_t count) const {
    std::vector<cv::Mat> pages;
    try {
      if (multiPage_) {
        if (!cv::imreadmulti(files_.front(), pages, static_cast<int>(firstSlice),
                             static_cast<int>(count), cv::IMREAD_UNCHANGED)) {
          pages.clear();
        }
      } else {
        for (int64_t s = 0; s < count; ++s) {
          pages.push_back(
              cv::imread(files_[static_cast<std::size_t>(firstSlice + s)], cv::IMREAD_UNCHANGED));
        }
      }
    } catch (const cv::Exception& e) {
      throw Error(pageName(firstSlice), fmt::format("cannot be decoded: {}", e.what()));
    }
    if (static_cast<int64_t>(pages.size()) != count) {
      throw Error(files_.front(),
                  fmt::format("cannot decode pages {} to {}", firstSlice, firstSlice + count - 1));
    }
    return pages;
  }

  VolumeInfo info_;
  std::vector<std::string> files_;
  bool multiPage_ = false;
  int type_ = -1;
};

}  // namespace

std::unique_ptr<VolumeSource> openTiffStack(const std::string& path, Vec3 spacingMm) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (fs::is_directory(path, ec)) {
    std::vector<std::string> names;
    for (const auto& entry : fs::directory_iterator(path, ec)) {
      if (entry.is_regular_file(ec) && hasTiffExtension(entry.path())) {
        names.push_back(entry.path().filename().string());
      }
    }
    if (ec) throw Error(path, "cannot list the folder: " + ec.message());
    if (names.empty()) throw Error(path, "the folder holds no .tif or .tiff files");
    std::sort(names.begin(), names.end(), naturalLess);
    std::vector<std::string> files;
    for (const auto& name : names) files.push_back((fs::path(path) / name).string());
    auto source = std::make_unique<TiffSource>(path, std::move(files), 1, spacingMm);
    source->addWarnings(numberingGaps(names));
    return source;
  }
  if (!fs::is_regular_file(path, ec)) throw Error(path, "not a readable file or folder");
  std::size_t pages = 0;
  try {
    pages = cv::imcount(path, cv::IMREAD_UNCHANGED);
  } catch (const cv::Exception& e) {
    throw Error(path, fmt::format("not a readable TIFF: {}", e.what()));
  }
  if (pages == 0) throw Error(path, "not a readable TIFF");
  return std::make_unique<TiffSource>(path, std::vector<std::string>{path},
                                      static_cast<int64_t>(pages), spacingMm);
}

}  // namespace octoray
