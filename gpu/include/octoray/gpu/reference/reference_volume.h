#pragma once
// The whole volume at full resolution in memory, as float physical values (HU for CT), for
// the CPU reference renderer. Loaded slab by slab from any VolumeSource, or from the leaf
// bricks of an octree store (the samples the GPU renderer will see).
//
// Or the volume as an LOD cut of the store holds it (fromCut): the leaves of a GPU working
// set, each drawn from its own brick or an ancestor's, at that brick's level. Then a point is
// the trilinear interpolant of the level whose leaf holds it (octree_layout.h: level sample s
// sits at leaf index (s + 0.5) * 2^(L-1-l) - 0.5), clamped at the level's faces as the
// brick's replicated border is; a point no leaf holds (a node the cut left out as empty) is
// NaN, which classifies as transparent. Only the cut's bricks are read: the reference for a
// converged picture of a volume far larger than memory.
//
// Sampling: voxel centres sit at integer indices; the domain is [-0.5, dim - 0.5] per axis.
// Between centres the value is the trilinear interpolant; between the outermost centres and
// the domain's faces it is clamped (the edge samples extend to the faces), as GL's
// CLAMP_TO_EDGE does on a texture holding the volume.

#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "octoray/core/geometry.h"
#include "octoray/volume/octree_layout.h"

namespace octoray {
class VolumeSource;
}
namespace octoray::volume {
class StoreReader;
}

namespace octoray::gpu::reference {

// One leaf of an LOD cut: the node, and how many levels up the node whose brick it is drawn
// from lies (0: its own brick). gpu::CutLeaf's key and dataLevelsUp.
struct CutLeafRef {
  volume::NodeKey key;
  int dataLevelsUp = 0;
};

class CutSamples;

class ReferenceVolume {
 public:
  // Throws octoray::Error for empty dims or a value count that does not match.
  ReferenceVolume(std::array<int64_t, 3> dims, const Mat4& patientFromIndex,
                  std::vector<float> values);

  // Reads every slab of `source` (throws octoray::Error from the source, or when the volume
  // does not fit the address space).
  static ReferenceVolume fromSource(VolumeSource& source);
  // Reads every leaf brick of the store and keeps each brick's interior (values in physical
  // units through the store's value mapping).
  static ReferenceVolume fromStore(const volume::StoreReader& store);
  // fromStore for an octree store, else fromSource over what openVolume reads at `path`.
  static ReferenceVolume fromPath(const std::string& path);
  // The cut's leaves (see above); reads each brick they are drawn from once. Throws
  // octoray::Error for a leaf that is not a node of the store, an ancestor above the root, two
  // leaves that overlap, or a brick that cannot be read.
  static ReferenceVolume fromCut(const volume::StoreReader& store,
                                 std::span<const CutLeafRef> leaves);

  const std::array<int64_t, 3>& dims() const { return dims_; }
  // True for fromCut(): no full-resolution samples (at() and values() hold none).
  const Mat4& patientFromIndex() const { return patientFromIndex_; }
  float at(int64_t i, int64_t j, int64_t k) const {
    return values_[static_cast<std::size_t>(i + dims_[0] * (j + dims_[1] * k))];
  }
  bool isCut() const { return cut_ != nullptr; }
  // True for a cut with a leaf drawn from a level above the leaf level (its interpolant has
  // other cell planes than the full volume's); false for a leaf-level cut and a full volume.
  bool hasCoarseLeaves() const;
  const std::vector<float>& values() const { return values_; }
  // Trilinear interpolant at index-space point p (clamped as above), in double precision.
  double sample(double i, double j, double k) const;
  // The interpolant's gradient in index space (value units per leaf voxel), by central
  // differences: of +-1 voxel for a full volume; for a cut, of +-h voxels of the level whose
  // leaf holds p, read from that leaf's brick alone (as the GPU does: h = 1 with a border of
  // two samples or more, 0.5 with one). Zero where no leaf holds p.
  Vec3 gradientIndex(const Vec3& p) const;

 private:
  ReferenceVolume(std::shared_ptr<const CutSamples> cut, std::array<int64_t, 3> dims,
                  const Mat4& patientFromIndex);

  std::array<int64_t, 3> dims_;
  Mat4 patientFromIndex_;
  std::vector<float> values_;
  std::shared_ptr<const CutSamples> cut_;
};

}  // namespace octoray::gpu::reference
