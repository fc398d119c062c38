#pragma once
// The working set (paper 003 §4 and §6): the cut through the store's octree that the
// raycaster draws, kept across frames and changed a little every frame, with the bricks it
// needs streamed from disk by the BrickLoader into the CPU BrickCache and from there into the
// GPU BrickPool. The render thread never reads the disk: what is not in the CPU cache is
// requested and the cut stays coarser there until a later frame finds it cached.
//
// Emptiness. A node is empty when nothing in it can show: in DVR when the TF's opacity is
// exactly zero over the node's [min, max] (the opacity summed-area table; gradient opacity and
// boundary enhancement only lower opacity, so the test stays sound), in isosurface mode when
// the isovalue lies outside [min, max], in MIP when the node's maximum lies below the lowest
// value of non-zero opacity. Empty nodes are not drawn, take no slot and are never loaded. The
// test runs every frame on the node table, so a new TF or isovalue reloads nothing.
//
// A node wants splitting when it is not a leaf of the store, its voxels project larger than
// `lodPixels` at its nearest point (0: always), it meets the view frustum, and the visibility
// feedback does not rule it out: with feedback on, only nodes the last feedback saw (enough
// rays reached them, or enough pixels of their box passed the occlusion query) are split, and
// with ray feedback only those where some ray wanted finer data than they hold. A node no
// feedback has covered yet (new this frame) waits for the next frame's.
//
// Never a hole: every leaf of the cut is drawn, from its own brick when that is in the pool,
// else from its nearest ancestor's (the spatial index's slot word carries the level offset and
// the raycaster samples the ancestor's brick over the leaf's box). The root brick is read when
// the working set is made and never leaves the pool, so every leaf has one.
//
// One frame (update()):
//  1. Cover. From the root down along the previous cut: a node that wants splitting stays
//     split if it was split last frame, or is split when each non-empty child has its brick in
//     the pool; otherwise it is a leaf. A leaf without its brick asks for it (step 2) unless it
//     wants its children instead (step 3); a leaf no feedback has seen for `mergeAfterFrames`
//     frames gives its slot up and is drawn from the root; a split node none of whose leaves
//     was seen for that long is merged back.
//  2. Fetch: leaves waiting for their own brick get it from the CPU cache when it is there
//     (else the loader is asked), within the upload budget and the pool's free slots.
//  3. Refine, largest projected voxel first: a leaf that wants splitting is split when its
//     missing non-empty children are all in the CPU cache, the pool has slots this frame does
//     not use, and the upload budget allows (the first split of a frame always may); otherwise
//     the missing children are requested from the loader with the leaf's priority. Below a
//     split node refinement continues in the same frame only where no feedback is needed.
//  4. The frame's requests replace the loader's queue (stale ones are cancelled); every brick
//     the cut is drawn from is pinned in the pool for the frame.
// After drawing, applyFeedback() records which leaves were seen; visibility propagates to
// ancestors. Unseen leaves are not refined and their slots are the first the pool reuses.

#include <array>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "octoray/gpu/brick_pool.h"
#include "octoray/gpu/camera.h"
#include "octoray/gpu/spatial_index.h"
#include "octoray/transfer/transfer_function.h"
#include "octoray/volume/brick_cache.h"
#include "octoray/volume/brick_loader.h"
#include "octoray/volume/store_reader.h"

namespace octoray::gpu {

enum class RaycastMode { Dvr, Iso, Mip };

// Which visibility feedback prunes the working set.
enum class Visibility { None, Occlusion, Rays, Both };
Visibility parseVisibility(const std::string& name);  // throws octoray::Error
const char* visibilityName(Visibility v);

// The 8 corners (patient space) of node `key`'s box clipped to the volume's domain (corner
// bits: x 1, y 2, z 4): what projection, culling and occlusion queries see of a node.
std::array<Vec3, 8> nodeBoxCorners(const volume::OctreeLayout& layout, const Mat4& patientFromIndex,
                                   const volume::NodeKey& key);

// Every node of `level` whose box meets the camera's view frustum, in node order, found from
// the root down with the test the working set culls with (a node is left out only when its box
// lies wholly outside one plane of the frustum, so every point a ray of the camera reaches is
// in one of them). The leaf level's nodes in view are the full-resolution volume as far as the
// picture can tell: ReferenceVolume::fromCut over them is the truth of a zoomed view of a store
// too large for fromStore.
std::vector<volume::NodeKey> nodesInFrustum(const volume::StoreReader& store, const Camera& camera,
                                            int level);

// MIP: the value from which the transfer function's opacity may be non-zero (+inf: never,
// -inf: everywhere; the TF is clamped at its ends). A maximum below it shows black: nodes whose
// range stays below it are empty to the working set, and the raycaster skips cells below it.
double mipVisibleFrom(const transfer::TransferFunction& tf);

struct WorkingSetOptions {
  RaycastMode mode = RaycastMode::Dvr;
  double lodPixels = 1.0;  // target projected voxel size; 0: finest level everywhere
  double isoValue = 0;     // RaycastMode::Iso
};

struct WorkingSetConfig {
  std::size_t uploadBytesPerFrame = std::size_t{64} << 20;  // 0: unlimited
  Visibility visibility = Visibility::Rays;
  int mergeAfterFrames = 4;  // frames unseen before a subtree is merged back
};

// One frame's figures (the C++ side of octoray-render --json and the viewer's status bar).
struct WorkingSetStats {
  int64_t leaves = 0;         // data leaves of the cut
  int64_t bricks = 0;         // distinct bricks they are drawn from (the working set's size; the
                              // root counts only where a seen leaf draws from it: unseen
                              // leaves drawn from it cost nothing, it is resident for good)
  int64_t proxyLeaves = 0;    // leaves drawn from an ancestor's brick (theirs missing or unseen)
  int64_t fetched = 0;        // own bricks of such leaves uploaded this frame
  int64_t emptyNodes = 0;     // nodes found empty while covering and refining
  int64_t visibleLeaves = 0;  // leaves the last feedback saw
  int64_t hiddenLeaves = 0;   // leaves the last feedback did not see
  int64_t unknownLeaves = 0;  // leaves with no feedback yet (new this frame, or feedback off)
  int64_t split = 0, merged = 0;  // nodes split / merged this frame
  int64_t hiddenWaiting = 0;  // split nodes unseen, merged back after mergeAfterFrames
  int64_t wantRefine = 0;     // leaves that want splitting after this frame (0: converged)
  int64_t waitingForData = 0; // of those, leaves whose children are not in the CPU cache
  int64_t stoppedByPool = 0, stoppedByBudget = 0, stoppedByError = 0;
  int64_t requestsIssued = 0;     // new loader requests this frame
  int64_t requestsQueued = 0;     // the frame's whole request set
  int64_t requestsCancelled = 0;  // queued last frame, no longer wanted and not loaded
  int64_t loaded = 0;             // bricks the loader finished since the last frame
  uint64_t bytesRead = 0;         // their compressed bytes in the store file
  int64_t uploaded = 0;           // bricks copied from the CPU cache to the pool
  uint64_t uploadBytes = 0;
  double selectMs = 0, uploadMs = 0;
  // Of those, what repack() copied this frame (0 unless it moved the cut), and its time:
  // included in uploaded, uploadBytes and uploadMs.
  int64_t repacked = 0;
  double repackMs = 0;
};

class WorkingSet {
 public:
  // Reads the root brick (the only read on the calling thread, ever) into the cache and the
  // pool, where it stays. Throws octoray::Error when the root cannot be read.
  WorkingSet(const volume::StoreReader& store, BrickPool& pool, volume::BrickCache& cache,
             volume::BrickLoader& loader, WorkingSetConfig config = {});

  // One frame: cover, merge, refine, request (see above). Never blocks on the disk.
  // Throws octoray::Error for a negative or non-finite lodPixels or a bad camera.
  const std::vector<CutLeaf>& update(const Camera& camera, const transfer::TransferFunction& tf,
                                     const WorkingSetOptions& options);
  // The per-leaf feedback of the frame drawn from the last update(): for each data leaf,
  // `seen` (the ray or query feedback saw it) and `wantsFiner` (ray feedback: some ray wanted
  // finer data there; occlusion feedback leaves it true).
  struct LeafFeedback {
    int64_t node = -1;
    bool seen = false;
    bool wantsFiner = true;
  };
  void applyFeedback(std::span<const LeafFeedback> feedback);

  const std::vector<CutLeaf>& cut() const { return cut_; }
  // Node ids of cut() in the same order.
  const std::vector<int64_t>& cutNodes() const { return cutNodes_; }
  const WorkingSetStats& stats() const { return stats_; }
  const WorkingSetConfig& config() const { return config_; }
  void setConfig(const WorkingSetConfig& config) { config_ = config; }
  // Loader errors (corrupted or unreadable bricks) since the last call, each node once; the
  // nodes concerned are never requested again and their ancestors stand in for them.
  std::vector<volume::LoadError> takeErrors();
  // True when the last frame changed nothing and waits for nothing: no split or merge, no
  // refinement or merge waiting for data or the upload budget, and (with feedback on) no leaf
  // without feedback, and the feedback it used was drawn for the current view (after a
  // camera, TF or LOD change the first frame decides from the previous view's feedback). A
  // working set held back by a full pool or by failed bricks is settled.
  bool settled() const;
  // Puts the bricks the cut is drawn from into the pool's first slots in node order (the root
  // first) and drops every other brick from the pool, so that a cut is drawn from the same
  // texture coordinates whatever the history: the same view gives the same pixels. (Where a
  // brick sits changes the float rounding of its texture coordinates, and with it the odd
  // pixel by one grey level.) Copies from the CPU cache only, never the disk; returns false,
  // changing nothing, when a brick is not cached. Call between update() and drawing; the
  // frame's upload statistics count the copies. A no-op when the slots are already so.
  bool repack();

 private:
  struct NodeState {
    uint64_t feedbackFrame = 0;  // frame of the last feedback that covered the node
    uint64_t seenFrame = 0;      // frame of the last feedback that saw it
    uint64_t finerFrame = 0;     // frame of the last feedback where a ray wanted finer
    uint64_t hiddenMergeFrame = 0;  // frame it was merged back because no leaf below was seen
  };
  // A digest of what the view depends on (camera, TF opacity, mode, isovalue, LOD): a node
  // merged back for being unseen is not split again for being seen until it changes (rays
  // that reach it only through its empty children would otherwise split and merge it over and
  // over).
  static uint64_t viewDigest(const Camera& camera, const transfer::TransferFunction& tf,
                             const WorkingSetOptions& options);
  bool wantsSplit(int64_t id, double pixels, bool inFrustum) const;
  bool wantsSplitIgnoringFeedback(int64_t id, double pixels, bool inFrustum) const;
  // The nearest ancestor-or-self with its brick in the pool, and how many levels up it is.
  std::pair<int64_t, int> nearestResidentAncestor(int64_t id) const;
  // The brick a leaf of the cut is drawn from, and how many levels up its node is: the
  // nearest resident ancestor-or-self, or for an `unseen` leaf giving its slot up, the root.
  std::pair<int64_t, int> drawnFrom(int64_t id, bool unseen) const;
  // With feedback on: no ray saw the node for mergeAfterFrames frames.
  bool hiddenNow(int64_t id) const;
  bool upload(const volume::Brick& brick);  // into the pool; false when it is full

  const volume::StoreReader& store_;
  BrickPool& pool_;
  volume::BrickCache& cache_;
  volume::BrickLoader& loader_;
  WorkingSetConfig config_;
  const volume::OctreeLayout& layout_;
  std::shared_ptr<const volume::Brick> root_;  // resident for good (repack() puts it back)

  std::vector<CutLeaf> cut_;
  std::vector<int64_t> cutNodes_;
  std::unordered_map<int64_t, NodeState> state_;
  std::unordered_set<int64_t> failed_;
  std::unordered_set<int64_t> lastRequests_;
  std::vector<volume::LoadError> errors_;
  std::unordered_set<int64_t> innerNodes_;  // the last frame's split nodes (cut ancestors)
  uint64_t frame_ = 0;
  uint64_t lastFeedbackFrame_ = 0;
  uint64_t viewDigest_ = 0;
  uint64_t viewChangedFrame_ = 0;
  int64_t pendingMerges_ = 0;
  // The last update decided from feedback drawn before the view changed (the feedback delay
  // of one frame): its "nothing to refine" says nothing about the new view.
  bool staleFeedback_ = false;
  WorkingSetStats stats_;
  // Per frame: emptiness and projection of the current view (working_set.cpp).
  struct FrameContext;
  FrameContext* context_ = nullptr;
};

}  // namespace octoray::gpu
