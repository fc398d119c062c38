#pragma once
// The GPU brick pool (paper 003 §4, the level-1 cache): bricks of one store in slots of a
// single 3D texture (R16, or R32F for float stores), an optional RGBA8 gradient texture with
// the same slot layout, and per slot the (min, max) of each 8^3-voxel cell (DVR skips cells
// whose values all map to zero opacity).
//
// Budget: the slot grid is the box of slots that holds the most slots within the byte budget
// (not whole layers only), so the pool uses its budget to within one slot row in practice.
//
// Residency. The pool only keeps books; the working set decides. Each frame starts with
// beginFrame(); nodes the frame draws are pin()ned; allocate() gives a slot that no pinned
// node uses: a never-used one first, then the one whose node was seen longest ago (a node
// the visibility feedback last saw is kept over one it never saw; ties by last use). A pinned
// slot is never handed out in the same frame, so a frame's cut stays resident while it draws.
// Every call needs the GL context current on the calling thread.

#include <cstddef>
#include <cstdint>
#include <unordered_map>
#include <vector>

#include "octoray/gpu/gl_program.h"
#include "octoray/volume/store_reader.h"

namespace octoray::gpu {

inline constexpr int kCellVoxels = 8;  // edge of the cells a slot's value ranges are kept for

struct BrickPoolStats {
  int64_t slots = 0;           // capacity
  int64_t slotsUsed = 0;       // slots holding a brick
  std::size_t budgetBytes = 0;
  std::size_t bytes = 0;       // slots * slotBytes (what the textures hold)
  std::size_t slotBytes = 0;
  uint64_t uploads = 0;        // since construction
  uint64_t uploadBytes = 0;    // texture bytes uploaded since construction
  uint64_t evictions = 0;      // bricks replaced by another since construction
};

class BrickPool {
 public:
  // Allocates the textures; throws octoray::Error when the budget cannot hold one slot, when
  // gradients are asked for and the store has none, or on a GL error.
  BrickPool(const volume::StoreReader& store, std::size_t budgetBytes, bool gradients);
  BrickPool(const BrickPool&) = delete;
  BrickPool& operator=(const BrickPool&) = delete;

  void beginFrame();
  uint64_t frame() const { return frame_; }

  // The slot holding node `id`, or -1.
  int64_t slotOf(int64_t id) const;
  bool resident(int64_t id) const { return slotOf(id) >= 0; }
  // The node in `slot`, or -1.
  int64_t nodeIn(uint32_t slot) const { return slots_[slot].node; }

  // Marks a resident node as used by this frame (no-op for a node not resident); `seen`:
  // the visibility feedback saw it this frame (eviction keeps seen nodes longer).
  void pin(int64_t id);
  void markSeen(int64_t id);
  // Slots not pinned this frame (that allocate() may hand out).
  int64_t freeSlots() const;

  // Puts the brick of node brick.nodeId into a slot that is not pinned this frame and pins
  // it. `slot` is -1 when every slot is pinned; `evicted` the node whose brick it replaced.
  struct Placement {
    int64_t slot = -1;
    int64_t evicted = -1;
  };
  Placement upload(const volume::Brick& brick);

  // Forgets every brick (e.g. after an error left the textures in doubt).
  void clear();

  const volume::StoreReader& store() const { return store_; }
  bool floatSamples() const { return floatPool_; }
  bool hasGradients() const { return gradients_; }
  int edge() const { return edge_; }
  const std::array<int64_t, 3>& slotGrid() const { return slotGrid_; }
  int cellsPerBrick() const { return cellsPerBrick_; }
  GLuint valueTexture() const { return values_.id(); }
  GLuint gradientTexture() const { return gradientTexture_.id(); }
  GLuint cellRangeTexture() const { return cellRange_.id(); }
  BrickPoolStats stats() const;

 private:
  struct Slot {
    int64_t node = -1;
    uint64_t lastPinned = 0;  // frame
    uint64_t lastSeen = 0;    // frame
  };
  int64_t takeSlot();

  const volume::StoreReader& store_;
  std::size_t budgetBytes_ = 0;
  bool floatPool_ = false;
  bool gradients_ = false;
  int edge_ = 0;
  std::size_t slotBytes_ = 0;
  std::array<int64_t, 3> slotGrid_{1, 1, 1};
  int64_t capacity_ = 0;
  int cellsPerBrick_ = 0;
  GlTexture values_{GL_TEXTURE_3D};
  GlTexture gradientTexture_{GL_TEXTURE_3D};
  GlTexture cellRange_{GL_TEXTURE_3D};

  std::vector<Slot> slots_;
  std::unordered_map<int64_t, uint32_t> slotOfNode_;
  uint64_t frame_ = 1;
  int64_t pinnedCount_ = 0;
  // Eviction order of this frame (built on the first allocation that needs it): slots not
  // pinned, the best victim last.
  std::vector<uint32_t> victims_;
  bool victimsBuilt_ = false;
  uint64_t uploads_ = 0, uploadBytes_ = 0, evictions_ = 0;
};

// The slot grid for `wanted` slots of `edge`^3 texels when no axis may exceed `perAxis`
// slots: the box with the most slots not above `wanted` (ties: the flattest), for tests.
std::array<int64_t, 3> slotGridFor(int64_t wanted, int64_t perAxis);

}  // namespace octoray::gpu
