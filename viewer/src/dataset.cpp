#include "octoray/viewer/dataset.h"

#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <xxhash.h>

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <limits>

#include "octoray/core/error.h"
#include "octoray/core/paths.h"
#include "octoray/dicom/formats.h"
#include "octoray/volume/store_builder.h"
#include "octoray/volume/store_format.h"

namespace octoray::viewer {
namespace fs = std::filesystem;

fs::path defaultCacheDir() { return userCacheDir(); }

bool isStoreFile(const fs::path& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) return false;
  std::ifstream in(path, std::ios::binary);
  char magic[sizeof(volume::kStoreMagic)] = {};
  in.read(magic, sizeof(magic));
  return in.gcount() == sizeof(magic) &&
         std::equal(magic, magic + sizeof(magic), volume::kStoreMagic);
}

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
    : grid_(info.dims, info.patientFromIndex) {
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
    slicesDone_.store(pk + 1, std::memory_order_release);
  }
}

double PreviewVolume::fraction() const {
  return static_cast<double>(slicesDone_.load()) / static_cast<double>(dims_[2]);
}

double PreviewVolume::sample(Vec3 q) const {
  const int64_t done = slicesDone_.load(std::memory_order_acquire);
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
  const int64_t z1 = std::min(i0[2] + 1, dims_[2] - 1);
  if (z1 >= done) return std::numeric_limits<double>::quiet_NaN();
  auto at = [&](int64_t x, int64_t y, int64_t z) {
    x = std::min(x, dims_[0] - 1);
    y = std::min(y, dims_[1] - 1);
    z = std::min(z, dims_[2] - 1);
    return static_cast<double>(values_[static_cast<std::size_t>((z * dims_[1] + y) * dims_[0] + x)]);
  };
  const int64_t x = i0[0], y = i0[1], z = i0[2];
  const double fx = t[0], fy = t[1], fz = t[2];
  const double c0 = (at(x, y, z) * (1 - fx) + at(x + 1, y, z) * fx) * (1 - fy) +
                    (at(x, y + 1, z) * (1 - fx) + at(x + 1, y + 1, z) * fx) * fy;
  const double c1 = (at(x, y, z + 1) * (1 - fx) + at(x + 1, y, z + 1) * fx) * (1 - fy) +
                    (at(x, y + 1, z + 1) * (1 - fx) + at(x + 1, y + 1, z + 1) * fx) * fy;
  return c0 * (1 - fz) + c1 * fz;
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
          const double v = sample(grid_.indexFromPatient.transformPoint(c + offset * plane.normal));
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

// ---- Dataset -------------------------------------------------------------------------------

Dataset::Dataset(const std::string& path, const fs::path& cacheDir) : path_(path), cacheDir_(cacheDir) {
  if (isStoreFile(path)) {
    store_ = std::make_unique<volume::StoreReader>(path);  // throws on damage
    storePath_ = path;
    const auto& h = store_->header();
    info_.dims = {h.dims[0], h.dims[1], h.dims[2]};
    info_.patientFromIndex = store_->patientFromIndex();
    info_.format = "octoray store";
    info_.sourcePath = path;
    try {
      const auto provenance = nlohmann::json::parse(store_->provenanceJson());
      const auto source = provenance.value("source", nlohmann::json::object());
      info_.description = source.value("description", "");
      info_.modality = source.value("modality", "");
      info_.seriesUid = source.value("seriesUid", "");
      info_.unit = source.value("unit", "");
    } catch (const nlohmann::json::exception&) {
      info_.description = fs::path(path).filename().string();
    }
    if (info_.description.empty()) info_.description = fs::path(path).filename().string();
    state_ = State::Ready;
    return;
  }
  status_ = "reading headers";
  import_ = std::thread([this] { importThread(); });
}

Dataset::~Dataset() {
  cancel_ = true;
  if (import_.joinable()) import_.join();
  if (previewThread_.joinable()) previewThread_.join();
}

void Dataset::importThread() {
  try {
    auto source = openVolume(path_);
    const VolumeInfo info = source->info();
    {
      std::lock_guard lock(mutex_);
      info_ = info;
      warnings_ = info.warnings;
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
    // The preview reads its own copy of the source while the import reads this one.
    auto preview = std::make_unique<PreviewVolume>(info, uint64_t{256} << 20);
    {
      std::lock_guard lock(mutex_);
      preview_ = std::move(preview);
    }
    previewThread_ = std::thread([this] {
      try {
        auto second = openVolume(path_);
        preview_->fill(*second, cancel_);
      } catch (const std::exception&) {
        // The import reports the same problem with the file; the preview just stops.
      }
    });
    const std::string key = storeCacheKey(*source);
    fs::create_directories(cacheDir_);
    const fs::path target = cacheDir_ / (key + ".octoray");
    bool reuse = false;
    if (isStoreFile(target)) {
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

}  // namespace octoray::viewer
