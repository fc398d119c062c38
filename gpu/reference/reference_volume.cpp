#include "octoray/gpu/reference/reference_volume.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <span>

#include "octoray/core/error.h"
#include "octoray/dicom/volume_source.h"
#include "octoray/volume/store_reader.h"

namespace octoray::gpu::reference {
namespace {

// Sample count of `dims`, or an error when it cannot be held in memory as float.
std::size_t checkedSampleCount(const std::array<int64_t, 3>& dims, const std::string& path) {
  for (int64_t d : dims) {
    if (d < 1)
      throw Error(path, fmt::format("volume dims {}x{}x{} are empty", dims[0], dims[1], dims[2]));
  }
  const double samples =
      static_cast<double>(dims[0]) * static_cast<double>(dims[1]) * static_cast<double>(dims[2]);
  if (samples * sizeof(float) >
      static_cast<double>(std::numeric_limits<std::ptrdiff_t>::max() / 2)) {
    throw Error(path, fmt::format("volume {}x{}x{} is too large to hold in memory", dims[0],
                                  dims[1], dims[2]));
  }
  return static_cast<std::size_t>(dims[0] * dims[1] * dims[2]);
}

}  // namespace

ReferenceVolume::ReferenceVolume(std::array<int64_t, 3> dims, const Mat4& patientFromIndex,
                                 std::vector<float> values)
    : dims_(dims), patientFromIndex_(patientFromIndex), values_(std::move(values)) {
  if (values_.size() != checkedSampleCount(dims_, "")) {
    throw Error("", fmt::format("{} values for a {}x{}x{} volume", values_.size(), dims_[0],
                                dims_[1], dims_[2]));
  }
  patientFromIndex_.inverseAffine();  // throws for a singular affine
}

ReferenceVolume ReferenceVolume::fromSource(VolumeSource& source) {
  const VolumeInfo& info = source.info();
  std::vector<float> values(checkedSampleCount(info.dims, info.sourcePath));
  const int64_t slice = info.sliceSamples();
  // Slabs of about 16 MiB keep the source's read calls large without a second full copy.
  const int64_t slabSlices = std::max<int64_t>(1, (int64_t{4} << 20) / slice);
  for (int64_t first = 0; first < info.dims[2]; first += slabSlices) {
    const int64_t count = std::min(slabSlices, info.dims[2] - first);
    source.readSlab(
        first, count,
        std::span<float>(values.data() + first * slice, static_cast<std::size_t>(count * slice)));
  }
  return ReferenceVolume(info.dims, info.patientFromIndex, std::move(values));
}

ReferenceVolume ReferenceVolume::fromStore(const volume::StoreReader& store) {
  const volume::OctreeLayout& layout = store.layout();
  const int leaf = layout.leafLevel();
  const volume::Index3 dims = layout.levelDims(leaf);
  std::vector<float> values(checkedSampleCount(dims, store.path()));
  const int b = layout.brickSize();
  const int a = layout.border();
  const int64_t edge = layout.storedEdge();
  const int64_t first = layout.levelNodeOffset(leaf);
  const int64_t end = first + layout.levelBricks(leaf)[0] * layout.levelBricks(leaf)[1] *
                                  layout.levelBricks(leaf)[2];
  for (int64_t id = first; id < end; ++id) {
    const volume::NodeKey key = layout.nodeKey(id);
    const volume::Brick brick = store.readBrick(id);
    const volume::Index3 origin{key.brick[0] * b, key.brick[1] * b, key.brick[2] * b};
    // The brick's interior, clipped to the volume (the last brick on an axis may be partial).
    const std::array<int64_t, 3> extent{std::min<int64_t>(b, dims[0] - origin[0]),
                                        std::min<int64_t>(b, dims[1] - origin[1]),
                                        std::min<int64_t>(b, dims[2] - origin[2])};
    for (int64_t z = 0; z < extent[2]; ++z) {
      for (int64_t y = 0; y < extent[1]; ++y) {
        const int64_t stored = a + edge * ((y + a) + edge * (z + a));
        float* out =
            values.data() + origin[0] + dims[0] * ((origin[1] + y) + dims[1] * (origin[2] + z));
        for (int64_t x = 0; x < extent[0]; ++x) {
          const std::size_t s = static_cast<std::size_t>(stored + x);
          out[x] = brick.format == volume::SampleFormat::UInt16
                       ? static_cast<float>(store.physical(brick.u16[s]))
                       : brick.f32[s];
        }
      }
    }
  }
  return ReferenceVolume(dims, store.patientFromIndex(), std::move(values));
}

double ReferenceVolume::sample(double i, double j, double k) const {
  // Clamp to the outermost centres (edge samples extend to the domain's faces), then blend
  // the 8 neighbours; the upper neighbour of an edge sample is the sample itself.
  const double pi = std::clamp(i, 0.0, static_cast<double>(dims_[0] - 1));
  const double pj = std::clamp(j, 0.0, static_cast<double>(dims_[1] - 1));
  const double pk = std::clamp(k, 0.0, static_cast<double>(dims_[2] - 1));
  const int64_t i0 = static_cast<int64_t>(pi), j0 = static_cast<int64_t>(pj),
                k0 = static_cast<int64_t>(pk);
  const double fi = pi - static_cast<double>(i0), fj = pj - static_cast<double>(j0),
               fk = pk - static_cast<double>(k0);
  const int64_t si = i0 + 1 < dims_[0] ? 1 : 0;
  const int64_t sj = j0 + 1 < dims_[1] ? dims_[0] : 0;
  const int64_t sk = k0 + 1 < dims_[2] ? dims_[0] * dims_[1] : 0;
  const float* p = values_.data() + (i0 + dims_[0] * (j0 + dims_[1] * k0));
  const double c00 = p[0] + fi * (static_cast<double>(p[si]) - p[0]);
  const double c10 = p[sj] + fi * (static_cast<double>(p[sj + si]) - p[sj]);
  const double c01 = p[sk] + fi * (static_cast<double>(p[sk + si]) - p[sk]);
  const double c11 = p[sk + sj] + fi * (static_cast<double>(p[sk + sj + si]) - p[sk + sj]);
  const double c0 = c00 + fj * (c10 - c00);
  const double c1 = c01 + fj * (c11 - c01);
  return c0 + fk * (c1 - c0);
}

}  // namespace octoray::gpu::reference
