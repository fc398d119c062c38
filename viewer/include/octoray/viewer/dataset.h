#pragma once
// What the viewer has open. An octree store opens at once. Anything else octoray-import reads
// (a DICOM folder, DICOMDIR or file, NRRD, MetaImage, NIfTI, TIFF) is imported on a background
// thread into a store in the cache folder, with progress; meanwhile a second reader fills a
// preview volume slice by slice, so the MPR views show the source's slices while the import
// runs. A store already imported is reused: stores are named by a key made of the series UID,
// the grid (dimensions and index-to-patient affine) and a hash of the first, middle and last
// slices' samples — not by the path the data came from.
//
// A series retrieved from a PACS opens while it arrives (Dataset(IncomingSeries)): the
// server's instance list gives every slice's position before its pixels come, so the preview
// has the series' whole grid at once and each slice appears in the MPR views as its file
// lands; the import starts when the last one has.

#include <atomic>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "octoray/dicom/dicom_series.h"
#include "octoray/dicom/volume_source.h"
#include "octoray/viewer/mpr.h"
#include "octoray/volume/store_reader.h"
#include "octoray/volume/value_histogram.h"

namespace octoray::viewer {

// $OCTORAY_CACHE, else $XDG_CACHE_HOME/octoray, else ~/.cache/octoray.
std::filesystem::path defaultCacheDir();

// The cache key of a source (hex): see above. Reads three slices.
std::string storeCacheKey(VolumeSource& source);

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
  // Adds source slice `k` (dims[0] x dims[1] values), in any order, from one thread; a
  // preview slice becomes visible once all the source slices it averages have come.
  void addSlice(int64_t k, std::span<const float> values);
  // A slice like StoreSlicer::slice (level ignored); NaN where the preview has no data yet.
  Slice slice(const SliceRequest& request) const;
  double fraction() const;
  // The values of the slices shown so far, counted in `bins` equal bins over their range
  // [lo, hi] (what the auto window/level reads while a volume arrives); empty before any.
  // Where they hold more than kHistogramSamples, every n-th row in order, so that at most that
  // many are read: the store's histogram reads as many (volume::storeHistogram), binned alike.
  static constexpr auto kHistogramSamples = static_cast<std::size_t>(volume::kHistogramSamples);
  std::vector<int> histogram(int bins, double& lo, double& hi) const;

 private:
  // NaN outside or where a slice it needs is not in `done` (a snapshot of sliceDone_).
  double sample(Vec3 leafIndex, const std::vector<uint8_t>& done) const;
  void publish(int64_t previewSlice);    // the slice's values are final: let readers see it
  Grid grid_;
  std::array<int64_t, 3> sourceDims_{1, 1, 1};
  int factor_ = 1;
  std::array<int64_t, 3> dims_{1, 1, 1};
  std::vector<float> values_;
  std::unique_ptr<std::atomic<bool>[]> sliceDone_;  // per preview slice
  std::atomic<int64_t> slicesDone_{0};              // how many are done
  // addSlice(): which source slices came, and the sums of preview slices still incomplete.
  std::vector<uint8_t> sourceSeen_;
  std::vector<int> sourcesIn_;
  std::vector<std::vector<double>> partialSums_;
};

// A series on its way into `folder` (one file per slice, under its final name only once
// complete): what the PACS listed, and how the retrieval ends. The retrieval's thread writes
// `state` and `error`; a Dataset reads them and looks for the files itself.
struct IncomingSeries {
  struct Slice {
    std::filesystem::path file;
    std::optional<std::array<double, 3>> position;     // ImagePositionPatient, if listed
    std::optional<std::array<double, 6>> orientation;  // ImageOrientationPatient, if listed
  };
  enum class State { Arriving, Complete, Failed };

  std::filesystem::path folder;
  std::string description;   // for the status line, e.g. the series description
  std::vector<Slice> slices;  // as listed
  std::atomic<State> state{State::Arriving};
  std::mutex mutex;
  std::string error;  // when Failed (guarded by mutex)

  void fail(const std::string& why) {
    {
      std::lock_guard lock(mutex);
      error = why;
    }
    state = State::Failed;
  }
};

// The grid of a listed series before its pixels arrive, by the import's rules: the slices of
// the majority orientation evenly spaced (the slice step from the end slices: a tilted stack
// is a shear), no two at one position; the in-plane columns from `file`, a file of the series
// that has arrived. Returns the grid and each listed slice's index in it (-1: not in the
// grid), or nullopt with `why`: with `listingFails` when the listing gives no such grid (no
// positions, uneven gaps, ...: the preview waits for the import), else because `file` is not
// one slice of the listed orientation (the next file that lands may give it).
struct IncomingGrid {
  VolumeInfo info;
  std::vector<int64_t> indexOfSlice;
};
std::optional<IncomingGrid> incomingGrid(const IncomingSeries& series, const VolumeInfo& file,
                                         std::string& why, bool& listingFails);

class Dataset {
 public:
  enum class State { Importing, Ready, Failed };

  // Opens a store now (throws octoray::Error when it is damaged), or starts the background
  // import of any other input (its errors arrive through state() and error()).
  Dataset(const std::string& path, const std::filesystem::path& cacheDir);
  // A series still arriving into incoming->folder: the preview fills as its files land, the
  // import of the folder starts once the retrieval is complete, and the preview holds every
  // slice that landed by the time the dataset is Ready.
  Dataset(std::shared_ptr<IncomingSeries> incoming, const std::filesystem::path& cacheDir);
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
  // The display windows the source names (VolumeInfo::windows), once its headers are read.
  std::vector<SourceWindow> windows() const;
  // For a DICOM source: patient name, ID, dates from its first image (empty for stores, which
  // keep no identity).
  dicom::PatientIdentity patient() const;
  // What the reader had to decide or repair, and every file of a DICOM source left out of the
  // volume (split off into another part of the series, or unreadable), by name.
  std::vector<std::string> warnings() const;

 private:
  void importThread();
  // Incoming series: previews the slices as they land; returns when the retrieval ended
  // (false, with the error set, when it failed or was cancelled).
  bool receive();
  struct Arrivals;
  void placeArrived(Arrivals& arrivals);  // looks once at every listed file not seen yet

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
  std::shared_ptr<IncomingSeries> incoming_;
  std::unique_ptr<Arrivals> arrivals_;
  std::thread import_, previewThread_;
};

}  // namespace octoray::viewer
