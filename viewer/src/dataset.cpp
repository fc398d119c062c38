#include "octoray/viewer/dataset.h"

#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <xxhash.h>

#include <chrono>
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <map>

#include "octoray/core/error.h"
#include "octoray/core/paths.h"
#include "octoray/dicom/formats.h"
#include "octoray/volume/store_builder.h"
#include "octoray/viewer/presets.h"
#include "octoray/volume/store_reader.h"
#include "octoray/volume/value_histogram.h"

namespace octoray::viewer {
namespace fs = std::filesystem;

fs::path defaultCacheDir() { return userCacheDir(); }

std::string storeCacheKey(VolumeSource& source) {
  const VolumeInfo& info = source.info();
  XXH3_state_t* state = XXH3_createState();
  XXH3_64bits_reset(state);
  XXH3_64bits_update(state, info.seriesUid.data(), info.seriesUid.size());
  XXH3_64bits_update(state, info.dims.data(), sizeof(info.dims));
  XXH3_64bits_update(state, &info.patientFromIndex.m, sizeof(info.patientFromIndex.m));
  std::vector<float> slice(static_cast<std::size_t>(info.sliceSamples()));
  for (int64_t k : {int64_t{0}, info.dims[2] / 2, info.dims[2] - 1}) {
    source.readSlab(k, 1, slice);
    XXH3_64bits_update(state, slice.data(), slice.size() * sizeof(float));
  }
  const uint64_t hash = XXH3_64bits_digest(state);
  XXH3_freeState(state);
  return fmt::format("{:016x}", hash);
}

// ---- PreviewVolume -------------------------------------------------------------------------

PreviewVolume::PreviewVolume(const VolumeInfo& info, uint64_t budgetBytes)
    : grid_(info.dims, info.patientFromIndex), sourceDims_(info.dims) {
  auto previewDims = [&](int f) {
    return std::array<int64_t, 3>{(info.dims[0] + f - 1) / f, (info.dims[1] + f - 1) / f,
                                  (info.dims[2] + f - 1) / f};
  };
  while (true) {
    dims_ = previewDims(factor_);
    const uint64_t bytes = static_cast<uint64_t>(dims_[0] * dims_[1] * dims_[2]) * sizeof(float);
    if (bytes <= budgetBytes || factor_ >= 64) break;
    factor_ *= 2;
  }
  values_.assign(static_cast<std::size_t>(dims_[0] * dims_[1] * dims_[2]),
                 std::numeric_limits<float>::quiet_NaN());
  sliceDone_ = std::make_unique<std::atomic<bool>[]>(static_cast<std::size_t>(dims_[2]));
}

void PreviewVolume::publish(int64_t pk) {
  sliceDone_[static_cast<std::size_t>(pk)].store(true, std::memory_order_release);
  slicesDone_.fetch_add(1, std::memory_order_acq_rel);
}

void PreviewVolume::addSlice(int64_t k, std::span<const float> values) {
  const auto& d = sourceDims_;
  if (k < 0 || k >= d[2] || values.size() != static_cast<std::size_t>(d[0] * d[1])) return;
  if (sourceSeen_.empty()) {
    sourceSeen_.assign(static_cast<std::size_t>(d[2]), 0);
    sourcesIn_.assign(static_cast<std::size_t>(dims_[2]), 0);
    partialSums_.resize(static_cast<std::size_t>(dims_[2]));
  }
  if (sourceSeen_[static_cast<std::size_t>(k)]) return;
  sourceSeen_[static_cast<std::size_t>(k)] = 1;
  const int64_t f = factor_, pk = k / f;
  std::vector<double>& sum = partialSums_[static_cast<std::size_t>(pk)];
  if (sum.empty()) sum.assign(static_cast<std::size_t>(dims_[0] * dims_[1]), 0.0);
  for (int64_t j = 0; j < d[1]; ++j) {
    for (int64_t i = 0; i < d[0]; ++i) {
      sum[static_cast<std::size_t>((j / f) * dims_[0] + i / f)] += values[static_cast<std::size_t>(j * d[0] + i)];
    }
  }
  const int64_t sources = std::min<int64_t>(f, d[2] - pk * f);
  if (++sourcesIn_[static_cast<std::size_t>(pk)] < sources) return;
  // The box filter's weights: the source samples that fell in each preview sample.
  float* out = values_.data() + static_cast<std::size_t>(pk * dims_[0] * dims_[1]);
  for (int64_t pj = 0; pj < dims_[1]; ++pj) {
    const int64_t rows = std::min<int64_t>(f, d[1] - pj * f);
    for (int64_t pi = 0; pi < dims_[0]; ++pi) {
      const int64_t columns = std::min<int64_t>(f, d[0] - pi * f);
      const std::size_t p = static_cast<std::size_t>(pj * dims_[0] + pi);
      out[p] = static_cast<float>(sum[p] / static_cast<double>(rows * columns * sources));
    }
  }
  std::vector<double>().swap(sum);
  publish(pk);
}

void PreviewVolume::fill(VolumeSource& source, const std::atomic<bool>& cancel) {
  const auto& d = source.info().dims;
  const int64_t f = factor_;
  std::vector<float> slab(static_cast<std::size_t>(d[0] * d[1] * f));
  std::vector<double> sum(static_cast<std::size_t>(dims_[0] * dims_[1]));
  std::vector<int> count(sum.size());
  for (int64_t pk = 0; pk < dims_[2] && !cancel.load(); ++pk) {
    const int64_t first = pk * f, n = std::min<int64_t>(f, d[2] - first);
    source.readSlab(first, n, std::span<float>(slab.data(), static_cast<std::size_t>(d[0] * d[1] * n)));
    std::fill(sum.begin(), sum.end(), 0.0);
    std::fill(count.begin(), count.end(), 0);
    for (int64_t k = 0; k < n; ++k) {
      for (int64_t j = 0; j < d[1]; ++j) {
        for (int64_t i = 0; i < d[0]; ++i) {
          const std::size_t p = static_cast<std::size_t>((j / f) * dims_[0] + i / f);
          sum[p] += slab[static_cast<std::size_t>((k * d[1] + j) * d[0] + i)];
          ++count[p];
        }
      }
    }
    float* out = values_.data() + static_cast<std::size_t>(pk * dims_[0] * dims_[1]);
    for (std::size_t p = 0; p < sum.size(); ++p) out[p] = static_cast<float>(sum[p] / std::max(1, count[p]));
    publish(pk);
  }
}

double PreviewVolume::fraction() const {
  return static_cast<double>(slicesDone_.load()) / static_cast<double>(dims_[2]);
}

std::vector<int> PreviewVolume::histogram(int bins, double& lo, double& hi) const {
  const std::size_t sliceSize = static_cast<std::size_t>(dims_[0] * dims_[1]);
  std::vector<std::size_t> shown;
  for (int64_t k = 0; k < dims_[2]; ++k) {
    if (sliceDone_[static_cast<std::size_t>(k)].load(std::memory_order_acquire)) shown.push_back(static_cast<std::size_t>(k));
  }
  // Every stride-th row of the shown slices, in order, so that at most kHistogramSamples are
  // read (the UI thread calls this while a volume arrives); whole rows, so that the memory
  // read shrinks with the samples. A full 64 Mi-sample preview (1024 x 1024 x 64) took 530 ms
  // read whole, 70 ms every 16th sample, 34 ms every 16th row (Release, 2026-12-06).
  const std::size_t rowLength = static_cast<std::size_t>(dims_[0]), rows = static_cast<std::size_t>(dims_[1]);
  const std::size_t total = shown.size() * sliceSize;
  const std::size_t stride = std::max<std::size_t>(1, (total + kHistogramSamples - 1) / kHistogramSamples);
  auto forEachSample = [&](auto&& visit) {
    std::size_t next = 0;  // the next row to read, counted from the current slice's first
    for (const std::size_t k : shown) {
      for (; next < rows; next += stride) {
        const float* row = values_.data() + k * sliceSize + next * rowLength;
        for (std::size_t i = 0; i < rowLength; ++i) {
          if (std::isfinite(row[i])) visit(static_cast<double>(row[i]));
        }
      }
      next -= rows;
    }
  };
  lo = std::numeric_limits<double>::infinity();
  hi = -lo;
  forEachSample([&](double v) {
    lo = std::min(lo, v);
    hi = std::max(hi, v);
  });
  if (!(hi >= lo)) return {};
  hi = volume::histogramTop(lo, hi);
  std::vector<int> counts(static_cast<std::size_t>(bins), 0);
  forEachSample([&](double v) {
    ++counts[static_cast<std::size_t>(volume::histogramBin(v, lo, hi, bins))];
  });
  return counts;
}

double PreviewVolume::sample(Vec3 q, const std::vector<uint8_t>& done) const {
  std::array<int64_t, 3> i0{};
  std::array<double, 3> t{};
  for (int a = 0; a < 3; ++a) {
    const double d = static_cast<double>(grid_.dims[static_cast<std::size_t>(a)]);
    if (!(q[a] >= -0.5 && q[a] <= d - 0.5)) return std::numeric_limits<double>::quiet_NaN();
    const double p = std::clamp((q[a] + 0.5) / factor_ - 0.5, 0.0,
                                static_cast<double>(dims_[static_cast<std::size_t>(a)] - 1));
    const double fl = std::min(std::floor(p), static_cast<double>(std::max<int64_t>(0, dims_[static_cast<std::size_t>(a)] - 2)));
    i0[static_cast<std::size_t>(a)] = static_cast<int64_t>(fl);
    t[static_cast<std::size_t>(a)] = std::clamp(p - fl, 0.0, 1.0);
  }
  // Both slices around the sample must be in, unless one has no weight: a sample on a slice
  // (to 1e-6 of the spacing, which the patient-to-index round trip may miss it by).
  constexpr double kOnSlice = 1e-6;
  if (t[2] < kOnSlice) t[2] = 0.0;
  if (t[2] > 1.0 - kOnSlice) t[2] = 1.0;
  const int64_t z1 = std::min(i0[2] + 1, dims_[2] - 1);
  const bool z0In = t[2] == 1.0 || done[static_cast<std::size_t>(i0[2])];
  const bool z1In = t[2] == 0.0 || done[static_cast<std::size_t>(z1)];
  if (!z0In || !z1In) return std::numeric_limits<double>::quiet_NaN();
  auto at = [&](int64_t x, int64_t y, int64_t z) {
    x = std::min(x, dims_[0] - 1);
    y = std::min(y, dims_[1] - 1);
    z = std::min(z, dims_[2] - 1);
    return static_cast<double>(values_[static_cast<std::size_t>((z * dims_[1] + y) * dims_[0] + x)]);
  };
  const int64_t x = i0[0], y = i0[1], z = i0[2];
  const double fx = t[0], fy = t[1], fz = t[2];
  // A slice without weight is not read: it may not be in yet.
  auto plane = [&](int64_t zz) {
    return (at(x, y, zz) * (1 - fx) + at(x + 1, y, zz) * fx) * (1 - fy) +
           (at(x, y + 1, zz) * (1 - fx) + at(x + 1, y + 1, zz) * fx) * fy;
  };
  if (fz == 0.0) return plane(z);
  if (fz == 1.0) return plane(z + 1);
  return plane(z) * (1 - fz) + plane(z + 1) * fz;
}

Slice PreviewVolume::slice(const SliceRequest& req) const {
  const MprPlane& plane = req.plane;
  Slice out;
  out.width = plane.width;
  out.height = plane.height;
  out.hu.assign(static_cast<std::size_t>(plane.width * plane.height), std::numeric_limits<float>::quiet_NaN());
  int samples = 1;
  if (req.slab != SlabMode::None && req.slabMm > 0) {
    samples = std::max(1, static_cast<int>(std::ceil(req.slabMm / (0.5 * grid_.minSpacingMm() * factor_))));
  }
  out.slabSamples = samples;
  out.missingBricks = slicesDone_.load() < dims_[2] ? 1 : 0;
  // One look at which slices are in, for the whole picture: a slice that comes meanwhile
  // shows in the next one, never in half of this one.
  std::vector<uint8_t> done(static_cast<std::size_t>(dims_[2]));
  for (std::size_t k = 0; k < done.size(); ++k) done[k] = sliceDone_[k].load(std::memory_order_acquire);
  tbb::parallel_for(tbb::blocked_range<int>(0, plane.height), [&](const tbb::blocked_range<int>& rows) {
    for (int y = rows.begin(); y < rows.end(); ++y) {
      for (int x = 0; x < plane.width; ++x) {
        const Vec3 c = plane.at(x + 0.5, y + 0.5);
        double acc = req.slab == SlabMode::MinIp ? std::numeric_limits<double>::infinity()
                     : req.slab == SlabMode::Mip ? -std::numeric_limits<double>::infinity()
                                                 : 0.0;
        int n = 0;
        for (int s = 0; s < samples; ++s) {
          const double offset = samples == 1 ? 0.0 : -0.5 * req.slabMm + (s + 0.5) * req.slabMm / samples;
          const double v = sample(grid_.indexFromPatient.transformPoint(c + offset * plane.normal), done);
          if (std::isnan(v)) continue;
          ++n;
          if (req.slab == SlabMode::Mip) acc = std::max(acc, v);
          else if (req.slab == SlabMode::MinIp) acc = std::min(acc, v);
          else if (req.slab == SlabMode::Mean) acc += v;
          else acc = v;
        }
        if (n == 0) continue;
        if (req.slab == SlabMode::Mean) acc /= n;
        out.hu[static_cast<std::size_t>(y * plane.width + x)] = static_cast<float>(acc);
      }
    }
  });
  return out;
}

// ---- IncomingSeries ------------------------------------------------------------------------

namespace {

Vec3 toVec3(const std::array<double, 3>& a) { return {a[0], a[1], a[2]}; }

std::array<long long, 6> orientationKey(const std::array<double, 6>& o) {
  std::array<long long, 6> key{};
  for (std::size_t i = 0; i < 6; ++i) key[i] = std::llround(o[i] * 1e4);
  return key;
}

}  // namespace

std::optional<IncomingGrid> incomingGrid(const IncomingSeries& series, const VolumeInfo& file,
                                         std::string& why, bool& listingFails) {
  listingFails = true;
  // The majority orientation: other slices (a localiser listed with the series) stay out.
  std::map<std::array<long long, 6>, int> votes;
  std::optional<std::array<double, 6>> orientation;
  int best = 0;
  for (const auto& s : series.slices) {
    if (!s.position || !s.orientation) continue;
    const int n = ++votes[orientationKey(*s.orientation)];
    if (n > best) best = n, orientation = s.orientation;
  }
  if (!orientation) {
    why = "the PACS did not list the slices' positions";
    return std::nullopt;
  }
  const Vec3 row = normalize(Vec3{(*orientation)[0], (*orientation)[1], (*orientation)[2]});
  const Vec3 column = normalize(Vec3{(*orientation)[3], (*orientation)[4], (*orientation)[5]});
  const Vec3 normal = normalize(cross(row, column));
  std::vector<std::pair<double, std::size_t>> along;
  for (std::size_t i = 0; i < series.slices.size(); ++i) {
    const auto& s = series.slices[i];
    if (s.position && s.orientation && orientationKey(*s.orientation) == orientationKey(*orientation)) {
      along.emplace_back(dot(toVec3(*s.position), normal), i);
    }
  }
  std::sort(along.begin(), along.end());
  const std::size_t n = along.size();
  if (n < 2) {
    why = "the series lists fewer than two slices of one orientation";
    return std::nullopt;
  }
  std::vector<double> gaps;
  for (std::size_t i = 1; i < n; ++i) gaps.push_back(along[i].first - along[i - 1].first);
  std::vector<double> sorted = gaps;
  std::sort(sorted.begin(), sorted.end());
  const double median = sorted[sorted.size() / 2];
  // The import's rules (dicom_volume.cpp, resolveStack): it keeps one of two instances at one
  // position, and resamples unless every gap is within max(5 um, 0.1 % of the median).
  if (sorted.front() < 1e-3) {
    why = "two instances share a slice position (the import keeps one)";
    return std::nullopt;
  }
  if (sorted.back() - sorted.front() > std::max(5e-3, 1e-3 * median)) {
    why = fmt::format("the slices are not evenly spaced (gaps {:.3f} to {:.3f} mm): the import resamples them",
                      sorted.front(), sorted.back());
    return std::nullopt;
  }
  // The in-plane columns from a file that arrived: one slice of the listed orientation.
  const Vec3 c0 = file.patientFromIndex.column(0), c1 = file.patientFromIndex.column(1);
  if (file.dims[2] != 1 || dot(normalize(c0), row) < 0.9999 || dot(normalize(c1), column) < 0.9999) {
    why = "the file is not one slice of the listed orientation";
    listingFails = false;
    return std::nullopt;
  }
  // The slice step from the end slices, as the import's: a tilted stack is a shear.
  const Vec3 first = toVec3(*series.slices[along.front().second].position);
  const Vec3 step = (1.0 / static_cast<double>(n - 1)) * (toVec3(*series.slices[along.back().second].position) - first);
  IncomingGrid grid;
  grid.info = file;
  grid.info.dims = {file.dims[0], file.dims[1], static_cast<int64_t>(n)};
  grid.info.patientFromIndex = Mat4::fromColumns(c0, c1, step, first);
  grid.info.sourcePath = series.folder.string();
  grid.info.sourceFiles.clear();
  grid.info.warnings.clear();
  grid.info.description = series.description.empty() ? file.description : series.description;
  grid.indexOfSlice.assign(series.slices.size(), -1);
  for (std::size_t k = 0; k < n; ++k) grid.indexOfSlice[along[k].second] = static_cast<int64_t>(k);
  return grid;
}

// ---- Dataset -------------------------------------------------------------------------------

Dataset::Dataset(const std::string& path, const fs::path& cacheDir) : path_(path), cacheDir_(cacheDir) {
  if (volume::isStoreFile(path)) {
    store_ = std::make_unique<volume::StoreReader>(path);  // throws on damage
    storePath_ = path;
    const auto& h = store_->header();
    info_.dims = {h.dims[0], h.dims[1], h.dims[2]};
    info_.patientFromIndex = store_->patientFromIndex();
    info_.format = "octoray store";
    info_.sourcePath = path;
    const volume::StoreSource& source = store_->source();
    info_.description = source.description;
    info_.modality = source.modality;
    info_.seriesUid = source.seriesUid;
    info_.unit = source.unit;
    info_.windows = source.windows;
    if (info_.description.empty()) info_.description = fs::path(path).filename().string();
    state_ = State::Ready;
    return;
  }
  status_ = "reading headers";
  import_ = std::thread([this] { importThread(); });
}

Dataset::Dataset(std::shared_ptr<IncomingSeries> incoming, const fs::path& cacheDir)
    : path_(incoming->folder.string()), cacheDir_(cacheDir), incoming_(std::move(incoming)) {
  status_ = "retrieving";
  info_.description = incoming_->description;
  info_.sourcePath = path_;
  import_ = std::thread([this] { importThread(); });
}

// What the preview has made of an incoming series' files so far.
struct Dataset::Arrivals {
  std::vector<uint8_t> seen;  // per listed slice: looked at
  std::optional<IncomingGrid> grid;
  bool noGrid = false;        // the listing gives none: the import's preview will show the series
  PreviewVolume* preview = nullptr;
  int64_t arrived = 0;
};

void Dataset::placeArrived(Arrivals& a) {
  const IncomingSeries& in = *incoming_;
  std::vector<float> values;
  for (std::size_t s = 0; s < in.slices.size() && !cancel_; ++s) {
    std::error_code ec;
    if (a.seen[s] || !fs::is_regular_file(in.slices[s].file, ec)) continue;
    a.seen[s] = 1;
    ++a.arrived;
    if (a.noGrid) continue;
    try {
      auto source = openVolume(in.slices[s].file.string());
      const VolumeInfo& one = source->info();
      if (!a.grid) {
        std::string why;
        bool listingFails = true;
        a.grid = incomingGrid(in, one, why, listingFails);
        if (!a.grid) {
          if (listingFails) {
            a.noGrid = true;
            std::lock_guard lock(mutex_);
            warnings_.push_back("no preview while the series arrives: " + why);
          }
          continue;  // else the next file that lands may give the grid
        }
        auto made = std::make_unique<PreviewVolume>(a.grid->info, uint64_t{256} << 20);
        a.preview = made.get();
        std::lock_guard lock(mutex_);
        info_ = a.grid->info;
        preview_ = std::move(made);
      }
      const int64_t k = a.grid->indexOfSlice[s];
      if (k < 0 || one.dims != std::array<int64_t, 3>{a.grid->info.dims[0], a.grid->info.dims[1], 1}) continue;
      // The file must be where the listing says it is.
      const auto& listed = *in.slices[s].position;
      if (length(one.patientFromIndex.transformPoint({0, 0, 0}) - Vec3{listed[0], listed[1], listed[2]}) > 0.01) continue;
      values.resize(static_cast<std::size_t>(one.sliceSamples()));
      source->readSlab(0, 1, values);
      a.preview->addSlice(k, values);
    } catch (const std::exception&) {
      // A file the preview cannot show; the import of the whole folder names it.
    }
  }
}

bool Dataset::receive() {
  IncomingSeries& in = *incoming_;
  slicesTotal_ = static_cast<int64_t>(in.slices.size());
  arrivals_ = std::make_unique<Arrivals>();
  arrivals_->seen.assign(in.slices.size(), 0);
  while (!cancel_) {
    // Complete: the import starts now; the files not looked at yet are placed meanwhile
    // (importThread). A folder complete from the start is previewed as any folder.
    const IncomingSeries::State state = in.state.load();
    if (state == IncomingSeries::State::Complete) return true;
    if (state == IncomingSeries::State::Failed) {
      std::lock_guard lock(mutex_);
      error_ = in.error;
      if (error_.find(path_) == std::string::npos) error_ = path_ + ": " + error_;
      state_ = State::Failed;
      return false;
    }
    placeArrived(*arrivals_);
    slicesDone_ = arrivals_->arrived;
    std::this_thread::sleep_for(std::chrono::milliseconds(40));
  }
  std::lock_guard lock(mutex_);
  error_ = path_ + ": retrieval cancelled";
  state_ = State::Failed;
  return false;
}

Dataset::~Dataset() {
  cancel_ = true;
  if (import_.joinable()) import_.join();
  if (previewThread_.joinable()) previewThread_.join();
}

void Dataset::importThread() {
  try {
    if (incoming_ && !receive()) return;
    {
      std::lock_guard lock(mutex_);
      status_ = "reading headers";
    }
    auto source = openVolume(path_);
    const VolumeInfo info = source->info();
    {
      std::lock_guard lock(mutex_);
      info_ = info;
      warnings_.insert(warnings_.end(), info.warnings.begin(), info.warnings.end());
      status_ = "hashing";
    }
    slicesTotal_ = info.dims[2];
    if (info.format == "dicom") {
      // The patient corner's identity, from the first image of the series the import reads.
      try {
        const dicom::DicomScan scan = dicom::scanDicom(path_);
        const std::size_t chosen = dicom::defaultSeriesIndex(scan, path_);
        const auto& series = scan.series.at(chosen);
        const std::vector<std::string> leftOut = dicom::filesLeftOut(scan, chosen);
        {
          std::lock_guard lock(mutex_);
          warnings_.insert(warnings_.end(), leftOut.begin(), leftOut.end());
        }
        if (!series.frames.empty()) {
          const dicom::PatientIdentity identity = dicom::readPatientIdentity(series.frames.front().path);
          std::lock_guard lock(mutex_);
          patient_ = identity;
        }
      } catch (const std::exception&) {
        // No identity to show; the import itself reports what is wrong with the files.
      }
    }
    // The preview reads its own copy of the source while the import reads this one (a series
    // that arrived from a PACS has its preview already).
    bool previewMade = false;
    {
      std::lock_guard lock(mutex_);
      previewMade = preview_ != nullptr;
      if (!previewMade) preview_ = std::make_unique<PreviewVolume>(info, uint64_t{256} << 20);
    }
    if (!previewMade) {
      previewThread_ = std::thread([this] {
        try {
          auto second = openVolume(path_);
          preview_->fill(*second, cancel_);
        } catch (const std::exception&) {
          // The import reports the same problem with the file; the preview just stops.
        }
      });
    } else if (arrivals_) {
      previewThread_ = std::thread([this] { placeArrived(*arrivals_); });  // the last arrivals
    }
    const std::string key = storeCacheKey(*source);
    fs::create_directories(cacheDir_);
    const fs::path target = cacheDir_ / (key + ".octoray");
    bool reuse = false;
    if (volume::isStoreFile(target)) {
      try {
        volume::StoreReader check(target.string());
        reuse = true;
      } catch (const Error&) {
        fs::remove(target);  // a damaged cached store is rebuilt
      }
    }
    if (!reuse) {
      {
        std::lock_guard lock(mutex_);
        status_ = "importing";
      }
      volume::BuildOptions options;
      options.border = 2;  // central differences for the 3D view's shading
      options.provenanceJson = nlohmann::json{{"importedBy", "octoray-view"}}.dump();
      options.progress = [this](int64_t done, int64_t total) {
        slicesDone_ = done;
        slicesTotal_ = total;
      };
      options.cancel = &cancel_;
      volume::buildStore(*source, target.string(), options);
    }
    reused_ = reuse;
    {
      std::lock_guard lock(mutex_);
      storePath_ = target.string();
      status_ = reuse ? "reused the cached store" : "imported";
    }
    slicesDone_ = slicesTotal_.load();
    // A retrieved series' preview holds every slice once the dataset is ready: its last
    // arrivals (the files that landed after the last poll, placed alongside the import).
    // A folder's preview fill may still run (it reads the whole volume) and is not waited for.
    if (arrivals_ && previewThread_.joinable()) previewThread_.join();
    state_ = State::Ready;
  } catch (const volume::BuildCancelled&) {
    std::lock_guard lock(mutex_);
    error_ = path_ + ": import cancelled";
    state_ = State::Failed;
  } catch (const std::exception& e) {
    std::lock_guard lock(mutex_);
    error_ = e.what();
    if (error_.find(path_) == std::string::npos) error_ = path_ + ": " + error_;
    state_ = State::Failed;
  }
}

double Dataset::progress() const {
  if (state_ == State::Ready) return 1.0;
  const int64_t total = slicesTotal_.load();
  return total > 0 ? static_cast<double>(slicesDone_.load()) / static_cast<double>(total) : 0.0;
}

std::string Dataset::error() const {
  std::lock_guard lock(mutex_);
  return error_;
}

std::string Dataset::status() const {
  std::lock_guard lock(mutex_);
  if (state_ == State::Importing && status_ == "importing") {
    return fmt::format("importing {}/{} slices", slicesDone_.load(), slicesTotal_.load());
  }
  if (state_ == State::Importing && status_ == "retrieving") {
    return fmt::format("retrieving {}/{} slices", slicesDone_.load(), slicesTotal_.load());
  }
  return status_;
}

const volume::StoreReader* Dataset::store() {
  if (state_ != State::Ready) return nullptr;
  if (!store_) {
    std::string path;
    {
      std::lock_guard lock(mutex_);
      path = storePath_;
    }
    store_ = std::make_unique<volume::StoreReader>(path);
  }
  return store_.get();
}

std::string Dataset::storePath() const {
  std::lock_guard lock(mutex_);
  return storePath_;
}

const PreviewVolume* Dataset::preview() const {
  std::lock_guard lock(mutex_);
  return preview_.get();
}

std::vector<std::string> Dataset::warnings() const {
  std::lock_guard lock(mutex_);
  return warnings_;
}

dicom::PatientIdentity Dataset::patient() const {
  std::lock_guard lock(mutex_);
  return patient_;
}

VolumeInfo Dataset::info() const {
  std::lock_guard lock(mutex_);
  return info_;
}

std::vector<SourceWindow> Dataset::windows() const {
  std::lock_guard lock(mutex_);
  return info_.windows;
}

}  // namespace octoray::viewer
