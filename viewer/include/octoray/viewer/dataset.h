#pragma once
// What the viewer has open. An octree store opens at once. Anything else octoray-import reads
// (a DICOM folder, DICOMDIR or file, NRRD, MetaImage, NIfTI, TIFF) is imported on a background
// thread into a store in the cache folder, with progress; meanwhile a second reader fills a
// preview volume slice by slice, so the MPR views show the source's slices while the import
// runs. A store already imported is reused: stores are named by a key made of the series UID,
// the grid (dimensions and index-to-patient affine) and a hash of the first, middle and last
// slices' samples — not by the path the data came from.

#include <atomic>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "octoray/dicom/dicom_series.h"
#include "octoray/dicom/volume_source.h"
#include "octoray/viewer/mpr.h"
#include "octoray/volume/store_reader.h"

namespace octoray::viewer {

// $OCTORAY_CACHE, else $XDG_CACHE_HOME/octoray, else ~/.cache/octoray.
std::filesystem::path defaultCacheDir();

// The cache key of a source (hex): see above. Reads three slices.
std::string storeCacheKey(VolumeSource& source);

// Whether `path` is an octree store (by its magic bytes).
bool isStoreFile(const std::filesystem::path& path);

// The source's slices held in memory while the import runs, downsampled by a power of two
// (the same box filter as the octree's levels) so that it fits `budgetBytes`.
class PreviewVolume {
 public:
  PreviewVolume(const VolumeInfo& info, uint64_t budgetBytes);
  const Grid& grid() const { return grid_; }
  int factor() const { return factor_; }
  // Reads the whole source slab by slab (on the calling thread: the preview thread) until
  // done or `cancel` is set; slices become visible as they are filled.
  void fill(VolumeSource& source, const std::atomic<bool>& cancel);
  // A slice like StoreSlicer::slice (level ignored); NaN where the preview has no data yet.
  Slice slice(const SliceRequest& request) const;
  double fraction() const;

 private:
  double sample(Vec3 leafIndex) const;  // NaN outside or not yet read
  Grid grid_;
  int factor_ = 1;
  std::array<int64_t, 3> dims_{1, 1, 1};
  std::vector<float> values_;
  std::atomic<int64_t> slicesDone_{0};  // preview slices complete
};

class Dataset {
 public:
  enum class State { Importing, Ready, Failed };

  // Opens a store now (throws octoray::Error when it is damaged), or starts the background
  // import of any other input (its errors arrive through state() and error()).
  Dataset(const std::string& path, const std::filesystem::path& cacheDir);
  ~Dataset();  // cancels a running import (the partial store is removed by the builder)
  Dataset(const Dataset&) = delete;
  Dataset& operator=(const Dataset&) = delete;

  const std::string& path() const { return path_; }
  State state() const { return state_.load(); }
  // Import progress in [0, 1]; 1 once ready.
  double progress() const;
  std::string error() const;
  // The import's phase in words ("reading headers", "importing 35/140 slices", ...).
  std::string status() const;
  // The store once ready (opened on the thread that calls this after the import finished).
  const volume::StoreReader* store();
  std::string storePath() const;
  bool reusedCache() const { return reused_.load(); }
  // While importing: the preview (null before the source's headers are read, and for stores).
  const PreviewVolume* preview() const;
  // What the source is, once known (description, dims, spacing, modality, UID).
  VolumeInfo info() const;
  // For a DICOM source: patient name, ID, dates from its first image (empty for stores, which
  // keep no identity).
  dicom::PatientIdentity patient() const;
  // What the reader had to decide or repair, and every file of a DICOM source left out of the
  // volume (split off into another part of the series, or unreadable), by name.
  std::vector<std::string> warnings() const;

 private:
  void importThread();

  std::string path_;
  std::filesystem::path cacheDir_;
  std::atomic<State> state_{State::Importing};
  std::atomic<int64_t> slicesDone_{0}, slicesTotal_{0};
  std::atomic<bool> cancel_{false}, reused_{false};
  mutable std::mutex mutex_;
  std::string error_, status_, storePath_;
  VolumeInfo info_;
  dicom::PatientIdentity patient_;
  std::vector<std::string> warnings_;
  std::unique_ptr<PreviewVolume> preview_;
  std::unique_ptr<volume::StoreReader> store_;
  std::thread import_, previewThread_;
};

}  // namespace octoray::viewer
