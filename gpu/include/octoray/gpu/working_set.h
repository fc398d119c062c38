#pragma once
// The static working set (paper §4, without the dynamic parts of §6): a cut through the
// store's octree chosen on the CPU for one view and transfer function.
//
// A node is empty when nothing in it can show: in DVR when the TF's opacity is exactly zero
// over the node's [min, max] (the opacity summed-area table; gradient opacity and boundary
// enhancement only lower opacity, so the test stays sound), in isosurface mode when the
// isovalue lies outside [min, max], in MIP when the node's maximum lies below the lowest value
// of non-zero opacity (such a node can only raise a maximum that stays invisible). Empty
// nodes are not refined and take no pool slot.
//
// Refinement runs largest-first on a priority queue keyed by the node's projected voxel size
// in pixels (its voxel edge in mm, scaled by the image height over the visible height at the
// node's nearest distance): a non-empty node is split while that size exceeds `lodPixels`
// (0: always split down to the leaf level, the reference's resolution), while the node can be
// seen (inside the view frustum), and while the pool has slots for its non-empty children.

#include <cstdint>
#include <vector>

#include "octoray/gpu/camera.h"
#include "octoray/transfer/transfer_function.h"
#include "octoray/volume/store_reader.h"

namespace octoray::gpu {

enum class RaycastMode { Dvr, Iso, Mip };

struct WorkingSetOptions {
  RaycastMode mode = RaycastMode::Dvr;
  double lodPixels = 1.0;  // target projected voxel size; 0: finest level everywhere
  double isoValue = 0;     // RaycastMode::Iso
  int64_t slotCapacity = 0;  // pool slots; 0: unlimited
};

struct WorkingSet {
  std::vector<volume::NodeKey> dataNodes;  // non-empty leaves of the cut, front of the queue first
  int64_t emptyNodes = 0;     // nodes found empty (not refined, no slot)
  int64_t culledNodes = 0;    // non-empty nodes kept coarse because they are outside the view
  int64_t capacityLimited = 0;  // non-empty nodes kept coarse because the pool was full
  double finestProjectedPixels = 0;  // largest projected voxel size among the data leaves
};

// Throws octoray::Error for a negative or non-finite lodPixels.
WorkingSet selectWorkingSet(const volume::StoreReader& store, const Camera& camera,
                            const transfer::TransferFunction& tf, const WorkingSetOptions& options);

}  // namespace octoray::gpu
