#include "octoray/gpu/raycaster.h"

#include <epoxy/gl.h>
#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <numeric>
#include <optional>

#include "octoray/core/elapsed.h"
#include "octoray/core/error.h"
#include "octoray/gpu/gl_context.h"
#include "octoray/gpu/gl_program.h"
#include "octoray/gpu/spatial_index.h"
#include "octoray/transfer/preintegration.h"

namespace octoray::gpu {
namespace {

constexpr int kTfTableSize = 8192;
// Bins of the pre-integration table over the TF's opacity support within the data's range.
constexpr int kPreintegrationBins = 256;

// True when the TF's gradient opacity changes nothing (no points, or every point 1).
bool gradientOpacityIsIdentity(const transfer::TransferFunction& tf) {
  return std::all_of(tf.gradientOpacity.begin(), tf.gradientOpacity.end(),
                     [](const transfer::GradientOpacityPoint& p) { return p.alpha == 1.0f; });
}

void setMat3(GLint location, const std::array<std::array<double, 3>, 3>& rows) {
  if (location < 0) return;
  std::array<float, 9> v{};
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) v[static_cast<std::size_t>(3 * r + c)] = static_cast<float>(rows[r][c]);
  glUniformMatrix3fv(location, 1, GL_TRUE, v.data());
}

}  // namespace

struct Raycaster::Impl {
  const volume::StoreReader& store;
  const BrickPool& pool;
  const volume::OctreeLayout& layout;

  GlTexture tfTable{GL_TEXTURE_1D};
  GlTexture tfNonZero{GL_TEXTURE_1D};   // entries of tfTable with opacity, counted below i
  GlTexture preintegration{GL_TEXTURE_2D};  // transfer::SegmentExtinctionTable
  std::array<float, 2> preintegrationRange{0, 1};
  GlBuffer nodeBuffer, leafBuffer, tfPointBuffer, touchedBuffer, feedbackBuffer, adaptiveBuffer;
  // Image-adaptive sampling: levels 1 .. L of the image pyramid (colour, aux and the stencil
  // that marks the pixels interpolated), level 0 being the targets below.
  struct PyramidLevel {
    GlTexture color{GL_TEXTURE_2D}, aux{GL_TEXTURE_2D}, depthStencil{GL_TEXTURE_2D};
    GlFramebuffer fbo;
    int width = 0, height = 0;
  };
  std::vector<std::unique_ptr<PyramidLevel>> pyramid;
  void ensurePyramid(int width, int height, int levels);
  GlVertexArray vao;
  GlFramebuffer fbo;
  GlFramebuffer depthFbo;          // targets[3] alone: the image-adaptive frame's depth pass
  std::vector<GlTexture> targets;  // colour, aux, stats, depth + stencil
  int targetWidth = 0, targetHeight = 0;
  // The targets read back, kept from frame to frame: fresh vectors of a 512² frame's 8 MiB
  // cost their page faults every frame.
  std::vector<float> readColor, readAux, readCounters;
  std::map<std::string, GlProgram> programs;

  // The ray parameters in the single precision the shader receives them in.
  struct RayUniforms {
    std::array<float, 3> eye{}, forward{}, right{}, up{}, qOffset{}, domainMax{};
    std::array<float, 2> halfExtent{}, viewport{};
    std::array<float, 9> qFromPatient{};  // row-major
    bool perspective = true;
  };
  RayUniforms rayUniforms(const Camera& camera) const;

  Impl(const volume::StoreReader& s, const BrickPool& p) : store(s), pool(p), layout(s.layout()) {
    glTextureStorage1D(tfNonZero.id(), 1, GL_R32F, kTfTableSize + 1);
    glTextureParameteri(tfNonZero.id(), GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glTextureParameteri(tfNonZero.id(), GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    glTextureStorage1D(tfTable.id(), 1, GL_RGBA32F, kTfTableSize);
    glTextureParameteri(tfTable.id(), GL_TEXTURE_MIN_FILTER, GL_LINEAR);
    glTextureParameteri(tfTable.id(), GL_TEXTURE_MAG_FILTER, GL_LINEAR);
    glTextureParameteri(tfTable.id(), GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    glTextureStorage2D(preintegration.id(), 1, GL_RGBA32F, kPreintegrationBins, kPreintegrationBins);
    glTextureParameteri(preintegration.id(), GL_TEXTURE_MIN_FILTER, GL_LINEAR);
    glTextureParameteri(preintegration.id(), GL_TEXTURE_MAG_FILTER, GL_LINEAR);
    glTextureParameteri(preintegration.id(), GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    glTextureParameteri(preintegration.id(), GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
    throwOnGlError("allocating the transfer-function tables");
  }

  void ensureTargets(int width, int height);
  // The program of gpu/shaders/`fragment` (with fullscreen.vert.glsl) for `defines`, built once.
  GlProgram& program(const std::vector<std::string>& defines,
                     std::string_view fragment = "raycast.frag.glsl");
  std::vector<std::string> defines(const transfer::TransferFunction& tf,
                                   const RaycastOptions& options, Projection projection,
                                   bool feedback) const;
  void uploadTransferFunction(const transfer::TransferFunction& tf, const RaycastOptions& options,
                              int counts[3]);
  double stepMm(const RaycastOptions& options) const;
  // The physical value range the TF table spans: the store's (the root's [min, max]).
  std::pair<double, double> tfRange() const {
    const volume::NodeRecord& root = store.node(0);
    return {root.minValue, root.maxValue > root.minValue ? root.maxValue : root.minValue + 1.0};
  }
};

Raycaster::Impl::RayUniforms Raycaster::Impl::rayUniforms(const Camera& camera) const {
  RayUniforms u;
  const auto f3 = [](Vec3 v) {
    return std::array<float, 3>{static_cast<float>(v.x), static_cast<float>(v.y), static_cast<float>(v.z)};
  };
  // Camera frame (Camera::ray).
  const Vec3 forward = normalize(camera.target - camera.eye);
  const Vec3 right = normalize(cross(forward, camera.up));
  const Vec3 up = cross(right, forward);
  const double aspect = static_cast<double>(camera.width) / camera.height;
  u.perspective = camera.projection == Projection::Perspective;
  const double halfY = u.perspective ? camera.tanHalfFovY()
                                     : 0.5 * camera.orthoHeightMm;
  u.eye = f3(camera.eye);
  u.forward = f3(forward);
  u.right = f3(right);
  u.up = f3(up);
  u.halfExtent = {static_cast<float>(halfY * aspect), static_cast<float>(halfY)};
  u.viewport = {static_cast<float>(camera.width), static_cast<float>(camera.height)};
  // Octree space: q = (indexFromPatient(p) + 0.5) / S.
  const Mat4 indexFromPatient = store.patientFromIndex().inverseAffine();
  const double cube = static_cast<double>(layout.brickSize()) * static_cast<double>(layout.levelScale(0));
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      u.qFromPatient[static_cast<std::size_t>(3 * r + c)] = static_cast<float>(indexFromPatient.m[r][c] / cube);
    }
    u.qOffset[static_cast<std::size_t>(r)] = static_cast<float>((indexFromPatient.m[r][3] + 0.5) / cube);
  }
  const volume::Index3& dims = layout.levelDims(layout.leafLevel());
  for (int a = 0; a < 3; ++a) {
    u.domainMax[static_cast<std::size_t>(a)] = static_cast<float>(static_cast<double>(dims[a]) / cube);
  }
  return u;
}

void Raycaster::Impl::ensureTargets(int width, int height) {
  if (width == targetWidth && height == targetHeight && !targets.empty()) return;
  targets.clear();
  const GLenum formats[4] = {GL_RGBA32F, GL_RGBA32F, GL_RGBA32F, GL_DEPTH32F_STENCIL8};
  for (int i = 0; i < 4; ++i) {
    targets.emplace_back(GL_TEXTURE_2D);
    glTextureStorage2D(targets.back().id(), 1, formats[i], width, height);
  }
  for (int i = 0; i < 3; ++i) {
    glNamedFramebufferTexture(fbo.id(), static_cast<GLenum>(GL_COLOR_ATTACHMENT0 + i), targets[static_cast<std::size_t>(i)].id(), 0);
  }
  glNamedFramebufferTexture(fbo.id(), GL_DEPTH_STENCIL_ATTACHMENT, targets[3].id(), 0);
  glNamedFramebufferTexture(depthFbo.id(), GL_DEPTH_STENCIL_ATTACHMENT, targets[3].id(), 0);
  glNamedFramebufferDrawBuffer(depthFbo.id(), GL_NONE);
  glNamedFramebufferReadBuffer(depthFbo.id(), GL_NONE);
  for (const GlFramebuffer* f : {&fbo, &depthFbo}) {
    const GLenum status = glCheckNamedFramebufferStatus(f->id(), GL_FRAMEBUFFER);
    if (status != GL_FRAMEBUFFER_COMPLETE) {
      throw Error("", fmt::format("GPU raycaster: framebuffer {}x{} incomplete (0x{:x})", width, height, status));
    }
  }
  targetWidth = width;
  targetHeight = height;
  throwOnGlError("allocating render targets");
}

void Raycaster::Impl::ensurePyramid(int width, int height, int levels) {
  bool same = static_cast<int>(pyramid.size()) == levels;
  for (int l = 1; same && l <= levels; ++l) {
    const PyramidLevel& p = *pyramid[static_cast<std::size_t>(l - 1)];
    same = p.width == (width + (1 << l) - 1) >> l && p.height == (height + (1 << l) - 1) >> l;
  }
  if (same) return;
  pyramid.clear();
  for (int l = 1; l <= levels; ++l) {
    auto p = std::make_unique<PyramidLevel>();
    p->width = (width + (1 << l) - 1) >> l;
    p->height = (height + (1 << l) - 1) >> l;
    glTextureStorage2D(p->color.id(), 1, GL_RGBA32F, p->width, p->height);
    glTextureStorage2D(p->aux.id(), 1, GL_RGBA32F, p->width, p->height);
    glTextureStorage2D(p->depthStencil.id(), 1, GL_DEPTH32F_STENCIL8, p->width, p->height);
    glNamedFramebufferTexture(p->fbo.id(), GL_COLOR_ATTACHMENT0, p->color.id(), 0);
    glNamedFramebufferTexture(p->fbo.id(), GL_COLOR_ATTACHMENT1, p->aux.id(), 0);
    glNamedFramebufferTexture(p->fbo.id(), GL_DEPTH_STENCIL_ATTACHMENT, p->depthStencil.id(), 0);
    const GLenum buffers[2] = {GL_COLOR_ATTACHMENT0, GL_COLOR_ATTACHMENT1};
    glNamedFramebufferDrawBuffers(p->fbo.id(), 2, buffers);
    const GLenum status = glCheckNamedFramebufferStatus(p->fbo.id(), GL_FRAMEBUFFER);
    if (status != GL_FRAMEBUFFER_COMPLETE) {
      throw Error("", fmt::format("GPU raycaster: image pyramid level {} incomplete (0x{:x})", l, status));
    }
    pyramid.push_back(std::move(p));
  }
  throwOnGlError("allocating the image pyramid");
}

GlProgram& Raycaster::Impl::program(const std::vector<std::string>& defs, std::string_view fragment) {
  std::string key(fragment);
  for (const std::string& d : defs) key += ";" + d;
  auto it = programs.find(key);
  if (it == programs.end()) {
    it = programs.emplace(key, GlProgram::build("fullscreen.vert.glsl", fragment, defs)).first;
  }
  return it->second;
}

std::vector<std::string> Raycaster::Impl::defines(const transfer::TransferFunction& tf,
                                                    const RaycastOptions& o,
                                                    Projection projection, bool feedback) const {
  std::vector<std::string> d;
  const bool shade = o.shading == RaycastOptions::Shading::On ||
                     (o.shading == RaycastOptions::Shading::FromTransferFunction && tf.material.shade);
  switch (o.mode) {
    case RaycastMode::Dvr: {
      d.emplace_back("MODE_DVR");
      if (o.preintegration) {
        d.emplace_back("PREINTEGRATION");
      } else {
        if (o.cellSkipping) d.emplace_back("CELL_SKIPPING");
        if (o.jitter) d.emplace_back("JITTER");
      }
      if (shade) d.emplace_back("SHADING");
      const bool gradientOpacity = o.gradientOpacity && !gradientOpacityIsIdentity(tf);
      if (gradientOpacity) d.emplace_back("GRADIENT_OPACITY");
      if (o.boundary.enabled) d.emplace_back("BOUNDARY_ENHANCEMENT");
      if (o.silhouette.enabled) d.emplace_back("SILHOUETTE_ENHANCEMENT");
      if (pool.hasGradients() && (shade || gradientOpacity || o.boundary.enabled || o.silhouette.enabled)) {
        d.emplace_back("GRADIENT_POOL");
      }
      break;
    }
    case RaycastMode::Iso:
      d.emplace_back("MODE_ISO");
      if (shade) d.emplace_back("SHADING");
      if (pool.hasGradients() && shade) d.emplace_back("GRADIENT_POOL");
      break;
    case RaycastMode::Mip:
      d.emplace_back("MODE_MIP");
      if (o.mip == RaycastOptions::MipMethod::Sampled) {
        d.emplace_back("MIP_SAMPLED");
      } else if (o.cellSkipping) {
        d.emplace_back("CELL_SKIPPING");  // groups of cells that cannot raise the maximum
      }
      break;
  }
  d.push_back(fmt::format("BRICK_SIZE {}", layout.brickSize()));
  d.push_back(fmt::format("BORDER {}", layout.border()));
  d.push_back(fmt::format("CELL_VOXELS {}", kCellVoxels));
  d.push_back(fmt::format("TF_TABLE_SIZE {}", kTfTableSize));
  // Central differences of +-1 voxel need two border samples; with one, +-0.5 voxel stays
  // inside the brick.
  d.push_back(layout.border() >= 2 ? "GRADIENT_DELTA 1.0" : "GRADIENT_DELTA 0.5");
  if (o.stats) d.emplace_back("STATS");
  if (feedback) d.emplace_back("FEEDBACK");
  if (o.imageAdaptive > 0) d.emplace_back("IMAGE_ADAPTIVE");
  if (projection == Projection::Perspective) d.emplace_back("PERSPECTIVE");
  return d;
}

double Raycaster::Impl::stepMm(const RaycastOptions& o) const {
  if (o.stepMm > 0) return o.stepMm;
  const Mat4 m = store.patientFromIndex();
  double smallest = std::numeric_limits<double>::infinity();
  for (int a = 0; a < 3; ++a) smallest = std::min(smallest, length(m.column(a)));
  return 0.25 * smallest;
}

void Raycaster::Impl::uploadTransferFunction(const transfer::TransferFunction& tf,
                                               const RaycastOptions& options, int counts[3]) {
  const auto [lo, hi] = tfRange();
  std::vector<float> table(static_cast<std::size_t>(kTfTableSize) * 4);
  for (int i = 0; i < kTfTableSize; ++i) {
    const double v = lo + (hi - lo) * i / (kTfTableSize - 1);
    const std::array<float, 4> c = tf.evaluate(v);
    const double alpha = std::clamp<double>(c[3], 0.0, 1.0);
    float* e = &table[static_cast<std::size_t>(i) * 4];
    e[0] = c[0];
    e[1] = c[1];
    e[2] = c[2];
    e[3] = alpha < 1.0 ? static_cast<float>(-std::log1p(-alpha)) : 1e4f;
  }
  glTextureSubImage1D(tfTable.id(), 0, 0, kTfTableSize, GL_RGBA, GL_FLOAT, table.data());
  // nonZero[i]: entries below i with opacity (exact integers in float up to 2^24).
  std::vector<float> nonZero(static_cast<std::size_t>(kTfTableSize) + 1, 0.0f);
  for (int i = 0; i < kTfTableSize; ++i) {
    nonZero[static_cast<std::size_t>(i) + 1] =
        nonZero[static_cast<std::size_t>(i)] + (table[static_cast<std::size_t>(i) * 4 + 3] > 0 ? 1.0f : 0.0f);
  }
  glTextureSubImage1D(tfNonZero.id(), 0, 0, kTfTableSize + 1, GL_RED, GL_FLOAT, nonZero.data());

  if (options.preintegration && options.mode == RaycastMode::Dvr) {
    // Over the opacity support within the data's range: a segment is clipped to it in the
    // shader, so the bins resolve the TF where it has material.
    auto [sLo, sHi] = transfer::opacitySupport(tf);
    sLo = std::max(sLo, lo);
    sHi = std::min(sHi, hi);
    std::vector<std::array<float, 4>> zeros;
    const std::vector<std::array<float, 4>>* data = &zeros;
    std::optional<transfer::SegmentExtinctionTable> segments;
    if (sLo < sHi) {
      segments.emplace(tf, sLo, sHi, kPreintegrationBins);
      data = &segments->data();
      preintegrationRange = {static_cast<float>(sLo), static_cast<float>(sHi)};
    } else {
      // No material in the data's range (or a single value): an all-transparent table.
      zeros.assign(static_cast<std::size_t>(kPreintegrationBins) * kPreintegrationBins, {0, 0, 0, 0});
      preintegrationRange = {static_cast<float>(lo), static_cast<float>(hi)};
    }
    glTextureSubImage2D(preintegration.id(), 0, 0, 0, kPreintegrationBins, kPreintegrationBins, GL_RGBA,
                        GL_FLOAT, data->data());
  }

  std::vector<float> points;
  for (const transfer::ColorPoint& p : tf.color) {
    points.insert(points.end(), {static_cast<float>(p.value), p.r, p.g, p.b});
  }
  for (const transfer::OpacityPoint& p : tf.opacity) {
    points.insert(points.end(), {static_cast<float>(p.value), p.alpha, 0, 0});
  }
  const bool gradient = options.gradientOpacity;
  if (gradient) {
    for (const transfer::GradientOpacityPoint& p : tf.gradientOpacity) {
      points.insert(points.end(), {static_cast<float>(p.magnitude), p.alpha, 0, 0});
    }
  }
  counts[0] = static_cast<int>(tf.color.size());
  counts[1] = static_cast<int>(tf.opacity.size());
  counts[2] = gradient ? static_cast<int>(tf.gradientOpacity.size()) : 0;
  if (points.empty()) points.assign(4, 0.0f);
  glNamedBufferData(tfPointBuffer.id(), static_cast<GLsizeiptr>(points.size() * sizeof(float)),
                    points.data(), GL_DYNAMIC_DRAW);
}

Raycaster::Raycaster(const volume::StoreReader& store, const BrickPool& pool)
    : impl_(std::make_unique<Impl>(store, pool)) {}

Raycaster::~Raycaster() = default;

DepthRange Raycaster::depthRange(const Camera& camera) const {
  // The domain's extent along the view axis, widened by 1 mm, the near plane kept in front.
  const Mat4 patientFromIndex = impl_->store.patientFromIndex();
  const volume::Index3& dims = impl_->layout.levelDims(impl_->layout.leafLevel());
  const Vec3 forward = normalize(camera.target - camera.eye);
  double zNear = std::numeric_limits<double>::infinity(), zFar = 0;
  for (int c = 0; c < 8; ++c) {
    const Vec3 p = patientFromIndex.transformPoint({(c & 1) ? dims[0] - 0.5 : -0.5,
                                                    (c & 2) ? dims[1] - 0.5 : -0.5,
                                                    (c & 4) ? dims[2] - 0.5 : -0.5});
    const double z = dot(p - camera.eye, forward);
    zNear = std::min(zNear, z);
    zFar = std::max(zFar, z);
  }
  DepthRange range;
  range.farMm = std::max(zFar, 1e-3) + 1.0;
  range.nearMm = std::clamp(zNear - 1.0, 1e-3 * range.farMm, range.farMm * 0.5);
  range.perspective = camera.projection == Projection::Perspective;
  return range;
}

unsigned Raycaster::variantProgram(const transfer::TransferFunction& tf,
                                     const RaycastOptions& options, Projection projection) {
  return impl_->program(impl_->defines(tf, options, projection, false)).id();
}

std::array<float, 3> Raycaster::domainMax(const Camera& camera) const {
  return impl_->rayUniforms(camera).domainMax;
}

OctreeRay Raycaster::pixelRay(const Camera& camera, int x, int y) const {
  // raycast.frag.glsl's first lines, operation for operation (GL rows run bottom-up).
  const Impl::RayUniforms u = impl_->rayUniforms(camera);
  const float fc[2] = {static_cast<float>(x) + 0.5f, static_cast<float>(camera.height - 1 - y) + 0.5f};
  float sv[2];
  for (int i = 0; i < 2; ++i) sv[i] = (2.0f * fc[i] / u.viewport[i] - 1.0f) * u.halfExtent[i];
  std::array<float, 3> origin{}, dir{};
  for (int a = 0; a < 3; ++a) {
    if (u.perspective) {
      origin[a] = u.eye[a];
      dir[a] = u.forward[a] + sv[0] * u.right[a] + sv[1] * u.up[a];
    } else {
      origin[a] = u.eye[a] + sv[0] * u.right[a] + sv[1] * u.up[a];
      dir[a] = u.forward[a];
    }
  }
  if (u.perspective) {
    const float inv = 1.0f / std::sqrt(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]);
    for (float& d : dir) d *= inv;
  }
  OctreeRay ray;
  for (int r = 0; r < 3; ++r) {
    const float* m = &u.qFromPatient[static_cast<std::size_t>(3 * r)];
    ray.origin[r] = m[0] * origin[0] + m[1] * origin[1] + m[2] * origin[2] + u.qOffset[r];
    ray.direction[r] = m[0] * dir[0] + m[1] * dir[1] + m[2] * dir[2];
  }
  return ray;
}

double Raycaster::defaultStepMm() const { return impl_->stepMm({}); }

std::vector<std::string> Raycaster::variantDefines(const transfer::TransferFunction& tf,
                                                     const RaycastOptions& options,
                                                     Projection projection) const {
  return impl_->defines(tf, options, projection, false);
}

const std::string& Raycaster::variantSource(const transfer::TransferFunction& tf,
                                              const RaycastOptions& options,
                                              Projection projection) {
  return impl_->program(impl_->defines(tf, options, projection, false)).fragmentSourceWithDefines();
}

Frame Raycaster::draw(const Camera& camera, const transfer::TransferFunction& tf,
                      const RaycastOptions& options, const SpatialIndex& index,
                      LeafFeedbackCounts* feedback, const TiledPass* tiles) {
  Impl& im = *impl_;
  validateRaycast(camera, tf, options);
  {
    // The shader steps in single precision: past 2^20 steps across the volume the step is
    // lost against the ray parameter and rays come out empty. Refused, as the reference refuses
    // steps past 1e9.
    const Mat4 m = im.store.patientFromIndex();
    const auto& dims = im.store.header().dims;
    double diagonalMm = 0;  // an upper bound: the edges' lengths summed
    for (int a = 0; a < 3; ++a) diagonalMm += length(m.column(a)) * static_cast<double>(dims[a]);
    const double step = im.stepMm(options);
    if (diagonalMm / step > double{1 << 20}) {
      throw Error(im.store.path(), fmt::format("step {} mm is too small for the GPU raycaster: over 2^20 "
                                               "steps across the volume (use --reference)",
                                               step));
    }
  }
  Frame frame;
  FrameStats& stats = frame.stats;
  const BrickPool& pool = im.pool;
  const BrickPoolStats poolStats = pool.stats();
  stats.workingSetBricks = index.dataLeaves;
  stats.poolSlots = poolStats.slots;
  stats.poolSlotsUsed = poolStats.slotsUsed;
  stats.poolBytes = poolStats.bytes;
  stats.poolBytesUsed = static_cast<std::size_t>(index.dataLeaves) * poolStats.slotBytes;
  glNamedBufferData(im.nodeBuffer.id(), static_cast<GLsizeiptr>(index.nodes.size() * 4),
                    index.nodes.data(), GL_DYNAMIC_DRAW);
  glNamedBufferData(im.leafBuffer.id(), static_cast<GLsizeiptr>(index.leaves.size() * 4),
                    index.leaves.data(), GL_DYNAMIC_DRAW);
  const std::size_t leafRecords = index.leaves.size() / kLeafRecordUints;
  if (options.stats) {
    std::vector<uint32_t> zeros(leafRecords, 0);
    glNamedBufferData(im.touchedBuffer.id(), static_cast<GLsizeiptr>(zeros.size() * 4), zeros.data(),
                      GL_DYNAMIC_READ);
  }
  if (feedback) {
    std::vector<uint32_t> zeros(std::max<std::size_t>(1, leafRecords) * 2, 0);
    glNamedBufferData(im.feedbackBuffer.id(), static_cast<GLsizeiptr>(zeros.size() * 4), zeros.data(),
                      GL_DYNAMIC_READ);
  }
  int counts[3];
  im.uploadTransferFunction(tf, options, counts);

  const int width = camera.width, height = camera.height;
  im.ensureTargets(width, height);
  GlProgram& prog = im.program(im.defines(tf, options, camera.projection, feedback != nullptr));
  glUseProgram(prog.id());

  const Impl::RayUniforms ru = im.rayUniforms(camera);
  const auto u3 = [&](const char* name, const std::array<float, 3>& v) {
    glUniform3f(prog.uniform(name), v[0], v[1], v[2]);
  };
  u3("uEye", ru.eye);
  u3("uForward", ru.forward);
  u3("uRight", ru.right);
  u3("uUp", ru.up);
  glUniform2f(prog.uniform("uHalfExtent"), ru.halfExtent[0], ru.halfExtent[1]);
  glUniform2f(prog.uniform("uViewport"), ru.viewport[0], ru.viewport[1]);
  glUniformMatrix3fv(prog.uniform("uQFromPatient"), 1, GL_TRUE, ru.qFromPatient.data());
  u3("uQOffset", ru.qOffset);
  u3("uDomainMax", ru.domainMax);
  {
    // The clip box in octree space (index + 0.5) / S, within the domain.
    std::array<float, 3> clipMin{0, 0, 0}, clipMax = ru.domainMax;
    if (options.clip.enabled) {
      const auto& layout = im.store.layout();
      const double cube = static_cast<double>(layout.brickSize()) * static_cast<double>(layout.levelScale(0));
      for (std::size_t a = 0; a < 3; ++a) {
        clipMin[a] = std::clamp(static_cast<float>((options.clip.lo[a] + 0.5) / cube), 0.0f, ru.domainMax[a]);
        clipMax[a] = std::clamp(static_cast<float>((options.clip.hi[a] + 0.5) / cube), 0.0f, ru.domainMax[a]);
      }
    }
    u3("uClipMin", clipMin);
    u3("uClipMax", clipMax);
  }
  const Mat4 patientFromIndex = im.store.patientFromIndex();
  const Mat4 indexFromPatient = patientFromIndex.inverseAffine();
  std::array<std::array<double, 3>, 3> normalFromIndex{};
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) normalFromIndex[r][c] = indexFromPatient.m[c][r];
  }
  setMat3(prog.uniform("uNormalFromIndex"), normalFromIndex);
  glUniform1i(prog.uniform("uLeafLevel"), im.layout.leafLevel());
  glUniform1i(prog.uniform("uMaxIterations"), static_cast<GLint>(3 * (leafRecords + 2)));
  glUniform1f(prog.uniform("uStepMm"), static_cast<float>(im.stepMm(options)));
  glUniform1f(prog.uniform("uInvUnitDistance"), static_cast<float>(1.0 / tf.unitDistanceMm));
  glUniform1f(prog.uniform("uEarlyTermination"), static_cast<float>(options.earlyTermination));

  const DepthRange depth = depthRange(camera);
  const double zNear = depth.nearMm, zFar = depth.farMm;
  glUniform1f(prog.uniform("uNear"), static_cast<float>(zNear));
  glUniform1f(prog.uniform("uFar"), static_cast<float>(zFar));

  const bool floatPool = pool.floatSamples();
  const double s = floatPool ? 1.0 : 65535.0 * im.store.header().valueScale;
  glUniform1f(prog.uniform("uValueScale"), static_cast<float>(s));
  glUniform1f(prog.uniform("uValueOffset"),
              static_cast<float>(floatPool ? 0.0 : im.store.header().valueOffset));
  if (options.mode == RaycastMode::Mip) {
    // The visibility floor in the pool's units (none where stored values decrease).
    const double big = std::numeric_limits<float>::max();
    const double offset = floatPool ? 0.0 : im.store.header().valueOffset;
    const double floor = s > 0 ? (mipVisibleFrom(tf) - offset) / s : -big;
    glUniform1f(prog.uniform("uMipFloor"), static_cast<float>(std::clamp(floor, -big, big)));
  }
  const auto [lo, hi] = im.tfRange();
  const double n = kTfTableSize;
  glUniform2f(prog.uniform("uTfMap"), static_cast<float>((n - 1) / ((hi - lo) * n)),
              static_cast<float>((-lo * (n - 1) / (hi - lo) + 0.5) / n));
  glUniform1i(prog.uniform("uColorPoints"), counts[0]);
  glUniform1i(prog.uniform("uOpacityPoints"), counts[1]);
  glUniform1i(prog.uniform("uGradientPoints"), counts[2]);
  const std::array<int64_t, 3>& slotGrid = pool.slotGrid();
  const int edge = pool.edge();
  glUniform3f(prog.uniform("uPoolInvSize"), 1.0f / static_cast<float>(slotGrid[0] * edge),
              1.0f / static_cast<float>(slotGrid[1] * edge),
              1.0f / static_cast<float>(slotGrid[2] * edge));
  glUniform2i(prog.uniform("uSlotGrid"), static_cast<GLint>(slotGrid[0]),
              static_cast<GLint>(slotGrid[0] * slotGrid[1]));
  const transfer::Material& mat = tf.material;
  glUniform4f(prog.uniform("uMaterial"), mat.ambient, mat.diffuse, mat.specular, mat.specularPower);
  glUniform3f(prog.uniform("uBoundary"), static_cast<float>(options.boundary.kC),
              static_cast<float>(options.boundary.kS), static_cast<float>(options.boundary.kE));
  glUniform3f(prog.uniform("uSilhouette"), static_cast<float>(options.silhouette.kC),
              static_cast<float>(options.silhouette.kS), static_cast<float>(options.silhouette.kE));
  glUniform1f(prog.uniform("uIsoValue"), static_cast<float>(options.isoValue));
  glUniform1f(prog.uniform("uGradientScale"), im.store.header().gradientScale);

  glBindTextureUnit(0, pool.valueTexture());
  glUniform1i(prog.uniform("uPool"), 0);
  glBindTextureUnit(1, im.tfTable.id());
  glUniform1i(prog.uniform("uTf"), 1);
  if (pool.hasGradients()) {
    glBindTextureUnit(2, pool.gradientTexture());
    glUniform1i(prog.uniform("uGradientPool"), 2);
  }
  glBindTextureUnit(3, pool.cellRangeTexture());
  glUniform1i(prog.uniform("uCellRange"), 3);
  glBindTextureUnit(4, im.tfNonZero.id());
  glUniform1i(prog.uniform("uTfNonZero"), 4);
  if (options.preintegration) {
    glBindTextureUnit(5, im.preintegration.id());
    glUniform1i(prog.uniform("uPreintegration"), 5);
    glUniform2f(prog.uniform("uPreintegrationRange"), im.preintegrationRange[0], im.preintegrationRange[1]);
  }
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 0, im.nodeBuffer.id());
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 1, im.leafBuffer.id());
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 2, im.tfPointBuffer.id());
  if (options.stats) glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 3, im.touchedBuffer.id());
  const bool adaptive = options.imageAdaptive > 0;
  if (feedback || adaptive) {
    // Projected voxel sizes: the ray-guided feedback's and the image-adaptive oracle's.
    double voxelMm = 0;
    for (int a = 0; a < 3; ++a) voxelMm = std::max(voxelMm, length(patientFromIndex.column(a)));
    const double pixelScale = camera.projection == Projection::Perspective
                                  ? 2.0 * camera.tanHalfFovY() / camera.height
                                  : camera.orthoHeightMm / camera.height;
    glUniform1f(prog.uniform("uLeafVoxelMm"), static_cast<float>(voxelMm));
    glUniform1f(prog.uniform("uPixelScale"), static_cast<float>(pixelScale));
  }
  if (feedback) {
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 4, im.feedbackBuffer.id());
    // Ray-guided feedback (GigaVoxels): a ray wants finer data in a leaf whose voxels project
    // larger than lodPixels where the ray enters it.
    glUniform1f(prog.uniform("uLodPixels"), static_cast<float>(options.lodPixels));
  }
  if (adaptive) {
    const uint32_t zeros[2] = {0, 0};
    glNamedBufferData(im.adaptiveBuffer.id(), sizeof(zeros), zeros, GL_DYNAMIC_READ);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 5, im.adaptiveBuffer.id());
    im.ensurePyramid(width, height, options.imageAdaptiveLevels);
  }

  glBindFramebuffer(GL_FRAMEBUFFER, im.fbo.id());
  const GLenum buffers[3] = {GL_COLOR_ATTACHMENT0, GL_COLOR_ATTACHMENT1, GL_COLOR_ATTACHMENT2};
  glNamedFramebufferDrawBuffers(im.fbo.id(), options.stats ? 3 : 2, buffers);
  glViewport(0, 0, width, height);
  glDisable(GL_BLEND);
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_ALWAYS);
  glDepthMask(GL_TRUE);
  glBindVertexArray(im.vao.id());
  throwOnGlError("setting up the raycasting pass");

  glFinish();
  const auto drawStart = std::chrono::steady_clock::now();
  // The image-adaptive passes (see "Adaptive sampling in the image plane" in raycast.frag.glsl).
  GlProgram* refineProg = nullptr;
  GlProgram* depthProg = nullptr;
  if (adaptive) {
    std::vector<std::string> refineDefines;
    if (options.stats) refineDefines.emplace_back("STATS");
    refineProg = &im.program(refineDefines, "image_adaptive.frag.glsl");
    depthProg = &im.program({}, "depth_from_aux.frag.glsl");
    glUseProgram(refineProg->id());
    glUniform1f(refineProg->uniform("uAdaptiveThreshold"), static_cast<float>(options.imageAdaptive));
    glUniform1i(refineProg->uniform("uCoarseColor"), 6);
    glUniform1i(refineProg->uniform("uCoarseAux"), 7);
    glUseProgram(depthProg->id());
    glUniform1i(depthProg->uniform("uAux"), 6);
    glUseProgram(prog.id());
  }
  // Level l of the pyramid into `target`, which is bound (within the scissor, if any): the
  // pixels the level above allows are interpolated (stencil 1), then the others are cast.
  const auto drawLevel = [&](int l, const GlFramebuffer& target) {
    const GLint zero = 0;
    glDisable(GL_DEPTH_TEST);
    glDepthMask(GL_FALSE);
    glEnable(GL_STENCIL_TEST);
    glStencilMask(0xFF);
    glClearNamedFramebufferiv(target.id(), GL_STENCIL, 0, &zero);
    if (l < options.imageAdaptiveLevels) {
      const Impl::PyramidLevel& above = *im.pyramid[static_cast<std::size_t>(l)];
      glBindTextureUnit(6, above.color.id());
      glBindTextureUnit(7, above.aux.id());
      glUseProgram(refineProg->id());
      glUniform1f(refineProg->uniform("uLevelScale"), static_cast<float>(1 << l));
      glStencilFunc(GL_ALWAYS, 1, 0xFF);
      glStencilOp(GL_KEEP, GL_KEEP, GL_REPLACE);
      glDrawArrays(GL_TRIANGLES, 0, 3);
      glUseProgram(prog.id());
    }
    glUniform1f(prog.uniform("uLevelScale"), static_cast<float>(1 << l));
    glStencilFunc(GL_EQUAL, 0, 0xFF);
    glStencilOp(GL_KEEP, GL_KEEP, GL_KEEP);
    glDrawArrays(GL_TRIANGLES, 0, 3);
    glDisable(GL_STENCIL_TEST);
    glEnable(GL_DEPTH_TEST);
    glDepthMask(GL_TRUE);
  };
  // The whole image (within the scissor, if any).
  const auto drawImage = [&] {
    if (!adaptive) {
      glDrawArrays(GL_TRIANGLES, 0, 3);
      return;
    }
    drawLevel(0, im.fbo);
    // The depth buffer from the depth values the passes carried in aux.w.
    glBindFramebuffer(GL_FRAMEBUFFER, im.depthFbo.id());
    glBindTextureUnit(6, im.targets[1].id());
    glUseProgram(depthProg->id());
    glDrawArrays(GL_TRIANGLES, 0, 3);
    glUseProgram(prog.id());
    glBindFramebuffer(GL_FRAMEBUFFER, im.fbo.id());
  };
  if (adaptive) {
    // The levels above the image, coarsest first; each but the coarsest interpolates from the
    // one above where it may.
    for (int l = options.imageAdaptiveLevels; l >= 1; --l) {
      const Impl::PyramidLevel& p = *im.pyramid[static_cast<std::size_t>(l - 1)];
      glBindFramebuffer(GL_FRAMEBUFFER, p.fbo.id());
      glViewport(0, 0, p.width, p.height);
      drawLevel(l, p.fbo);
    }
    glBindFramebuffer(GL_FRAMEBUFFER, im.fbo.id());
    glViewport(0, 0, width, height);
  }
  if (tiles == nullptr || tiles->tiles.empty()) {
    drawImage();
  } else {
    // Tile by tile, each followed by the caller's work on it (the occlusion queries).
    glEnable(GL_SCISSOR_TEST);
    for (std::size_t i = 0; i < tiles->tiles.size(); ++i) {
      const ScreenTile& t = tiles->tiles[i];
      glScissor(t.x, t.y, t.width, t.height);
      drawImage();
      if (tiles->afterTile) {
        tiles->afterTile(i);
        glUseProgram(prog.id());
        glBindVertexArray(im.vao.id());
        glColorMask(GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
        glDepthMask(GL_TRUE);
        glDepthFunc(GL_ALWAYS);
        glEnable(GL_SCISSOR_TEST);  // the queries turn it off
      }
    }
    glDisable(GL_SCISSOR_TEST);
  }
  glFinish();
  stats.drawMs = millisecondsSince(drawStart);
  throwOnGlError("raycasting");

  // Read back (GL rows run bottom-up; Image row 0 is the top).
  const std::size_t pixels = static_cast<std::size_t>(width) * static_cast<std::size_t>(height);
  std::vector<float>& color = im.readColor;
  std::vector<float>& aux = im.readAux;
  std::vector<float>& counters = im.readCounters;
  color.resize(pixels * 4);
  aux.resize(pixels * 4);
  glPixelStorei(GL_PACK_ALIGNMENT, 4);
  glGetTextureImage(im.targets[0].id(), 0, GL_RGBA, GL_FLOAT, static_cast<GLsizei>(color.size() * 4), color.data());
  glGetTextureImage(im.targets[1].id(), 0, GL_RGBA, GL_FLOAT, static_cast<GLsizei>(aux.size() * 4), aux.data());
  if (options.stats) {
    counters.resize(pixels * 4);
    glGetTextureImage(im.targets[2].id(), 0, GL_RGBA, GL_FLOAT, static_cast<GLsizei>(counters.size() * 4),
                      counters.data());
  }
  frame.image = Image(width, height);
  const bool wantValue = options.mode != RaycastMode::Dvr;
  if (wantValue) frame.value.assign(pixels, std::numeric_limits<float>::quiet_NaN());
  if (options.stats) {
    frame.leafCounts.assign(pixels, 0);
    frame.samples.assign(pixels, 0);
  }
  double samples = 0, contributing = 0, leavesVisited = 0;
  for (int y = 0; y < height; ++y) {
    const std::size_t src = static_cast<std::size_t>(height - 1 - y) * static_cast<std::size_t>(width);
    const std::size_t dst = static_cast<std::size_t>(y) * static_cast<std::size_t>(width);
    std::copy_n(&color[src * 4], static_cast<std::size_t>(width) * 4, &frame.image.rgba[dst * 4]);
    for (int x = 0; x < width; ++x) {
      const float* a = &aux[(src + static_cast<std::size_t>(x)) * 4];
      frame.image.depth[dst + static_cast<std::size_t>(x)] = a[0];
      if (wantValue && std::isfinite(a[0])) frame.value[dst + static_cast<std::size_t>(x)] = a[1];
      if (options.stats) {
        const float* c = &counters[(src + static_cast<std::size_t>(x)) * 4];
        frame.samples[dst + static_cast<std::size_t>(x)] = c[0];
        frame.leafCounts[dst + static_cast<std::size_t>(x)] = c[2];
        samples += c[0];
        contributing += c[1];
        leavesVisited += c[2];
        if (c[2] > 0) ++stats.pixelsCovered;
      }
    }
  }
  if (adaptive) {
    uint32_t counted[2] = {0, 0};
    glGetNamedBufferSubData(im.adaptiveBuffer.id(), 0, sizeof(counted), counted);
    stats.raysCast = counted[0];
    if (options.stats) stats.samplesTaken = counted[1];
  } else {
    stats.raysCast = static_cast<int64_t>(pixels);
    if (options.stats) stats.samplesTaken = static_cast<int64_t>(samples);
  }
  if (options.stats) {
    const double covered = std::max<double>(1.0, static_cast<double>(stats.pixelsCovered));
    stats.samplesPerPixel = samples / covered;
    stats.contributingPerPixel = contributing / covered;
    stats.leavesPerPixel = leavesVisited / covered;
    std::vector<uint32_t> touched(leafRecords);
    glGetNamedBufferSubData(im.touchedBuffer.id(), 0, static_cast<GLsizeiptr>(touched.size() * 4), touched.data());
    stats.bricksTouched = std::count(touched.begin(), touched.end(), 1u);
  }
  if (feedback) {
    std::vector<uint32_t> rayCounts(leafRecords * 2);
    if (!rayCounts.empty()) {
      glGetNamedBufferSubData(im.feedbackBuffer.id(), 0, static_cast<GLsizeiptr>(rayCounts.size() * 4),
                              rayCounts.data());
    }
    feedback->rays.resize(leafRecords);
    feedback->finer.resize(leafRecords);
    for (std::size_t r = 0; r < leafRecords; ++r) {
      feedback->rays[r] = rayCounts[2 * r];
      feedback->finer[r] = rayCounts[2 * r + 1];
    }
  }
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
  throwOnGlError("reading the frame back");
  return frame;
}

}  // namespace octoray::gpu
