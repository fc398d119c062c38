#pragma once
// Building the octree store from a VolumeSource in one streaming pass: slabs flow into a
// window of slices per level; each level's finished row of bricks is cut (borders replicated),
// measured (min/max), compressed and appended; each level's slices are 2x box-filtered into
// the next coarser level as they arrive. Peak memory is bounded by the windows and a
// per-batch brick budget, not by the volume size.

#include <atomic>
#include <cstdint>
#include <functional>
#include <string>

#include "octoray/dicom/volume_source.h"
#include "octoray/volume/store_format.h"

namespace octoray::volume {

struct BuildOptions {
  int brickSize = 32;                  // B: 16, 32 or 64
  int border = 1;                      // A: 1 (trilinear) or 2 (central differences)
  bool gradients = false;              // precompute RGBA8 gradients (paper §4)
  Codec codec = Codec::Lz4;
  int zstdLevel = 3;
  uint64_t memoryBudgetBytes = uint64_t{1} << 30;
  // UInt16 needs integer values: CT in HU is stored as HU + 1024, clamped to [0, 65535].
  // Auto picks UInt16 for integer-valued sources with unit HU, Float32 otherwise.
  enum class Format { Auto, UInt16, Float32 } format = Format::Auto;
  std::string provenanceJson = "{}";   // extra provenance (series UID, description, ...)
  // sourceContentHash(source.info().sourceFiles), recorded as the provenance's
  // source.contentHash when set: what octoray-batch compares to skip a store already built.
  std::string sourceContentHash;
  std::function<void(int64_t slicesDone, int64_t slicesTotal)> progress;
  const std::atomic<bool>* cancel = nullptr;  // set to stop; the build throws BuildCancelled
};

struct BuildReport {
  int64_t voxels = 0;
  int64_t nodes = 0;
  int64_t constantNodes = 0;
  int64_t clampedSamples = 0;  // values outside the UInt16 range (reported, never silent)
  uint64_t bytesOnDisk = 0;
  uint64_t uncompressedBytes = 0;
  double seconds = 0;
  int levels = 0;
  SampleFormat sampleFormat = SampleFormat::UInt16;
};

class BuildCancelled : public std::runtime_error {
 public:
  BuildCancelled() : std::runtime_error("build cancelled") {}
};

// Builds the store at `outPath` (through a temporary file in the same folder, renamed when
// complete; any failure or cancellation removes it and leaves an existing `outPath` as it
// was). Throws octoray::Error naming the file on I/O or source errors.
BuildReport buildStore(VolumeSource& source, const std::string& outPath,
                       const BuildOptions& options = {});

}  // namespace octoray::volume
