#pragma once
// Occlusion feedback (paper 003 §6): after the raycaster has written, per pixel, the depth of
// the ray's last sample (where it terminated, or the far plane), the bounding box of every
// rendered leaf is drawn against that depth inside a GL_SAMPLES_PASSED query; a leaf whose
// front faces pass on fewer than the threshold's pixels is hidden behind what the rays already
// accumulated, and the working set neither refines it nor keeps its brick.
//
// Screen-space tiling, as the paper schedules it: the screen is split in two, again and again
// (alternating along the longer side, at the median of the boxes' projected centres), until a
// tile holds at most `leavesPerTile` projected boxes; boxes that straddle a split wait for the
// end. The raycaster draws tile by tile (scissored) and the queries of a tile's boxes are
// issued right after its tile, so that on a GPU they run while the next tiles are raycast;
// the results are read after the frame and used by the next update (a delay of one frame).
//
// Boxes the near plane cuts (the eye inside or close) are not queried and count as seen.

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "octoray/core/geometry.h"
#include "octoray/gpu/camera.h"
#include "octoray/gpu/gl_program.h"

namespace octoray::gpu {

// A rectangle of the window in GL's convention (x from the left, y from the bottom).
struct ScreenTile {
  int x = 0, y = 0, width = 0, height = 0;
};

// The raycaster's depth mapping: window depth of a point `z` mm along the view axis.
struct DepthRange {
  double nearMm = 1, farMm = 2;
  bool perspective = true;
};

class OcclusionQueries {
 public:
  OcclusionQueries();
  OcclusionQueries(const OcclusionQueries&) = delete;
  OcclusionQueries& operator=(const OcclusionQueries&) = delete;

  // Projects the boxes and plans the tiles; returns them in drawing order.
  const std::vector<ScreenTile>& plan(const Camera& camera, const DepthRange& depth,
                                      std::span<const std::array<Vec3, 8>> boxes,
                                      int leavesPerTile = 64);
  // Issues the queries of the boxes planned for tile `tile` (after the last tile, also those
  // that straddle tiles). Needs the raycaster's framebuffer bound, its depth buffer written.
  // Leaves GL state as the raycaster set it except program, vertex array, colour and depth
  // writes, which the caller restores.
  void issue(std::size_t tile);
  // Samples passed per box in plan() order (blocks until the queries finish); boxes not
  // queried (cut by the near plane) report UINT32_MAX.
  std::vector<uint32_t> results();

  int64_t queriesIssued() const { return issued_; }

 private:
  GlProgram program_;
  GlBuffer vertices_;
  GlVertexArray vao_;
  std::vector<ScreenTile> tiles_;
  std::vector<std::vector<uint32_t>> tileBoxes_;  // per tile, then one list for the rest
  std::vector<std::array<int, 2>> ranges_;         // per box: first vertex, vertex count
  std::vector<GLuint> queries_;
  std::vector<bool> queried_;
  std::array<float, 16> clipFromCamera_{};
  int64_t issued_ = 0;
};

}  // namespace octoray::gpu
