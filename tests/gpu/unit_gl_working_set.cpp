// The persistent working set (working_set.h) with the loader, both caches and the raycaster
// (gpu_renderer.h): on random camera paths with TF, mode and LOD changes, small caches and a
// small upload budget, every frame's cut must be a valid cover of the non-empty domain
// (checked against a brute-force walk of every leaf brick of the store, with emptiness decided
// here from the TF's control points, not by the code under test), no ray may cross a hole
// (every empty leaf a ray of the CPU traversal mirror crosses is truly empty), caches stay in
// budget, the picture converges to the static one when the camera stops, feedback shrinks the
// set without changing the picture, the converged picture of a path matches the CPU reference
// rendered over the same LOD cut, a new TF reloads nothing cached, and a brick corrupted on
// disk mid-session gives one error and its ancestor.

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <random>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "file_damage.h"
#include "gl_test_support.h"
#include "octoray/core/error.h"
#include "octoray/dicom/formats.h"
#include "octoray/gpu/brick_pool.h"
#include "octoray/gpu/camera.h"
#include "octoray/gpu/camera_path.h"
#include "octoray/gpu/gpu_renderer.h"
#include "octoray/gpu/image_metrics.h"
#include "octoray/gpu/occlusion.h"
#include "octoray/gpu/reference/reference_renderer.h"
#include "octoray/gpu/spatial_index.h"
#include "octoray/transfer/transfer_function_io.h"
#include "octoray/volume/phantom.h"
#include "octoray/volume/store_builder.h"
#include "octoray/volume/store_reader.h"
#include "test_paths.h"
#include "test_stores.h"

namespace octoray::gpu {
namespace {

// 128 x 120 x 96 voxels in 16^3 bricks: 4 levels, 441 nodes.
const std::filesystem::path& workingSetPhantomStore() {
  static const std::filesystem::path path = [] {
    volume::PhantomOptions options;
    options.dims = {128, 120, 96};
    options.spacingMm = {0.7, 0.75, 0.9};
    options.seed = 11;
    return test::buildPhantomTestStore(options, "gl_working_set", 16);
  }();
  return path;
}

VolumeDomain domainOf(const volume::StoreReader& store) {
  return {store.layout().levelDims(store.layout().leafLevel()), store.patientFromIndex()};
}

Camera orbit(const volume::StoreReader& store, double azimuth, double elevation, double zoom, int size) {
  OrbitParameters o;
  o.azimuthDegrees = azimuth;
  o.elevationDegrees = elevation;
  o.zoom = zoom;
  o.width = o.height = size;
  return orbitCamera(domainOf(store), o);
}

// Independent emptiness: the TF's opacity is piecewise linear between its points and clamped
// outside them, so it is zero over [lo, hi] exactly when it is zero at lo, at hi and at every
// point inside.
bool transparentOver(const transfer::TransferFunction& tf, double lo, double hi) {
  if (tf.evaluate(lo)[3] > 0 || tf.evaluate(hi)[3] > 0) return false;
  for (const transfer::OpacityPoint& p : tf.opacity) {
    if (p.value >= lo && p.value <= hi && p.alpha > 0) return false;
  }
  return true;
}

struct View {
  RaycastMode mode = RaycastMode::Dvr;
  double iso = 0;
  const transfer::TransferFunction* tf = nullptr;
};

bool emptyNode(const volume::StoreReader& store, int64_t id, const View& view) {
  const volume::NodeRecord& n = store.node(id);
  if (view.mode == RaycastMode::Iso) return !(view.iso >= n.minValue && view.iso <= n.maxValue);
  // DVR: the stored range is widened by one quantisation step (the code under test widens by
  // one too; a node it keeps that this calls empty is only a wasted slot, not a hole).
  const double q = store.sampleFormat() == volume::SampleFormat::UInt16 ? store.header().valueScale : 0;
  return transparentOver(*view.tf, n.minValue - q, n.maxValue + q);
}

// Brute force over every leaf brick of the store: at most one node of the cut among it and its
// ancestors, and exactly one when none of them is empty; every cut node non-empty and resident
// in the slot the index names.
void expectValidCover(const GpuRenderer& renderer, const volume::StoreReader& store, const View& view,
                      const std::string& where) {
  const volume::OctreeLayout& layout = store.layout();
  const WorkingSet& ws = renderer.workingSet();
  const std::set<int64_t> cut(ws.cutNodes().begin(), ws.cutNodes().end());
  ASSERT_EQ(cut.size(), ws.cutNodes().size()) << where << ": a node listed twice";
  for (std::size_t i = 0; i < ws.cutNodes().size(); ++i) {
    const int64_t id = ws.cutNodes()[i];
    ASSERT_LT(ws.cut()[i].slot, static_cast<uint32_t>(renderer.pool().stats().slots)) << where;
    // Its own brick, or (drawn from an ancestor) the brick of the ancestor it names.
    int64_t data = id;
    for (int up = 0; up < ws.cut()[i].dataLevelsUp; ++up) data = layout.parent(data);
    ASSERT_GE(data, 0) << where;
    ASSERT_EQ(renderer.pool().nodeIn(ws.cut()[i].slot), data) << where << ": slot of node " << id;
    ASSERT_EQ(ws.cut()[i].key.level, layout.nodeKey(id).level) << where;
  }
  const int leaf = layout.leafLevel();
  const volume::Index3& bricks = layout.levelBricks(leaf);
  for (int64_t z = 0; z < bricks[2]; ++z) {
    for (int64_t y = 0; y < bricks[1]; ++y) {
      for (int64_t x = 0; x < bricks[0]; ++x) {
        int inCut = 0;
        bool anyEmpty = false;
        for (int64_t n = layout.nodeId({leaf, {x, y, z}}); n >= 0; n = layout.parent(n)) {
          inCut += cut.count(n) ? 1 : 0;
          anyEmpty = anyEmpty || emptyNode(store, n, view);
        }
        ASSERT_LE(inCut, 1) << where << ": overlapping nodes above leaf brick " << x << "," << y << "," << z;
        if (!anyEmpty) {
          ASSERT_EQ(inCut, 1) << where << ": hole at leaf brick " << x << "," << y << "," << z;
        }
      }
    }
  }
  for (int64_t id : cut) {
    // A cut node the test calls empty is allowed only when the code under test's wider bound
    // kept it (never the other way round, which the loop above catches as a hole).
    if (emptyNode(store, id, view)) {
      const volume::NodeRecord& n = store.node(id);
      ADD_FAILURE() << where << ": empty node " << id << " [" << n.minValue << ", " << n.maxValue
                    << "] drawn";
    }
  }
}

// True when every leaf brick of the store inside node `key`'s box has an empty node among
// itself and its ancestors (so nothing there can show); nodes outside the store count as empty.
bool regionEmpty(const volume::StoreReader& store, const volume::NodeKey& key, const View& view) {
  const volume::OctreeLayout& layout = store.layout();
  const volume::Index3& bricks = layout.levelBricks(key.level);
  for (int a = 0; a < 3; ++a) {
    if (key.brick[a] >= bricks[a]) return true;
  }
  const int64_t id = layout.nodeId(key);
  for (int64_t n = id; n >= 0; n = layout.parent(n)) {
    if (emptyNode(store, n, view)) return true;
  }
  if (key.level == layout.leafLevel()) return false;
  for (int c = 0; c < 8; ++c) {
    const volume::NodeKey child{key.level + 1,
                                {2 * key.brick[0] + (c & 1), 2 * key.brick[1] + ((c >> 1) & 1),
                                 2 * key.brick[2] + ((c >> 2) & 1)}};
    if (!regionEmpty(store, child, view)) return false;
  }
  return true;
}

// The CPU traversal mirror over the last index for a grid of pixels: every empty leaf a ray
// crosses with length must be outside the store or under an empty node.
void expectNoHoleOnRays(const GpuRenderer& renderer, const volume::StoreReader& store,
                        const Camera& camera, const View& view, const std::string& where) {
  const SpatialIndex& index = renderer.lastIndex();
  for (int y = 1; y < camera.height; y += 7) {
    for (int x = 2; x < camera.width; x += 7) {
      const OctreeRay ray = renderer.pixelRay(camera, x, y);
      const OctreeChord chord = clipOctreeDomain(ray, renderer.domainMax(camera), 0.0f);
      if (!(chord.tFar > chord.tNear)) continue;
      traverseRay(index, ray, chord.tNear, chord.tFar, [&](const LeafCrossing& c) {
        if (c.kind != kEmptyLeaf || !(c.tExit > c.tEnter)) return true;
        const double cells = std::exp2(c.level);
        const std::array<int64_t, 3> b{static_cast<int64_t>(std::floor(c.boxMin[0] * cells)),
                                       static_cast<int64_t>(std::floor(c.boxMin[1] * cells)),
                                       static_cast<int64_t>(std::floor(c.boxMin[2] * cells))};
        const bool empty = regionEmpty(store, {c.level, b}, view);
        EXPECT_TRUE(empty) << where << ": pixel " << x << "," << y << " crosses a hole at level "
                           << c.level << " brick " << b[0] << "," << b[1] << "," << b[2];
        return empty;
      });
    }
  }
}

// One frame per camera of `path`, then the last camera again until the working set settles
// (at most 200 more frames) and, with `untilNothingUploads`, until a frame uploads nothing too
// (a repack copies the cut one frame after settling). The last frame drawn.
Frame followPathUntilSettled(GpuRenderer& renderer, const std::vector<Camera>& path,
                             const transfer::TransferFunction& tf, const RaycastOptions& options,
                             bool untilNothingUploads = false) {
  for (const Camera& c : path) renderer.renderFrame(c, tf, options);
  Frame last;
  int frames = 0;
  do {
    last = renderer.renderFrame(path.back(), tf, options);
    if (!renderer.workingSet().settled()) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  } while (!(renderer.workingSet().settled() && (!untilNothingUploads || last.stats.workingSet.uploaded == 0)) &&
           ++frames < 200);
  return last;
}

double coverage(const Image& image) {
  double sum = 0;
  for (std::size_t i = 3; i < image.rgba.size(); i += 4) sum += image.rgba[i];
  return sum / (static_cast<double>(image.rgba.size()) / 4);
}

class WorkingSetTest : public GlTest {};

// Occlusion queries by hand: an opaque slab fills the window's left half at depth 0.25 (the
// raycaster's role, played here by a clear and a scissored depth clear); a box in front of it
// passes on its whole projected area, the same box behind it only where the slab is not.
TEST_F(WorkingSetTest, OcclusionQueriesCountThePixelsInFrontOfTheRaysLastSamples) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  Camera camera;
  camera.projection = Projection::Orthographic;
  camera.eye = {0, -100, 0};
  camera.target = {0, 0, 0};
  camera.up = {0, 0, 1};
  camera.orthoHeightMm = 64;
  camera.width = camera.height = 64;  // 1 mm per pixel
  const DepthRange depth{50, 150, false};  // window depth = (y + 50) / 100
  const auto box = [](double x0, double x1, double y0, double y1) {
    std::array<Vec3, 8> c;
    for (int i = 0; i < 8; ++i) c[static_cast<std::size_t>(i)] = {(i & 1) ? x1 : x0, (i & 2) ? y1 : y0, (i & 4) ? 8.0 : -8.0};
    return c;
  };
  // x in [-16, 16] (32 px) by z in [-8, 8] (16 px): 512 pixels; half of it behind the slab.
  const std::vector<std::array<Vec3, 8>> boxes = {box(-16, 16, -40, -30), box(-16, 16, -10, 0)};
  GlTexture colour(GL_TEXTURE_2D), depthTexture(GL_TEXTURE_2D);
  glTextureStorage2D(colour.id(), 1, GL_RGBA8, 64, 64);
  glTextureStorage2D(depthTexture.id(), 1, GL_DEPTH_COMPONENT32F, 64, 64);
  GlFramebuffer fbo;
  glNamedFramebufferTexture(fbo.id(), GL_COLOR_ATTACHMENT0, colour.id(), 0);
  glNamedFramebufferTexture(fbo.id(), GL_DEPTH_ATTACHMENT, depthTexture.id(), 0);
  glBindFramebuffer(GL_FRAMEBUFFER, fbo.id());
  glViewport(0, 0, 64, 64);
  glEnable(GL_DEPTH_TEST);
  glDepthMask(GL_TRUE);
  glClearDepth(1.0);
  glClear(GL_DEPTH_BUFFER_BIT);
  glEnable(GL_SCISSOR_TEST);
  glScissor(0, 0, 32, 64);  // the slab: rays stopped at y = -25 mm on the left half
  glClearDepth(0.25);
  glClear(GL_DEPTH_BUFFER_BIT);
  glDisable(GL_SCISSOR_TEST);
  OcclusionQueries queries;
  const std::vector<ScreenTile>& tiles = queries.plan(camera, depth, boxes, 1);
  ASSERT_GE(tiles.size(), 1u);
  int64_t area = 0;
  for (const ScreenTile& t : tiles) area += int64_t{t.width} * t.height;
  EXPECT_EQ(area, 64 * 64) << "the tiles partition the window";
  for (std::size_t t = 0; t < tiles.size(); ++t) queries.issue(t);
  const std::vector<uint32_t> samples = queries.results();
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
  ASSERT_EQ(samples.size(), 2u);
  EXPECT_EQ(samples[0], 512u) << "in front of the slab: every pixel of its front face";
  EXPECT_EQ(samples[1], 256u) << "behind the slab: only the right half";
  EXPECT_TRUE(context_->takeErrors().empty());
}

TEST_F(WorkingSetTest, CutIsAlwaysAValidCoverWithoutHolesOnRandomPaths) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const volume::StoreReader store(workingSetPhantomStore().string());
  const std::vector<transfer::TransferFunction> tfs = {
      transfer::findPreset("bone"), transfer::findPreset("soft-tissue"), transfer::findPreset("skin")};
  for (const Visibility visibility : {Visibility::None, Visibility::Rays, Visibility::Occlusion}) {
    RendererConfig config;
    const std::size_t slotBytes = std::size_t{20 * 20 * 20 * 2};
    config.poolBytes = 60 * slotBytes;       // 60 slots of 441 nodes: refinement hits the pool
    config.cacheBytes = 40 * (slotBytes + sizeof(volume::Brick));  // and the CPU cache evicts
    config.uploadBytesPerFrame = 5 * slotBytes;
    config.visibility = visibility;
    config.visibilityThreshold = 1;
    GpuRenderer renderer(store, config);
    std::mt19937 random(5 + static_cast<unsigned>(visibility));
    std::uniform_real_distribution<double> unit(0, 1);
    View view{RaycastMode::Dvr, 0, &tfs[0]};
    RaycastOptions options;
    Camera camera = orbit(store, 0, 0, 1, 64);
    int64_t maxUploadBytes = 0, refinedFrames = 0, frames = 0;
    for (int f = 0; f < 60; ++f) {
      if (f % 6 == 0) {  // a new view, TF, mode or LOD now and then
        camera = orbit(store, 360 * unit(random), 160 * unit(random) - 80, 0.7 + 3.5 * unit(random), 64);
        const double r = unit(random);
        view.mode = r < 0.25 ? RaycastMode::Iso : RaycastMode::Dvr;
        view.iso = -200 + 1400 * unit(random);
        view.tf = &tfs[static_cast<std::size_t>(f / 6) % tfs.size()];
        options.mode = view.mode;
        options.isoValue = view.iso;
        options.lodPixels = std::array{0.0, 0.5, 1.0, 2.0}[static_cast<std::size_t>(f / 6) % 4];
      } else {  // small drags between
        camera = turnAboutCentre(camera, domainOf(store).centrePatient(), 3.0);
      }
      const std::string where = "visibility " + std::string(visibilityName(visibility)) + ", frame " + std::to_string(f);
      const Frame frame = renderer.renderFrame(camera, *view.tf, options);
      ++frames;
      ASSERT_TRUE(frame.stats.errors.empty()) << where;
      expectValidCover(renderer, store, view, where);
      expectNoHoleOnRays(renderer, store, camera, view, where);
      // Budgets: the CPU cache's, the pool's slots, the frame's uploads (the first split of a
      // frame may exceed a budget below one node's eight children).
      EXPECT_LE(renderer.cache().stats().bytes, config.cacheBytes) << where;
      EXPECT_LE(renderer.pool().stats().slotsUsed, renderer.pool().stats().slots) << where;
      maxUploadBytes = std::max<int64_t>(maxUploadBytes, static_cast<int64_t>(frame.stats.workingSet.uploadBytes));
      EXPECT_LE(frame.stats.workingSet.uploadBytes, std::max<uint64_t>(config.uploadBytesPerFrame, 8 * slotBytes)) << where;
      refinedFrames += frame.stats.workingSet.split > 0 ? 1 : 0;
      if (HasFatalFailure()) return;
    }
    EXPECT_GT(refinedFrames, 10) << "the walk must actually refine";
    EXPECT_GT(maxUploadBytes, 0);
    EXPECT_TRUE(context_->takeErrors().empty());
  }
}

TEST_F(WorkingSetTest, PictureConvergesToTheStaticOneWhenTheCameraStops) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const volume::StoreReader store(workingSetPhantomStore().string());
  const transfer::TransferFunction tf = transfer::findPreset("bone");
  RaycastOptions options;
  options.lodPixels = 0.5;
  OrbitParameters start;
  start.width = start.height = 96;
  const std::vector<Camera> path = cameraPath("orbit:12,degrees:120,zoom-from:1,zoom-to:2.5", domainOf(store), start);
  Frame still;
  {
    RendererConfig reference;  // feedback off, no budget: the static picture
    GpuRenderer renderer(store, reference);
    still = renderer.render(path.back(), tf, options);
  }
  ASSERT_GT(coverage(still.image), 0.1);
  for (const Visibility visibility : {Visibility::None, Visibility::Rays}) {
    RendererConfig config;
    config.uploadBytesPerFrame = 6 * 20 * 20 * 20 * 2;
    config.visibility = visibility;
    config.visibilityThreshold = 1;
    GpuRenderer renderer(store, config);
    const Frame last = followPathUntilSettled(renderer, path, tf, options);
    ASSERT_TRUE(renderer.workingSet().settled()) << visibilityName(visibility);
    const ImageMetrics m = compare(still.image, last.image);
    if (visibility == Visibility::None) {
      // The same cut; only the bricks' places in the pool differ, which moves texture
      // coordinates by float rounding: the same 8-bit picture.
      EXPECT_LE(m.maxAbsError, 1.0 / 255) << "the same cut must give the same picture";
      EXPECT_EQ(last.stats.workingSetBricks, still.stats.workingSetBricks);
    }
    EXPECT_GE(m.psnrDb, 40.0) << visibilityName(visibility);
  }
}

TEST_F(WorkingSetTest, VisibilityFeedbackShrinksTheSetButNotThePicture) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const volume::StoreReader store(workingSetPhantomStore().string());
  // Opaque bone: the rays stop in the near wall of the skull.
  transfer::TransferFunction tf = transfer::findPreset("bone");
  tf.opacity = {{150, 0.0f}, {300, 1.0f}};
  RaycastOptions options;
  options.lodPixels = 0;
  const Camera camera = orbit(store, 30, 10, 2.5, 128);
  RendererConfig none;
  GpuRenderer withoutFeedback(store, none);
  const Frame a = withoutFeedback.render(camera, tf, options);
  ASSERT_GT(coverage(a.image), 0.3) << "zoomed into the skull: most of the picture is bone";
  // What rays sample of the set without feedback (the counting variant, same cut).
  RaycastOptions counting = options;
  counting.stats = true;
  const int64_t sampled = withoutFeedback.render(camera, tf, counting).stats.bricksTouched;
  ASSERT_GT(sampled, 0);
  ASSERT_LT(sampled, a.stats.workingSetBricks * 3 / 4) << "the view must hide something";
  for (const Visibility visibility : {Visibility::Rays, Visibility::Occlusion, Visibility::Both}) {
    RendererConfig config;
    config.visibility = visibility;
    GpuRenderer withFeedback(store, config);
    const Frame b = withFeedback.render(camera, tf, options);
    // The acceptance's relative bar: no more than the sampled bricks plus 20 % of the rest.
    EXPECT_LE(b.stats.workingSetBricks, sampled + (a.stats.workingSetBricks - sampled) / 5)
        << visibilityName(visibility) << ": without feedback " << a.stats.workingSetBricks
        << ", sampled " << sampled;
    const ImageMetrics m = compare(a.image, b.image);
    EXPECT_GE(m.psnrDb, 40.0) << visibilityName(visibility);
    EXPECT_GT(b.stats.workingSet.hiddenLeaves, 0) << visibilityName(visibility);
    if (visibility != Visibility::Rays) {
      EXPECT_GT(b.stats.queriesIssued, 0);
    }
    EXPECT_TRUE(context_->takeErrors().empty());
  }
}

// The acceptance's check of a converged picture, on a cut of several levels: after a path with
// ray feedback and an upload budget the camera stops; once the working set settles, the
// picture must match the CPU reference rendered over the very cut it was drawn from (only the
// cut's bricks read), closer than it matches the full-resolution reference.
TEST_F(WorkingSetTest, ConvergedPictureMatchesTheCpuReferenceOverItsCut) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const volume::StoreReader store(workingSetPhantomStore().string());
  const transfer::TransferFunction tf = transfer::findPreset("bone");
  RaycastOptions options;
  options.lodPixels = 2;  // coarse: leaves of several levels
  OrbitParameters start;
  start.width = start.height = 112;
  const std::vector<Camera> path = cameraPath("orbit:8,degrees:90,zoom-from:1,zoom-to:1.8", domainOf(store), start);
  RendererConfig config;
  config.visibility = Visibility::Rays;
  config.uploadBytesPerFrame = 8 * 20 * 20 * 20 * 2;
  GpuRenderer renderer(store, config);
  const Frame last = followPathUntilSettled(renderer, path, tf, options);
  ASSERT_TRUE(renderer.workingSet().settled());
  ASSERT_GT(coverage(last.image), 0.1);

  std::vector<reference::CutLeafRef> leaves;
  std::set<int> levels;
  for (const CutLeaf& leaf : renderer.workingSet().cut()) {
    leaves.push_back({leaf.key, leaf.dataLevelsUp});
    levels.insert(leaf.key.level - leaf.dataLevelsUp);
  }
  ASSERT_GE(levels.size(), 2u) << "the check needs a cut of several levels";
  reference::RenderOptions ro;
  ro.stepMm = renderer.defaultStepMm();
  const reference::ReferenceVolume overCut = reference::ReferenceVolume::fromCut(store, leaves);
  const Image cpu = reference::ReferenceRenderer(overCut).render(path.back(), tf, ro).image;
  const ImageMetrics m = compare(cpu, last.image);
  EXPECT_GE(m.psnrDb, 40.0) << "SSIM " << m.ssim;
  const reference::ReferenceVolume full = reference::ReferenceVolume::fromStore(store);
  const Image fine = reference::ReferenceRenderer(full).render(path.back(), tf, ro).image;
  const double fullPsnr = compare(fine, last.image).psnrDb;
  RecordProperty("psnrOverCutDb", std::to_string(m.psnrDb));
  RecordProperty("psnrFullDb", std::to_string(fullPsnr));
  RecordProperty("dataLevels", static_cast<int>(levels.size()));
  EXPECT_GT(m.psnrDb, fullPsnr + 3.0)
      << "the picture is the cut's: the reference over the cut must be the closer one";
}

// repackWhenSettled: a settled cut sits in the pool's first slots in node order, so the same
// view converged after any history is the same picture, float for float (without it, bricks
// in other slots round their texture coordinates differently: test above).
TEST_F(WorkingSetTest, RepackedConvergedViewIsTheSamePictureWhateverTheHistory) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const volume::StoreReader store(workingSetPhantomStore().string());
  const transfer::TransferFunction tf = transfer::findPreset("bone");
  RaycastOptions options;
  options.lodPixels = 0.5;
  OrbitParameters start;
  start.width = start.height = 96;
  const std::vector<Camera> path = cameraPath("orbit:12,degrees:200,zoom-from:1,zoom-to:2.5", domainOf(store), start);
  RendererConfig config;
  config.visibility = Visibility::Rays;
  config.repackWhenSettled = true;
  Frame fresh;
  {
    GpuRenderer renderer(store, config);
    fresh = renderer.render(path.back(), tf, options);
  }
  GpuRenderer renderer(store, config);
  const Frame last = followPathUntilSettled(renderer, path, tf, options, true);
  ASSERT_TRUE(renderer.workingSet().settled());
  ASSERT_GT(coverage(last.image), 0.1);
  EXPECT_EQ(last.stats.workingSet.leaves, fresh.stats.workingSet.leaves);
  // Slots 0 .. n-1 hold the cut's bricks in node order, and nothing else is resident.
  std::vector<int64_t> data{0};
  for (const CutLeaf& leaf : renderer.workingSet().cut()) data.push_back(renderer.pool().nodeIn(leaf.slot));
  std::sort(data.begin(), data.end());
  data.erase(std::unique(data.begin(), data.end()), data.end());
  EXPECT_EQ(renderer.pool().stats().slotsUsed, static_cast<int64_t>(data.size()));
  for (std::size_t k = 0; k < data.size(); ++k) EXPECT_EQ(renderer.pool().slotOf(data[k]), static_cast<int64_t>(k));
  const ImageMetrics m = compare(fresh.image, last.image);
  EXPECT_EQ(m.maxAbsError, 0.0) << m.psnrDb << " dB";
  EXPECT_EQ(m.maxAlphaError, 0.0);
}

// The acceptance's relative bar on real heads, where a view hides little: the default
// feedback (rays) keeps no more than the bricks some ray samples without feedback plus 20 %
// of the rest, with the same picture. Nodes no ray asks finer of but whose children are all
// empty are split into nothing, as without feedback (kept whole, each held a brick of its
// own: 2-3 bricks over the bar on the tilted head), and unseen leaves drawn from the root
// cost no brick.
TEST_F(WorkingSetTest, RealHeadsMeetTheRelativeBar) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  OCTORAY_REQUIRE_PATH(test::philipsDir());
  const transfer::TransferFunction tf = transfer::findPreset("bone");
  for (const char* series : {"S21570/S2020", "S21610/S2010"}) {
    const auto source = openVolume((test::philipsDir() / series).string());
    const std::filesystem::path path = test::freshTempDir("gl_working_set_heads") / "head.octoray";
    volume::BuildOptions build;
    build.border = 2;
    volume::buildStore(*source, path.string(), build);
    const volume::StoreReader store(path.string());
    for (const double zoom : {1.0, 2.0}) {
      const std::string where = std::string(series) + " zoom " + std::to_string(zoom);
      const Camera camera = orbit(store, 30, 10, zoom, 512);
      RaycastOptions options;
      GpuRenderer withoutFeedback(store, RendererConfig{});
      const Frame a = withoutFeedback.render(camera, tf, options);
      RaycastOptions counting = options;
      counting.stats = true;
      const int64_t sampled = withoutFeedback.render(camera, tf, counting).stats.bricksTouched;
      ASSERT_GT(sampled, 100) << where;
      RendererConfig config;
      config.visibility = Visibility::Rays;
      GpuRenderer withFeedback(store, config);
      const Frame b = withFeedback.render(camera, tf, options);
      const int64_t removable = a.stats.workingSetBricks - sampled;
      EXPECT_LE(b.stats.workingSetBricks * 5, sampled * 5 + removable)
          << where << ": without feedback " << a.stats.workingSetBricks << ", sampled " << sampled
          << ", with " << b.stats.workingSetBricks;
      EXPECT_GE(compare(a.image, b.image).psnrDb, 40.0) << where;
      // Feedback only keeps nodes coarser: each of its leaves is a leaf without feedback, or
      // an ancestor of one (never a node the cut without feedback split into nothing).
      std::set<int64_t> covered(withoutFeedback.workingSet().cutNodes().begin(),
                                withoutFeedback.workingSet().cutNodes().end());
      for (int64_t id : withoutFeedback.workingSet().cutNodes()) {
        for (int64_t n = store.layout().parent(id); n >= 0; n = store.layout().parent(n)) covered.insert(n);
      }
      for (int64_t id : withFeedback.workingSet().cutNodes()) {
        EXPECT_TRUE(covered.count(id)) << where << ": leaf " << id << " covers nothing the cut without feedback draws";
      }
    }
  }
}

TEST_F(WorkingSetTest, NewTransferFunctionReevaluatesEmptinessWithoutReloading) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const volume::StoreReader store(workingSetPhantomStore().string());
  const transfer::TransferFunction bone = transfer::findPreset("bone");
  const transfer::TransferFunction soft = transfer::findPreset("soft-tissue");
  RaycastOptions options;
  options.lodPixels = 0;
  const Camera camera = orbit(store, 120, 25, 1, 96);
  GpuRenderer renderer(store);
  const Frame first = renderer.render(camera, bone, options);
  const Frame other = renderer.render(camera, soft, options);
  EXPECT_NE(first.stats.workingSetBricks, other.stats.workingSetBricks) << "the TFs differ in emptiness";
  const uint64_t loadedBefore = renderer.loader().stats().loaded;
  const Frame again = renderer.render(camera, bone, options);
  EXPECT_EQ(renderer.loader().stats().loaded, loadedBefore) << "every brick was cached";
  EXPECT_EQ(compare(first.image, again.image).maxAbsError, 0.0);
  EXPECT_EQ(first.stats.workingSetBricks, again.stats.workingSetBricks);
}

TEST_F(WorkingSetTest, BrickCorruptedMidSessionGivesOneErrorAndItsAncestor) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const std::filesystem::path dir = test::freshTempDir("gl_working_set_corrupt");
  const std::filesystem::path copy = dir / "phantom.octoray";
  std::filesystem::copy_file(workingSetPhantomStore(), copy);
  const volume::StoreReader store(copy.string());
  const transfer::TransferFunction tf = transfer::findPreset("bone");
  const Camera camera = orbit(store, 60, 20, 1.5, 64);
  RaycastOptions coarse, fine;
  coarse.lodPixels = 1e6;  // the root only
  fine.lodPixels = 0;
  // A leaf brick the fine view needs (from a separate renderer over the intact file).
  int64_t victim = -1;
  {
    GpuRenderer probe(store);
    probe.render(camera, tf, fine);
    for (int64_t id : probe.workingSet().cutNodes()) {
      if (store.layout().nodeKey(id).level == store.layout().leafLevel() && store.node(id).payloadBytes > 0) {
        victim = id;
        break;
      }
    }
  }
  ASSERT_GE(victim, 0);
  GpuRenderer renderer(store);
  renderer.render(camera, tf, coarse);
  ASSERT_EQ(renderer.workingSet().cutNodes().size(), 1u);
  const volume::NodeRecord& n = store.node(victim);
  test::flipByte(copy, static_cast<std::streamoff>(n.payloadOffset + n.payloadBytes / 2));
  std::vector<std::string> errors;
  for (int f = 0; f < 60; ++f) {
    const Frame frame = renderer.renderFrame(camera, tf, fine);
    errors.insert(errors.end(), frame.stats.errors.begin(), frame.stats.errors.end());
    const std::vector<int64_t>& cut = renderer.workingSet().cutNodes();
    ASSERT_EQ(std::count(cut.begin(), cut.end(), victim), 0) << "the corrupted brick was drawn";
    if (renderer.workingSet().settled()) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  ASSERT_EQ(errors.size(), 1u) << "one message for the one corrupted brick";
  EXPECT_NE(errors[0].find(copy.string()), std::string::npos) << errors[0];
  const std::vector<int64_t>& cut = renderer.workingSet().cutNodes();
  EXPECT_EQ(std::count(cut.begin(), cut.end(), store.layout().parent(victim)), 1)
      << "its parent stands in for it";
  EXPECT_GT(cut.size(), 8u) << "the rest of the view still refined";
}

TEST_F(WorkingSetTest, ShutsDownCleanlyWhileBricksAreLoading) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const volume::StoreReader store(workingSetPhantomStore().string());
  const transfer::TransferFunction tf = transfer::findPreset("soft-tissue");
  RaycastOptions options;
  options.lodPixels = 0;
  for (int round = 0; round < 5; ++round) {
    RendererConfig config;
    config.loaderThreads = 2;
    config.uploadBytesPerFrame = 1;
    GpuRenderer renderer(store, config);
    for (int f = 0; f < 1 + round; ++f) renderer.renderFrame(orbit(store, 40.0 * f, 0, 1, 32), tf, options);
    // Destroyed with requests queued and loads in flight.
  }
  EXPECT_TRUE(context_->takeErrors().empty());
}

TEST_F(WorkingSetTest, PoolUsesItsWholeBudgetNotWholeLayers) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  // The 8 GiB phantom's case: 5773 slots of 36^3 wanted, at most 56 per axis (2048 texels).
  const std::array<int64_t, 3> grid = slotGridFor(5773, 56);
  EXPECT_LE(grid[0] * grid[1] * grid[2], 5773);
  EXPECT_GE(grid[0] * grid[1] * grid[2], 5773 * 95 / 100);
  for (int64_t a : grid) EXPECT_LE(a, 56);
  const volume::StoreReader store(workingSetPhantomStore().string());
  const std::size_t slotBytes = 20 * 20 * 20 * 2;
  for (const std::size_t budget : {std::size_t{1} << 20, std::size_t{3} << 20, 5 * slotBytes + 7}) {
    BrickPool pool(store, budget, false);
    const BrickPoolStats s = pool.stats();
    EXPECT_LE(s.bytes, budget);
    EXPECT_GE(static_cast<double>(s.bytes), 0.95 * static_cast<double>(budget) - static_cast<double>(slotBytes))
        << "budget " << budget;
  }
  EXPECT_THROW(BrickPool(store, slotBytes - 1, false), Error);
}

}  // namespace
}  // namespace octoray::gpu

namespace octoray::gpu {
namespace {

// The clip box cuts each ray to its chord inside the box: the whole domain changes nothing;
// half the columns leaves an orthographic MIP unchanged where rays stay in the kept half and
// empty where they run through the removed one.
TEST_F(WorkingSetTest, ClipBoxCutsTheRaysToTheBox) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const volume::StoreReader store(workingSetPhantomStore().string());
  const transfer::TransferFunction bone = transfer::findPreset("bone");
  OrbitParameters o;
  o.projection = Projection::Orthographic;
  o.width = o.height = 96;
  const Camera camera = orbitCamera(domainOf(store), o);  // anterior: rays along +Y
  GpuRenderer renderer(store);
  RaycastOptions options;
  options.lodPixels = 0;
  const Frame full = renderer.render(camera, bone, options);
  options.clip.enabled = true;
  options.clip.lo = {-0.5, -0.5, -0.5};
  options.clip.hi = {127.5, 119.5, 95.5};
  const Frame whole = renderer.render(camera, bone, options);
  EXPECT_EQ(compare(full.image, whole.image).maxAbsError, 0.0);

  // MIP with a TF under which every maximum shows (none is left unfound as invisible).
  transfer::TransferFunction seen = bone;
  seen.opacity = {{-1024, 0.05f}, {3000, 1.0f}};
  options.mode = RaycastMode::Mip;
  options.clip.enabled = false;
  const Frame mip = renderer.render(camera, seen, options);
  options.clip.enabled = true;
  options.clip.hi[0] = 63.5;
  const Frame half = renderer.render(camera, seen, options);
  const Mat4 indexFromPatient = store.patientFromIndex().inverseAffine();
  int kept = 0, removed = 0;
  for (int y = 0; y < 96; ++y) {
    for (int x = 0; x < 96; ++x) {
      const double i = indexFromPatient.transformPoint(camera.ray(x + 0.5, y + 0.5).origin).x;
      const std::size_t p = static_cast<std::size_t>(y * 96 + x);
      if (i < 62.5 && !std::isnan(mip.value[p])) {
        EXPECT_EQ(half.value[p], mip.value[p]) << x << "," << y;
        ++kept;
      } else if (i > 64.5 && !std::isnan(mip.value[p])) {
        EXPECT_TRUE(std::isnan(half.value[p])) << x << "," << y << " i " << i;
        ++removed;
      }
    }
  }
  EXPECT_GT(kept, 1000);
  EXPECT_GT(removed, 1000);
  options.clip.hi[0] = -1;  // lo > hi
  EXPECT_THROW(renderer.render(camera, seen, options), Error);
}

}  // namespace
}  // namespace octoray::gpu

namespace octoray::gpu {
namespace {

// The viewer's interactive quality: frames at half resolution and twice the LOD target while
// the camera turns, then the still camera at full quality. With ray feedback the converged
// cut must be the one a fresh renderer reaches for that camera (no visible leaf left merged
// because it was unseen in the coarse frames).
TEST_F(WorkingSetTest, ConvergesToTheSameCutAfterInteractiveFrames) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const volume::StoreReader store(workingSetPhantomStore().string());
  const transfer::TransferFunction bone = transfer::findPreset("bone");
  RendererConfig config;
  config.visibility = Visibility::Rays;
  RaycastOptions still;
  const Camera last = orbit(store, 40, 10, 1.3, 160);
  GpuRenderer fresh(store, config);
  const Frame reference = fresh.render(last, bone, still);

  GpuRenderer renderer(store, config);
  renderer.render(orbit(store, 0, 10, 1.3, 160), bone, still);  // converged before the drag
  RaycastOptions moving;
  moving.lodPixels = 2;
  for (int f = 1; f <= 3; ++f) {
    Camera c = orbit(store, f * 40.0 / 3, 10, 1.3, 80);
    renderer.renderFrame(c, bone, moving);
  }
  // The drag pauses: the half-resolution picture settles (no ray wants finer data at LOD 2).
  for (int f = 0; f < 6; ++f) renderer.renderFrame(orbit(store, 40, 10, 1.3, 80), bone, moving);
  Frame converged;
  for (int f = 0; f < 200; ++f) {
    converged = renderer.renderFrame(last, bone, still);
    // The viewer's test for a converged picture.
    if (renderer.workingSet().settled() && converged.stats.workingSet.uploaded == 0 &&
        converged.stats.workingSet.fetched == 0) {
      break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  EXPECT_EQ(converged.stats.workingSet.leaves, reference.stats.workingSet.leaves);
  EXPECT_GT(compare(converged.image, reference.image).psnrDb, 50.0);
}

}  // namespace
}  // namespace octoray::gpu
