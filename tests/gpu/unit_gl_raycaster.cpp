// The GPU raycaster (gpu_renderer.h) against the CPU reference renderer, the oracle: the same
// store, camera and transfer function at --lod-pixels 0 must give the reference's picture
// (DVR), its isosurface depths and its MIP maxima; per-pixel leaf counts must equal the CPU
// traversal mirror's; ramps must cross bricks without seams; variants must carry only the code
// of the effects they use; nothing may be NaN; no GL error may occur.
// The isosurface tests are in unit_gl_raycaster_iso.cpp, the MIP tests in
// unit_gl_raycaster_mip.cpp; what they share in raycaster_test_support.h.

#include <gtest/gtest.h>

#include "raycaster_test_support.h"

namespace octoray::gpu {
namespace {

using namespace raycaster_test;

TEST_F(RaycasterTest, ShadedDvrMatchesTheReferenceOnThePhantom) {
  OCTORAY_GL_TEST_PREAMBLE();
  const volume::StoreReader store(phantomStore().string());
  RaycastOptions options;
  options.lodPixels = 0;
  const transfer::TransferFunction tf = transfer::findPreset("bone");
  ASSERT_TRUE(tf.material.shade);
  for (const auto& [azimuth, elevation] : {std::pair{30.0, 20.0}, std::pair{200.0, -35.0}}) {
    const Camera camera = orbit(store, azimuth, elevation, 128);
    const Pair p = renderBoth(store, camera, tf, options);
    const ImageMetrics m = compare(p.reference.image, p.gpu.image);
    EXPECT_GE(m.psnrDb, 40.0) << "azimuth " << azimuth;
    EXPECT_GE(m.ssim, 0.98) << "azimuth " << azimuth;
    EXPECT_LE(m.maxAlphaError, 0.05) << "azimuth " << azimuth;
    // Not an empty picture matching an empty picture.
    double coverage = 0;
    for (std::size_t i = 3; i < p.reference.image.rgba.size(); i += 4) coverage += p.reference.image.rgba[i];
    EXPECT_GT(coverage, 0.1 * camera.width * camera.height);
  }
}

TEST_F(RaycasterTest, EnhancementsAndUnshadedDvrMatchTheReference) {
  OCTORAY_GL_TEST_PREAMBLE();
  const volume::StoreReader store(phantomStore().string());
  const Camera camera = orbit(store, 120, 10, 96, Projection::Orthographic);
  const transfer::TransferFunction tf = transfer::findPreset("bone");
  RaycastOptions options;
  options.lodPixels = 0;
  options.shading = RaycastOptions::Shading::Off;
  const Pair unshaded = renderBoth(store, camera, tf, options);
  ImageMetrics m = compare(unshaded.reference.image, unshaded.gpu.image);
  EXPECT_GE(m.psnrDb, 40.0);
  options.shading = RaycastOptions::Shading::On;
  options.boundary = {true, 0.2, 0.05, 0.8};
  const Pair p = renderBoth(store, camera, tf, options);
  m = compare(p.reference.image, p.gpu.image);
  EXPECT_GE(m.psnrDb, 40.0);
  EXPECT_GE(m.ssim, 0.98);
}

TEST_F(RaycasterTest, RampCrossesBricksAndLevelsWithoutSeams) {
  OCTORAY_GL_TEST_PREAMBLE();
  const volume::StoreReader store(rampStore().string());
  ASSERT_GT(store.layout().levels(), 2);
  RaycastOptions options;
  options.lodPixels = 0;
  for (const bool shade : {false, true}) {
    const Camera camera = orbit(store, 33, 27, 128, Projection::Perspective, 1.4);
    const Pair p = renderBoth(store, camera, rampTf(shade), options);
    const ImageMetrics m = compare(p.reference.image, p.gpu.image);
    EXPECT_GE(m.psnrDb, 50.0) << (shade ? "shaded" : "unshaded");
    EXPECT_LE(m.maxAbsError, 0.02) << (shade ? "shaded" : "unshaded");
    // Not an empty picture matching an empty picture.
    double coverage = 0;
    for (std::size_t i = 3; i < p.gpu.image.rgba.size(); i += 4) coverage += p.gpu.image.rgba[i];
    EXPECT_GT(coverage, 0.2 * camera.width * camera.height) << (shade ? "shaded" : "unshaded");
  }
  // MIP of a linear field is its value at an end of the chord; exact at every pixel, also
  // where rays run along brick faces (orthographic, axis-aligned view).
  options.mode = RaycastMode::Mip;
  for (const double azimuth : {0.0, 90.0, 17.0}) {
    const Camera camera = orbit(store, azimuth, 0, 100, Projection::Orthographic);
    const Pair p = renderBoth(store, camera, rampTf(false), options);
    double worst = 0;
    for (std::size_t i = 0; i < p.gpu.value.size(); ++i) {
      if (std::isnan(p.reference.value[i])) continue;
      worst = std::max(worst, std::abs(p.reference.value[i] - p.gpu.value[i]));
    }
    EXPECT_LE(worst, 0.05) << "azimuth " << azimuth;
  }
}

// Rays that run along brick faces (an orthographic view down the k axis of the sheared grid,
// pixel rows and columns dense enough that many rays lie within half a voxel of a face) are
// where a seam would show: their largest error against the reference must be no larger than
// that of the other rays (a missing or shifted border shows there as a step of the ramp's
// colour, a wrong gradient at the face as a line of different shading).
TEST_F(RaycasterTest, ErrorAtBrickFacesIsNoLargerThanElsewhere) {
  OCTORAY_GL_TEST_PREAMBLE();
  const volume::StoreReader store(rampStore().string());
  const Mat4 patientFromIndex = store.patientFromIndex();
  const Mat4 indexFromPatient = patientFromIndex.inverseAffine();
  const volume::Index3 dims = store.layout().levelDims(store.layout().leafLevel());
  const Vec3 centre = patientFromIndex.transformPoint(
      {0.5 * (dims[0] - 1), 0.5 * (dims[1] - 1), 0.5 * (dims[2] - 1)});
  const Vec3 along = normalize(patientFromIndex.column(2));
  Camera camera;
  camera.projection = Projection::Orthographic;
  camera.eye = centre - 200.0 * along;
  camera.target = centre;
  camera.up = patientFromIndex.column(1);
  camera.orthoHeightMm = 40.0;
  camera.width = camera.height = 160;
  const int brick = store.layout().brickSize();
  for (const bool shade : {false, true}) {
    RaycastOptions options;
    options.lodPixels = 0;
    const Pair p = renderBoth(store, camera, rampTf(shade), options);
    double worstAtFaces = 0, worstElsewhere = 0;
    int64_t facePixels = 0;
    for (int y = 0; y < camera.height; ++y) {
      for (int x = 0; x < camera.width; ++x) {
        const Vec3 index = indexFromPatient.transformPoint(camera.ray(x + 0.5, y + 0.5).origin);
        bool atFace = false;
        for (const double c : {index.x, index.y}) {
          // Brick faces lie at b * B - 0.5 in index space (voxel i owns [i - 0.5, i + 0.5]).
          const double face = std::round((c + 0.5) / brick) * brick - 0.5;
          atFace = atFace || std::abs(c - face) < 0.5;
        }
        const std::size_t i = static_cast<std::size_t>(y * camera.width + x) * 4;
        double error = 0;
        for (int ch = 0; ch < 4; ++ch) {
          error = std::max(error, static_cast<double>(std::abs(p.gpu.image.rgba[i + ch] -
                                                               p.reference.image.rgba[i + ch])));
        }
        if (p.reference.image.rgba[i + 3] <= 0) continue;  // outside the volume
        (atFace ? worstAtFaces : worstElsewhere) = std::max(atFace ? worstAtFaces : worstElsewhere, error);
        facePixels += atFace ? 1 : 0;
      }
    }
    EXPECT_GT(facePixels, 500) << "the view should put many rays along brick faces";
    // Both are single-precision noise (~1e-4) on a correct renderer; differences below half an
    // 8-bit display step cannot show, so that is the floor of "no larger".
    EXPECT_LE(worstAtFaces, std::max(worstElsewhere, 0.5 / 255))
        << (shade ? "shaded" : "unshaded") << ": a seam (elsewhere " << worstElsewhere << ")";
    std::printf("%s: largest error at brick faces %.3g, elsewhere %.3g (%lld face pixels)\n",
                shade ? "shaded" : "unshaded", worstAtFaces, worstElsewhere,
                static_cast<long long>(facePixels));
  }
}

// Coarser working sets: the picture degrades gracefully (no holes, no NaN), takes fewer
// bricks, and every brick still sits where it belongs (close to the full-resolution picture).
TEST_F(RaycasterTest, CoarserWorkingSetsStayCloseAndUseFewerBricks) {
  OCTORAY_GL_TEST_PREAMBLE();
  const volume::StoreReader store(phantomStore().string());
  const Camera camera = orbit(store, 45, 30, 128);
  const transfer::TransferFunction tf = transfer::findPreset("bone");
  GpuRenderer renderer(store);
  RaycastOptions options;
  options.lodPixels = 0;
  const Frame fine = renderer.render(camera, tf, options);
  int64_t previous = fine.stats.workingSetBricks;
  for (const double lod : {2.0, 4.0, 16.0}) {
    options.lodPixels = lod;
    const Frame coarse = renderer.render(camera, tf, options);
    EXPECT_EQ(nonFinite(coarse), 0);
    EXPECT_LE(coarse.stats.workingSetBricks, previous) << "lod " << lod;
    previous = coarse.stats.workingSetBricks;
    const ImageMetrics m = compare(fine.image, coarse.image);
    EXPECT_GE(m.psnrDb, lod <= 2 ? 25.0 : 15.0) << "lod " << lod;
  }
  EXPECT_LT(previous, fine.stats.workingSetBricks / 4) << "16 px voxels take far fewer bricks";
  EXPECT_TRUE(context_->takeErrors().empty());
}

// Per-pixel leaf counts of the shader equal those of traverseRay (the mirror) on the same
// index. The shader receives the ray from the same single-precision uniforms, but its
// normalize() and matrix product may round the last bit differently; where a 1-ulp change of
// the ray changes the mirror's count (the ray grazes a node boundary), the shader's count
// must be one of the mirror's answers; everywhere else it must be equal.
TEST_F(RaycasterTest, LeafCountsEqualTheTraversalMirror) {
  OCTORAY_GL_TEST_PREAMBLE();
  const volume::StoreReader store(phantomStore().string());
  transfer::TransferFunction tf = rampTf(false);
  tf.opacity = {{-1024, 0.0f}, {-500, 0.0f}, {-400, 0.001f}, {3071, 0.001f}};
  GpuRenderer renderer(store);
  RaycastOptions options;
  options.stats = true;
  options.earlyTermination = 1.0;  // rays never stop early: every leaf on the chord counts
  int64_t pixelsChecked = 0, unstable = 0;
  std::set<int> levelsSeen;
  const struct {
    double azimuth, elevation, lod;
    Projection projection;
  } views[] = {{0, 0, 0, Projection::Orthographic},
               {90, 0, 1, Projection::Orthographic},
               {31, 22, 0, Projection::Perspective},
               {140, -50, 3, Projection::Perspective},
               {260, 65, 8, Projection::Perspective}};
  for (const auto& view : views) {
    options.lodPixels = view.lod;
    const Camera camera = orbit(store, view.azimuth, view.elevation, 64, view.projection, 1.2);
    const Frame frame = renderer.render(camera, tf, options);
    const SpatialIndex& index = renderer.lastIndex();
    const std::array<float, 3> domainMax = renderer.domainMax(camera);
    const auto count = [&](const OctreeRay& ray) {
      const OctreeChord chord = clipOctreeDomain(ray, domainMax, 0.0f);
      if (!(chord.tFar >= chord.tNear)) return 0;
      int n = 0;
      traverseRay(index, ray, chord.tNear, chord.tFar, [&](const LeafCrossing& c) {
        ++n;
        levelsSeen.insert(c.level);
        return true;
      });
      return n;
    };
    for (int y = 0; y < camera.height; ++y) {
      for (int x = 0; x < camera.width; ++x) {
        const OctreeRay ray = renderer.pixelRay(camera, x, y);
        const int expected = count(ray);
        std::set<int> answers{expected};
        for (int k = 0; k < 6; ++k) {
          OctreeRay nudged = ray;
          float& component = k < 3 ? nudged.origin[static_cast<std::size_t>(k)]
                                   : nudged.direction[static_cast<std::size_t>(k - 3)];
          for (const float towards : {-INFINITY, INFINITY}) {
            const float saved = component;
            component = std::nextafter(component, towards);
            answers.insert(count(nudged));
            component = saved;
          }
        }
        const float got = frame.leafCounts[static_cast<std::size_t>(y * camera.width + x)];
        ++pixelsChecked;
        if (answers.size() == 1) {
          ASSERT_EQ(got, static_cast<float>(expected)) << "pixel (" << x << ", " << y << ")";
        } else {
          ++unstable;
          ASSERT_TRUE(answers.count(static_cast<int>(got)) > 0) << "pixel (" << x << ", " << y << ")";
        }
      }
    }
  }
  EXPECT_EQ(pixelsChecked, 5 * 64 * 64);
  EXPECT_LT(unstable, pixelsChecked / 100) << "grazing pixels";
  RecordProperty("unstablePixels", std::to_string(unstable));
  std::printf("leaf counts: %lld pixels, %lld where a 1-ulp change of the ray changes the count\n",
              static_cast<long long>(pixelsChecked), static_cast<long long>(unstable));
  EXPECT_GE(levelsSeen.size(), 2u) << "the cuts should mix levels";
  EXPECT_TRUE(context_->takeErrors().empty());
}

// A scene pays only for the effects it uses: the compiled variants keep the uniforms of the
// code they contain and nothing else (GL reports a uniform inactive when the compiled program
// does not use it).
TEST_F(RaycasterTest, VariantsContainOnlyTheEffectsTheyUse) {
  OCTORAY_GL_TEST_PREAMBLE();
  const volume::StoreReader store(phantomStore().string());
  GpuRenderer renderer(store);
  const transfer::TransferFunction tf = transfer::findPreset("bone");
  const auto active = [](unsigned program, const char* name) {
    return glGetUniformLocation(program, name) >= 0;
  };
  RaycastOptions options;
  options.shading = RaycastOptions::Shading::Off;
  unsigned program = renderer.variantProgram(tf, options);
  EXPECT_FALSE(active(program, "uNormalFromIndex")) << "gradient code without shading";
  EXPECT_FALSE(active(program, "uMaterial")) << "lighting code without shading";
  EXPECT_TRUE(active(program, "uTf"));
  EXPECT_TRUE(active(program, "uEarlyTermination"));

  options.shading = RaycastOptions::Shading::On;
  program = renderer.variantProgram(tf, options);
  EXPECT_TRUE(active(program, "uNormalFromIndex"));
  EXPECT_TRUE(active(program, "uMaterial"));
  EXPECT_FALSE(active(program, "uBoundary"));
  EXPECT_FALSE(active(program, "uSilhouette"));
  options.boundary.enabled = true;
  options.silhouette.enabled = true;
  program = renderer.variantProgram(tf, options);
  EXPECT_TRUE(active(program, "uBoundary"));
  EXPECT_TRUE(active(program, "uSilhouette"));

  options = {};
  options.mode = RaycastMode::Mip;
  options.shading = RaycastOptions::Shading::On;  // ignored in MIP
  program = renderer.variantProgram(tf, options);
  EXPECT_FALSE(active(program, "uTf")) << "opacity classification in MIP";
  EXPECT_FALSE(active(program, "uMaterial")) << "shading in MIP";
  EXPECT_FALSE(active(program, "uNormalFromIndex")) << "gradients in MIP";
  EXPECT_FALSE(active(program, "uEarlyTermination"));
  const std::vector<std::string> defines = renderer.variantDefines(tf, options);
  EXPECT_EQ(std::count(defines.begin(), defines.end(), "SHADING"), 0);

  options.mode = RaycastMode::Iso;
  options.shading = RaycastOptions::Shading::Off;
  program = renderer.variantProgram(tf, options);
  EXPECT_FALSE(active(program, "uTf"));
  EXPECT_FALSE(active(program, "uMaterial"));
  EXPECT_TRUE(context_->takeErrors().empty());
}

// The RGBA8 gradient pool (stores built with --gradients): shading from quantised gradients
// stays close to the reference's central differences.
TEST_F(RaycasterTest, GradientPoolShadingStaysCloseToTheReference) {
  OCTORAY_GL_TEST_PREAMBLE();
  static const std::filesystem::path path = [] {
    volume::PhantomOptions phantom;
    phantom.dims = {64, 64, 48};
    phantom.spacingMm = {0.8, 0.8, 1.0};
    const auto source = volume::makePhantom(phantom);
    const std::filesystem::path dir = test::freshTempDir("gl_raycaster_gradients");
    volume::BuildOptions options;
    options.brickSize = 16;
    options.border = 2;
    options.gradients = true;
    volume::buildStore(*source, (dir / "g.octoray").string(), options);
    return dir / "g.octoray";
  }();
  const volume::StoreReader store(path.string());
  const Camera camera = orbit(store, 40, 20, 96);
  const transfer::TransferFunction tf = transfer::findPreset("bone");
  RaycastOptions options;
  options.lodPixels = 0;
  RendererConfig config;
  config.gradientPool = true;
  GpuRenderer withPool(store, config);
  const std::vector<std::string> defines = withPool.variantDefines(tf, options);
  EXPECT_EQ(std::count(defines.begin(), defines.end(), "GRADIENT_POOL"), 1);
  const Frame pooled = withPool.render(camera, tf, options);
  const Frame computed = GpuRenderer(store).render(camera, tf, options);
  const ReferenceVolume volume = ReferenceVolume::fromStore(store);
  const auto reference = ReferenceRenderer(volume).render(camera, tf, referenceOptions(options));
  const ImageMetrics mPooled = compare(reference.image, pooled.image);
  const ImageMetrics mComputed = compare(reference.image, computed.image);
  EXPECT_EQ(nonFinite(pooled), 0);
  EXPECT_GE(mComputed.psnrDb, 40.0);
  EXPECT_GE(mPooled.psnrDb, 30.0) << "8-bit gradients";
  EXPECT_GE(mPooled.ssim, 0.95);
  EXPECT_LT(mPooled.psnrDb, mComputed.psnrDb) << "the pool should not be the path under test by accident";
  EXPECT_TRUE(context_->takeErrors().empty());
}

// View-dependent transparency (silhouette enhancement, which the reference lacks): neutral
// parameters change nothing; kC = 0, kS = 1 makes surfaces facing the viewer transparent, so
// coverage drops, and where it stays the picture is the edges'.
TEST_F(RaycasterTest, SilhouetteEnhancementIsNeutralOrThinsFacingSurfaces) {
  OCTORAY_GL_TEST_PREAMBLE();
  const volume::StoreReader store(phantomStore().string());
  const Camera camera = orbit(store, 0, 0, 96);
  const transfer::TransferFunction tf = transfer::findPreset("bone");
  GpuRenderer renderer(store);
  RaycastOptions options;
  options.lodPixels = 0;
  const Frame plain = renderer.render(camera, tf, options);
  options.silhouette = {true, 1.0, 0.0, 1.0};
  const Frame neutral = renderer.render(camera, tf, options);
  EXPECT_GE(compare(plain.image, neutral.image).psnrDb, 80.0);
  options.silhouette = {true, 0.0, 1.0, 2.0};
  const Frame thinned = renderer.render(camera, tf, options);
  const auto coverage = [](const Frame& f) {
    double sum = 0;
    for (std::size_t i = 3; i < f.image.rgba.size(); i += 4) sum += f.image.rgba[i];
    return sum;
  };
  EXPECT_LT(coverage(thinned), 0.9 * coverage(plain));
  EXPECT_GT(coverage(thinned), 0.0);
  EXPECT_EQ(nonFinite(thinned), 0);
  EXPECT_TRUE(context_->takeErrors().empty());
}

// Skipping the transparent cells of bricks is exact: the same picture bit for bit, from fewer
// samples (on the phantom and on the sheared ramp, where cells are transparent only in part).
TEST_F(RaycasterTest, CellSkippingChangesNoPixelAndTakesFewerSamples) {
  OCTORAY_GL_TEST_PREAMBLE();
  for (const std::filesystem::path* path : {&phantomStore(), &rampStore()}) {
    const volume::StoreReader store(path->string());
    GpuRenderer renderer(store);
    transfer::TransferFunction tf = path == &phantomStore() ? transfer::findPreset("bone") : rampTf(true);
    if (path == &rampStore()) tf.opacity = {{-900, 0.0f}, {-100, 0.0f}, {-99, 0.2f}, {200, 0.2f}, {201, 0.0f}};
    for (const double lod : {0.0, 3.0}) {
      RaycastOptions options;
      options.lodPixels = lod;
      options.stats = true;
      const Camera camera = orbit(store, 70, 35, 96);
      const Frame skipping = renderer.render(camera, tf, options);
      options.cellSkipping = false;
      const Frame sampling = renderer.render(camera, tf, options);
      EXPECT_EQ(skipping.image.rgba, sampling.image.rgba) << path->filename() << " lod " << lod;
      EXPECT_EQ(skipping.image.depth, sampling.image.depth) << path->filename() << " lod " << lod;
      EXPECT_LT(skipping.stats.samplesPerPixel, 0.9 * sampling.stats.samplesPerPixel)
          << path->filename() << " lod " << lod;
      EXPECT_GT(skipping.stats.contributingPerPixel, 0.0);
    }
  }
  EXPECT_TRUE(context_->takeErrors().empty());
}

TEST_F(RaycasterTest, SmallPoolKeepsTheWorkingSetCoarseInsteadOfFailing) {
  OCTORAY_GL_TEST_PREAMBLE();
  const volume::StoreReader store(phantomStore().string());
  RendererConfig config;
  const std::size_t edge = static_cast<std::size_t>(store.layout().storedEdge());
  config.poolBytes = 12 * edge * edge * edge * 2;  // 12 slots of 16-bit samples
  GpuRenderer renderer(store, config);
  EXPECT_EQ(renderer.poolSlots(), 12);
  RaycastOptions options;
  options.lodPixels = 0;
  const Frame frame = renderer.render(orbit(store, 10, 10, 64), transfer::findPreset("bone"), options);
  EXPECT_LE(frame.stats.workingSetBricks, 12);
  EXPECT_GT(frame.stats.workingSetBricks, 0);
  EXPECT_EQ(nonFinite(frame), 0);
  double coverage = 0;
  for (std::size_t i = 3; i < frame.image.rgba.size(); i += 4) coverage += frame.image.rgba[i];
  EXPECT_GT(coverage, 100.0) << "a coarse picture, not an empty one";
  EXPECT_TRUE(context_->takeErrors().empty());
}

TEST_F(RaycasterTest, BadOptionsAreRejectedWithAMessage) {
  OCTORAY_GL_TEST_PREAMBLE();
  const volume::StoreReader store(phantomStore().string());
  GpuRenderer renderer(store);
  const Camera camera = orbit(store, 0, 0, 16);
  const transfer::TransferFunction tf = transfer::findPreset("bone");
  RaycastOptions options;
  options.earlyTermination = 0;
  EXPECT_THROW(renderer.render(camera, tf, options), Error);
  options = {};
  options.lodPixels = -1;
  EXPECT_THROW(renderer.render(camera, tf, options), Error);
  options = {};
  options.mode = RaycastMode::Iso;
  options.isoValue = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(renderer.render(camera, tf, options), Error);
  RendererConfig config;
  config.gradientPool = true;  // the store has no gradients
  EXPECT_THROW(GpuRenderer(store, config), Error);
  EXPECT_TRUE(context_->takeErrors().empty());
}

// Real CT: the Philips 1 mm head series, CT-Bone from 3D Slicer's presets; DVR, an isosurface at
// 300 HU (depth within half a voxel) and MIP (visible maxima equal at 16 bits).
TEST_F(RaycasterTest, PhilipsHeadDvrIsoAndMipMatchTheReference) {
  OCTORAY_GL_TEST_PREAMBLE();
  const std::filesystem::path series = test::philipsDir() / "S21570" / "S2020";
  OCTORAY_REQUIRE_PATH(series);
  const std::filesystem::path presets = test::sharedDir() / "data/presets/slicer/presets.xml";
  OCTORAY_REQUIRE_PATH(presets);
  const auto source = openVolume(series.string());
  const std::filesystem::path path = raycasterStore(*source, "philips", 32);
  const volume::StoreReader store(path.string());
  const transfer::TransferFunction tf =
      transfer::selectTransferFunction(transfer::loadTransferFunctions(presets.string()), "CT-Bone",
                                       presets.string());
  RaycastOptions options;
  options.lodPixels = 0;
  const Camera camera = orbit(store, 20, 10, 128);
  const Pair p = renderBoth(store, camera, tf, options);
  const ImageMetrics m = compare(p.reference.image, p.gpu.image);
  EXPECT_GE(m.psnrDb, 40.0);
  EXPECT_GE(m.ssim, 0.98);

  options.mode = RaycastMode::Iso;
  options.isoValue = 300;
  const Pair iso = renderBoth(store, camera, tf, options);
  const double halfVoxel = 0.5 * length(store.patientFromIndex().column(0));  // 0.449 mm columns
  const IsoAgreement ia = isoAgreement(iso.gpu.image, iso.reference.image, halfVoxel);
  EXPECT_GT(ia.hitsBoth, 2000);
  EXPECT_EQ(ia.far, 0) << "pixels whose isosurface depth differs by more than half a voxel";
  EXPECT_LE(ia.hitMismatch, ia.hitsBoth / 500) << ia.hitMismatch << " pixels hit in one renderer only";

  options.mode = RaycastMode::Mip;
  const Pair mip = renderBoth(store, camera, tf, options);
  const MipAgreement ma = mipAgreement(mip.gpu.value, mip.reference.value, tf, store.header().valueScale);
  EXPECT_EQ(ma.invisibleShown, 0);
  EXPECT_EQ(ma.missed, 0);
  EXPECT_GT(ma.hits, 1000);
  EXPECT_EQ(ma.differ, 0) << "worst difference " << ma.worst << " HU";
}

// The options both renderers share carry over in each direction, field by field; the GPU's own
// stay at their defaults when they come from the reference's.
TEST(RaycastOptionsConversion, TheSharedOptionsCarryOverInEachDirection) {
  for (const RaycastMode mode : {RaycastMode::Dvr, RaycastMode::Iso, RaycastMode::Mip}) {
    RaycastOptions gpu;
    gpu.mode = mode;
    gpu.stepMm = 0.375;
    gpu.earlyTermination = 0.95;
    gpu.shading = mode == RaycastMode::Iso ? RaycastOptions::Shading::Off : RaycastOptions::Shading::On;
    gpu.gradientOpacity = false;
    gpu.boundary = {true, 0.25, 2.0, 0.5};
    gpu.isoValue = 300;
    gpu.preintegration = mode == RaycastMode::Dvr;
    gpu.jitter = mode == RaycastMode::Mip;
    gpu.silhouette = {true, 0.5, 1.0, 2.0};
    gpu.lodPixels = 4;
    gpu.imageAdaptive = 0.02;
    gpu.clip.enabled = true;
    const reference::RenderOptions cpu = referenceOptions(gpu);
    EXPECT_EQ(cpu.mode, mode == RaycastMode::Dvr   ? RenderMode::Dvr
                        : mode == RaycastMode::Iso ? RenderMode::Iso
                                                   : RenderMode::Mip);
    EXPECT_EQ(cpu.stepMm, 0.375);
    EXPECT_EQ(cpu.earlyTermination, 0.95);
    EXPECT_EQ(cpu.shading, mode == RaycastMode::Iso ? reference::RenderOptions::Shading::Off
                                                    : reference::RenderOptions::Shading::On);
    EXPECT_FALSE(cpu.gradientOpacity);
    EXPECT_TRUE(cpu.boundary.enabled);
    EXPECT_EQ(cpu.boundary.kC, 0.25);
    EXPECT_EQ(cpu.boundary.kS, 2.0);
    EXPECT_EQ(cpu.boundary.kE, 0.5);
    EXPECT_EQ(cpu.isoValue, 300);
    EXPECT_EQ(cpu.preintegration, mode == RaycastMode::Dvr);
    EXPECT_EQ(cpu.jitter, mode == RaycastMode::Mip);

    const RaycastOptions back = raycastOptions(cpu);
    EXPECT_EQ(back.mode, mode);
    EXPECT_EQ(back.stepMm, gpu.stepMm);
    EXPECT_EQ(back.earlyTermination, gpu.earlyTermination);
    EXPECT_EQ(back.shading, gpu.shading);
    EXPECT_EQ(back.gradientOpacity, gpu.gradientOpacity);
    EXPECT_EQ(back.boundary.enabled, gpu.boundary.enabled);
    EXPECT_EQ(back.boundary.kC, gpu.boundary.kC);
    EXPECT_EQ(back.boundary.kS, gpu.boundary.kS);
    EXPECT_EQ(back.boundary.kE, gpu.boundary.kE);
    EXPECT_EQ(back.isoValue, gpu.isoValue);
    EXPECT_EQ(back.preintegration, gpu.preintegration);
    EXPECT_EQ(back.jitter, gpu.jitter);
    // What the reference does not have comes back at the GPU's defaults.
    const RaycastOptions defaults;
    EXPECT_FALSE(back.silhouette.enabled);
    EXPECT_EQ(back.lodPixels, defaults.lodPixels);
    EXPECT_EQ(back.imageAdaptive, defaults.imageAdaptive);
    EXPECT_FALSE(back.clip.enabled);
  }
  // The shading that follows the transfer function's material, in each direction.
  EXPECT_EQ(referenceOptions(RaycastOptions{}).shading, reference::RenderOptions::Shading::FromTransferFunction);
  EXPECT_EQ(raycastOptions(reference::RenderOptions{}).shading, RaycastOptions::Shading::FromTransferFunction);
}

}  // namespace
}  // namespace octoray::gpu
