#include "octoray/gpu/brick_pool.h"

#include <epoxy/gl.h>
#include <fmt/format.h>

#include <algorithm>
#include <tuple>

#include "octoray/core/error.h"
#include "octoray/gpu/gl_context.h"
#include "octoray/gpu/spatial_index.h"

namespace octoray::gpu {
namespace {

// Per cell of kCellVoxels^3 voxels of a brick, the smallest and largest stored sample that a
// trilinear sample inside the cell can read (the cell's voxels and one more on each side,
// from the brick's border), as (min, max) pairs in x-fastest cell order.
template <typename T>
std::vector<T> cellRanges(const std::vector<T>& samples, int edge, int brickSize, int border) {
  const int cells = brickSize / kCellVoxels;
  std::vector<T> ranges(static_cast<std::size_t>(cells) * cells * cells * 2);
  const auto at = [&](int x, int y, int z) {
    return samples[static_cast<std::size_t>(x) +
                   static_cast<std::size_t>(edge) * (static_cast<std::size_t>(y) +
                                                     static_cast<std::size_t>(edge) * static_cast<std::size_t>(z))];
  };
  std::size_t out = 0;
  for (int cz = 0; cz < cells; ++cz) {
    for (int cy = 0; cy < cells; ++cy) {
      for (int cx = 0; cx < cells; ++cx) {
        T lo = at(border + cx * kCellVoxels, border + cy * kCellVoxels, border + cz * kCellVoxels);
        T hi = lo;
        for (int z = border + cz * kCellVoxels - 1; z <= border + (cz + 1) * kCellVoxels; ++z) {
          for (int y = border + cy * kCellVoxels - 1; y <= border + (cy + 1) * kCellVoxels; ++y) {
            for (int x = border + cx * kCellVoxels - 1; x <= border + (cx + 1) * kCellVoxels; ++x) {
              const T v = at(x, y, z);
              lo = std::min(lo, v);
              hi = std::max(hi, v);
            }
          }
        }
        ranges[out++] = lo;
        ranges[out++] = hi;
      }
    }
  }
  return ranges;
}

}  // namespace

std::array<int64_t, 3> slotGridFor(int64_t wanted, int64_t perAxis) {
  wanted = std::max<int64_t>(1, wanted);
  perAxis = std::max<int64_t>(1, perAxis);
  std::array<int64_t, 3> best{1, 1, 1};
  int64_t bestCount = 1;
  for (int64_t a = 1; a <= std::min(wanted, perAxis); ++a) {
    for (int64_t b = 1; b <= std::min(wanted / a, perAxis); ++b) {
      const int64_t c = std::min(wanted / (a * b), perAxis);
      const int64_t count = a * b * c;
      // More slots first; among equal counts the grid with the fewest layers (c) and rows.
      if (count > bestCount || (count == bestCount && std::tie(c, b) < std::tie(best[2], best[1]))) {
        best = {a, b, c};
        bestCount = count;
      }
    }
  }
  return best;
}

BrickPool::BrickPool(const volume::StoreReader& store, std::size_t budgetBytes, bool gradients)
    : store_(store), budgetBytes_(budgetBytes) {
  const volume::OctreeLayout& layout = store.layout();
  edge_ = layout.storedEdge();
  floatPool_ = store.sampleFormat() == volume::SampleFormat::Float32;
  gradients_ = gradients && (store.header().flags & volume::kStoreHasGradients);
  if (gradients && !gradients_) {
    throw Error(store.path(), "a gradient pool was asked for but the store has no gradients "
                              "(import it with --gradients)");
  }
  const std::size_t e3 = static_cast<std::size_t>(edge_) * edge_ * edge_;
  slotBytes_ = e3 * (floatPool_ ? 4 : 2) + (gradients_ ? e3 * 4 : 0);
  if (budgetBytes < slotBytes_) {
    throw Error(store.path(), fmt::format("a GPU pool of {} bytes cannot hold one brick of {} bytes",
                                          budgetBytes, slotBytes_));
  }
  GLint max3d = 0;
  glGetIntegerv(GL_MAX_3D_TEXTURE_SIZE, &max3d);
  const int64_t perAxis = std::max<int64_t>(1, max3d / edge_);
  int64_t want = static_cast<int64_t>(budgetBytes / slotBytes_);
  want = std::min<int64_t>(want, static_cast<int64_t>(store.nodes().size()));
  want = std::min<int64_t>(want, int64_t{kMaxSlots} - 1);  // the spatial index's slot field
  // The driver may refuse a texture the budget allows (llvmpipe caps one texture below
  // 2 GiB): fewer slots until it accepts them, the pool's size then reported by stats().
  const auto outOfMemory = [] {
    bool oom = false;
    for (int i = 0; i < 16; ++i) {
      const GLenum e = glGetError();
      if (e == GL_NO_ERROR) break;
      oom = oom || e == GL_OUT_OF_MEMORY;
    }
    return oom;
  };
  outOfMemory();  // errors of earlier calls are not this allocation's
  cellsPerBrick_ = layout.brickSize() / kCellVoxels;
  for (;;) {
    slotGrid_ = slotGridFor(want, perAxis);
    capacity_ = slotGrid_[0] * slotGrid_[1] * slotGrid_[2];
    const auto w = static_cast<GLsizei>(slotGrid_[0] * edge_), h = static_cast<GLsizei>(slotGrid_[1] * edge_),
               d = static_cast<GLsizei>(slotGrid_[2] * edge_);
    values_ = GlTexture(GL_TEXTURE_3D);
    gradientTexture_ = GlTexture(GL_TEXTURE_3D);
    cellRange_ = GlTexture(GL_TEXTURE_3D);
    glTextureStorage3D(values_.id(), 1, floatPool_ ? GL_R32F : GL_R16, w, h, d);
    if (gradients_) glTextureStorage3D(gradientTexture_.id(), 1, GL_RGBA8, w, h, d);
    glTextureStorage3D(cellRange_.id(), 1, floatPool_ ? GL_RG32F : GL_RG16,
                       static_cast<GLsizei>(slotGrid_[0] * cellsPerBrick_),
                       static_cast<GLsizei>(slotGrid_[1] * cellsPerBrick_),
                       static_cast<GLsizei>(slotGrid_[2] * cellsPerBrick_));
    if (!outOfMemory()) break;
    if (want <= 1) throw Error(store.path(), "the GL driver cannot allocate even one brick slot");
    want = want * 7 / 8;
  }
  slots_.assign(static_cast<std::size_t>(capacity_), {});
  const auto w = static_cast<GLsizei>(slotGrid_[0] * edge_), h = static_cast<GLsizei>(slotGrid_[1] * edge_),
             d = static_cast<GLsizei>(slotGrid_[2] * edge_);
  for (GLuint tex : {values_.id(), gradientTexture_.id()}) {
    glTextureParameteri(tex, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
    glTextureParameteri(tex, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
    glTextureParameteri(tex, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    glTextureParameteri(tex, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
    glTextureParameteri(tex, GL_TEXTURE_WRAP_R, GL_CLAMP_TO_EDGE);
  }
  glTextureParameteri(cellRange_.id(), GL_TEXTURE_MIN_FILTER, GL_NEAREST);
  glTextureParameteri(cellRange_.id(), GL_TEXTURE_MAG_FILTER, GL_NEAREST);
  throwOnGlError(fmt::format("allocating a {}x{}x{} brick pool", w, h, d));
}

void BrickPool::beginFrame() {
  ++frame_;
  pinnedCount_ = 0;
  victims_.clear();
  victimsBuilt_ = false;
}

int64_t BrickPool::slotOf(int64_t id) const {
  const auto it = slotOfNode_.find(id);
  return it == slotOfNode_.end() ? -1 : static_cast<int64_t>(it->second);
}

void BrickPool::pin(int64_t id) {
  const auto it = slotOfNode_.find(id);
  if (it == slotOfNode_.end()) return;
  Slot& s = slots_[it->second];
  if (s.lastPinned != frame_) {
    s.lastPinned = frame_;
    ++pinnedCount_;
  }
}

void BrickPool::markSeen(int64_t id) {
  const auto it = slotOfNode_.find(id);
  if (it != slotOfNode_.end()) slots_[it->second].lastSeen = frame_;
}

int64_t BrickPool::freeSlots() const { return capacity_ - pinnedCount_; }

int64_t BrickPool::takeSlot() {
  if (!victimsBuilt_) {
    victims_.clear();
    for (uint32_t s = 0; s < slots_.size(); ++s) {
      if (slots_[s].lastPinned != frame_) victims_.push_back(s);
    }
    // Best victim last: empty slots, then the node seen longest ago, then used longest ago.
    std::sort(victims_.begin(), victims_.end(), [&](uint32_t a, uint32_t b) {
      const Slot& x = slots_[a];
      const Slot& y = slots_[b];
      return std::tuple(x.node >= 0, x.lastSeen, x.lastPinned, a) >
             std::tuple(y.node >= 0, y.lastSeen, y.lastPinned, b);
    });
    victimsBuilt_ = true;
  }
  while (!victims_.empty()) {
    const uint32_t s = victims_.back();
    victims_.pop_back();
    if (slots_[s].lastPinned != frame_) return s;
  }
  return -1;
}

BrickPool::Placement BrickPool::upload(const volume::Brick& brick) {
  Placement placement;
  const int64_t existing = slotOf(brick.nodeId);
  const int64_t taken = existing >= 0 ? existing : takeSlot();
  if (taken < 0) return placement;
  placement.slot = taken;
  const auto s = static_cast<uint32_t>(taken);
  Slot& slot = slots_[s];
  if (slot.node >= 0 && slot.node != brick.nodeId) {
    slotOfNode_.erase(slot.node);
    placement.evicted = slot.node;
    ++evictions_;
  }
  if (slot.lastPinned != frame_) ++pinnedCount_;
  slot = {brick.nodeId, frame_, slot.node == brick.nodeId ? slot.lastSeen : 0};
  slotOfNode_[brick.nodeId] = s;

  const volume::OctreeLayout& layout = store_.layout();
  const auto x = static_cast<GLint>(static_cast<int64_t>(s) % slotGrid_[0] * edge_);
  const auto y = static_cast<GLint>(static_cast<int64_t>(s) / slotGrid_[0] % slotGrid_[1] * edge_);
  const auto z = static_cast<GLint>(static_cast<int64_t>(s) / (slotGrid_[0] * slotGrid_[1]) * edge_);
  glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
  const GLint cx = x / edge_ * cellsPerBrick_, cy = y / edge_ * cellsPerBrick_, cz = z / edge_ * cellsPerBrick_;
  if (floatPool_) {
    glTextureSubImage3D(values_.id(), 0, x, y, z, edge_, edge_, edge_, GL_RED, GL_FLOAT, brick.f32.data());
    const std::vector<float> ranges = cellRanges(brick.f32, edge_, layout.brickSize(), layout.border());
    glTextureSubImage3D(cellRange_.id(), 0, cx, cy, cz, cellsPerBrick_, cellsPerBrick_, cellsPerBrick_,
                        GL_RG, GL_FLOAT, ranges.data());
  } else {
    glTextureSubImage3D(values_.id(), 0, x, y, z, edge_, edge_, edge_, GL_RED, GL_UNSIGNED_SHORT,
                        brick.u16.data());
    const std::vector<uint16_t> ranges = cellRanges(brick.u16, edge_, layout.brickSize(), layout.border());
    glTextureSubImage3D(cellRange_.id(), 0, cx, cy, cz, cellsPerBrick_, cellsPerBrick_, cellsPerBrick_,
                        GL_RG, GL_UNSIGNED_SHORT, ranges.data());
  }
  if (gradients_) {
    glTextureSubImage3D(gradientTexture_.id(), 0, x, y, z, edge_, edge_, edge_, GL_RGBA,
                        GL_UNSIGNED_BYTE, brick.gradients.data());
  }
  ++uploads_;
  uploadBytes_ += slotBytes_;
  return placement;
}

void BrickPool::clear() {
  slots_.assign(slots_.size(), {});
  slotOfNode_.clear();
  pinnedCount_ = 0;
  victims_.clear();
  victimsBuilt_ = false;
}

BrickPoolStats BrickPool::stats() const {
  BrickPoolStats s;
  s.slots = capacity_;
  s.slotsUsed = static_cast<int64_t>(slotOfNode_.size());
  s.budgetBytes = budgetBytes_;
  s.slotBytes = slotBytes_;
  s.bytes = static_cast<std::size_t>(capacity_) * slotBytes_;
  s.uploads = uploads_;
  s.uploadBytes = uploadBytes_;
  s.evictions = evictions_;
  return s;
}

}  // namespace octoray::gpu
