#include "octoray/gpu/occlusion.h"

#include <epoxy/gl.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "octoray/core/error.h"
#include "octoray/gpu/gl_context.h"

namespace octoray::gpu {
namespace {

// The box faces as corner indices (corner bits: x 1, y 2, z 4), in order around each face.
constexpr int kFaces[6][4] = {{0, 2, 6, 4}, {1, 3, 7, 5}, {0, 1, 5, 4},
                              {2, 3, 7, 6}, {0, 1, 3, 2}, {4, 5, 7, 6}};

struct Rect {
  double x0, y0, x1, y1;  // pixels, GL convention
};

}  // namespace

OcclusionQueries::OcclusionQueries()
    : program_(GlProgram::build("occlusion_box.vert.glsl", "occlusion_box.frag.glsl", {})) {
  glVertexArrayVertexBuffer(vao_.id(), 0, vertices_.id(), 0, 3 * sizeof(float));
  glEnableVertexArrayAttrib(vao_.id(), 0);
  glVertexArrayAttribFormat(vao_.id(), 0, 3, GL_FLOAT, GL_FALSE, 0);
  glVertexArrayAttribBinding(vao_.id(), 0, 0);
  throwOnGlError("setting up the occlusion queries");
}

const std::vector<ScreenTile>& OcclusionQueries::plan(const Camera& camera, const DepthRange& depth,
                                                      std::span<const std::array<Vec3, 8>> boxes,
                                                      int leavesPerTile) {
  const Vec3 forward = normalize(camera.target - camera.eye);
  const Vec3 right = normalize(cross(forward, camera.up));
  const Vec3 up = cross(right, forward);
  const double aspect = static_cast<double>(camera.width) / camera.height;
  const bool perspective = camera.projection == Projection::Perspective;
  const double halfY = perspective ? camera.tanHalfFovY() : 0.5 * camera.orthoHeightMm;
  const double halfX = halfY * aspect;
  const double n = depth.nearMm, f = depth.farMm;
  // Row-major clip-from-camera: the raycaster's ray directions and gl_FragDepth mapping.
  if (perspective) {
    clipFromCamera_ = {static_cast<float>(1 / halfX), 0, 0, 0,
                       0, static_cast<float>(1 / halfY), 0, 0,
                       0, 0, static_cast<float>((f + n) / (f - n)), static_cast<float>(-2 * f * n / (f - n)),
                       0, 0, 1, 0};
  } else {
    clipFromCamera_ = {static_cast<float>(1 / halfX), 0, 0, 0,
                       0, static_cast<float>(1 / halfY), 0, 0,
                       0, 0, static_cast<float>(2 / (f - n)), static_cast<float>(-2 * n / (f - n) - 1),
                       0, 0, 0, 1};
  }

  std::vector<float> vertices;
  ranges_.assign(boxes.size(), {0, 0});
  queried_.assign(boxes.size(), false);
  std::vector<Rect> rects(boxes.size());
  std::vector<uint32_t> all;
  for (std::size_t b = 0; b < boxes.size(); ++b) {
    std::array<Vec3, 8> cam;
    bool nearCut = false;
    Rect r{std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity(),
           -std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity()};
    Vec3 centre{0, 0, 0};
    for (int c = 0; c < 8; ++c) {
      const Vec3 v = boxes[b][static_cast<std::size_t>(c)] - camera.eye;
      cam[static_cast<std::size_t>(c)] = {dot(v, right), dot(v, up), dot(v, forward)};
      centre = centre + 0.125 * boxes[b][static_cast<std::size_t>(c)];
      const Vec3& p = cam[static_cast<std::size_t>(c)];
      if (perspective && p.z <= n * 1.0001) nearCut = true;
      const double sx = perspective ? p.x / (p.z * halfX) : p.x / halfX;
      const double sy = perspective ? p.y / (p.z * halfY) : p.y / halfY;
      r.x0 = std::min(r.x0, (sx + 1) * 0.5 * camera.width);
      r.x1 = std::max(r.x1, (sx + 1) * 0.5 * camera.width);
      r.y0 = std::min(r.y0, (sy + 1) * 0.5 * camera.height);
      r.y1 = std::max(r.y1, (sy + 1) * 0.5 * camera.height);
    }
    if (!perspective && std::any_of(cam.begin(), cam.end(), [&](const Vec3& p) { return p.z <= n; })) {
      nearCut = true;
    }
    if (nearCut) continue;  // not queried: counts as seen
    rects[b] = r;
    ranges_[b][0] = static_cast<int>(vertices.size() / 3);
    for (const auto& face : kFaces) {
      const Vec3 a = boxes[b][static_cast<std::size_t>(face[0])];
      Vec3 normal = cross(boxes[b][static_cast<std::size_t>(face[1])] - a,
                          boxes[b][static_cast<std::size_t>(face[3])] - a);
      Vec3 faceCentre{0, 0, 0};
      for (int i : face) faceCentre = faceCentre + 0.25 * boxes[b][static_cast<std::size_t>(i)];
      if (dot(normal, faceCentre - centre) < 0) normal = -1.0 * normal;
      const bool front = perspective ? dot(normal, faceCentre - camera.eye) < 0 : dot(normal, forward) < 0;
      if (!front) continue;
      for (int i : {0, 1, 2, 0, 2, 3}) {
        const Vec3& p = cam[static_cast<std::size_t>(face[i])];
        vertices.insert(vertices.end(), {static_cast<float>(p.x), static_cast<float>(p.y), static_cast<float>(p.z)});
      }
    }
    ranges_[b][1] = static_cast<int>(vertices.size() / 3) - ranges_[b][0];
    queried_[b] = true;
    all.push_back(static_cast<uint32_t>(b));
  }
  if (vertices.empty()) vertices.assign(3, 0.0f);
  glNamedBufferData(vertices_.id(), static_cast<GLsizeiptr>(vertices.size() * sizeof(float)),
                    vertices.data(), GL_STREAM_DRAW);

  // Binary splits at the median of the projected centres until a tile holds few boxes.
  tiles_.clear();
  tileBoxes_.clear();
  std::vector<uint32_t> rest;
  const int minSide = 16;
  const auto split = [&](auto&& self, ScreenTile tile, std::vector<uint32_t> inside) -> void {
    const bool vertical = tile.width >= tile.height;
    const int side = vertical ? tile.width : tile.height;
    if (static_cast<int>(inside.size()) <= leavesPerTile || side < 2 * minSide) {
      tiles_.push_back(tile);
      tileBoxes_.push_back(std::move(inside));
      return;
    }
    std::vector<double> centres;
    for (uint32_t b : inside) {
      const Rect& r = rects[b];
      centres.push_back(vertical ? 0.5 * (r.x0 + r.x1) : 0.5 * (r.y0 + r.y1));
    }
    std::nth_element(centres.begin(), centres.begin() + static_cast<std::ptrdiff_t>(centres.size() / 2), centres.end());
    const int origin = vertical ? tile.x : tile.y;
    const int cut = std::clamp(static_cast<int>(std::lround(centres[centres.size() / 2])), origin + minSide,
                               origin + side - minSide);
    ScreenTile low = tile, high = tile;
    if (vertical) {
      low.width = cut - tile.x;
      high.x = cut;
      high.width = tile.x + tile.width - cut;
    } else {
      low.height = cut - tile.y;
      high.y = cut;
      high.height = tile.y + tile.height - cut;
    }
    std::vector<uint32_t> lowBoxes, highBoxes;
    for (uint32_t b : inside) {
      const Rect& r = rects[b];
      const double lo = vertical ? r.x0 : r.y0, hi = vertical ? r.x1 : r.y1;
      if (hi <= cut) {
        lowBoxes.push_back(b);
      } else if (lo >= cut) {
        highBoxes.push_back(b);
      } else {
        rest.push_back(b);
      }
    }
    self(self, low, std::move(lowBoxes));
    self(self, high, std::move(highBoxes));
  };
  split(split, ScreenTile{0, 0, camera.width, camera.height}, std::move(all));
  tileBoxes_.push_back(std::move(rest));

  queries_.assign(boxes.size(), 0);
  if (!boxes.empty()) glCreateQueries(GL_SAMPLES_PASSED, static_cast<GLsizei>(boxes.size()), queries_.data());
  throwOnGlError("planning the occlusion queries");
  return tiles_;
}

void OcclusionQueries::issue(std::size_t tile) {
  glUseProgram(program_.id());
  glUniformMatrix4fv(program_.uniform("uClipFromCamera"), 1, GL_TRUE, clipFromCamera_.data());
  glBindVertexArray(vao_.id());
  glColorMask(GL_FALSE, GL_FALSE, GL_FALSE, GL_FALSE);
  glDepthMask(GL_FALSE);
  glDepthFunc(GL_LESS);
  glDisable(GL_SCISSOR_TEST);
  const auto run = [&](const std::vector<uint32_t>& boxes) {
    for (uint32_t b : boxes) {
      glBeginQuery(GL_SAMPLES_PASSED, queries_[b]);
      if (ranges_[b][1] > 0) glDrawArrays(GL_TRIANGLES, ranges_[b][0], ranges_[b][1]);
      glEndQuery(GL_SAMPLES_PASSED);
      ++issued_;
    }
  };
  run(tileBoxes_[tile]);
  if (tile + 1 == tiles_.size()) run(tileBoxes_.back());
  throwOnGlError("issuing occlusion queries");
}

std::vector<uint32_t> OcclusionQueries::results() {
  std::vector<uint32_t> samples(queries_.size(), std::numeric_limits<uint32_t>::max());
  for (std::size_t b = 0; b < queries_.size(); ++b) {
    if (!queried_[b]) continue;
    GLuint v = 0;
    glGetQueryObjectuiv(queries_[b], GL_QUERY_RESULT, &v);
    samples[b] = v;
  }
  if (!queries_.empty()) glDeleteQueries(static_cast<GLsizei>(queries_.size()), queries_.data());
  queries_.clear();
  throwOnGlError("reading occlusion query results");
  return samples;
}

}  // namespace octoray::gpu
