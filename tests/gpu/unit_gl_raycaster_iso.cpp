// The GPU raycaster's isosurfaces against the CPU reference: depths within half a voxel, and
// surfaces thinner than the step found (isoDip).

#include <gtest/gtest.h>

#include "raycaster_test_support.h"

namespace octoray::gpu {
namespace {

using namespace raycaster_test;

TEST_F(RaycasterTest, IsosurfaceDepthIsWithinHalfAVoxelOfTheReference) {
  OCTORAY_GL_TEST_PREAMBLE();
  const volume::StoreReader store(phantomStore().string());
  RaycastOptions options;
  options.mode = RaycastMode::Iso;
  options.isoValue = 300;
  options.lodPixels = 0;
  const transfer::TransferFunction tf = transfer::findPreset("bone");
  const Camera camera = orbit(store, 75, 25, 128);
  const Pair p = renderBoth(store, camera, tf, options);
  const IsoAgreement a = isoAgreement(p.gpu.image, p.reference.image, 0.5 * 0.55);  // half a voxel
  EXPECT_GT(a.hitsBoth, 2000);
  EXPECT_EQ(a.far, 0) << "pixels whose isosurface depth differs by more than half a voxel";
  // A pixel may change between hit and miss only where the surface grazes the ray.
  EXPECT_LE(a.hitMismatch, a.hitsBoth / 500) << a.hitMismatch << " pixels hit in one renderer only";
  const ImageMetrics m = compare(p.reference.image, p.gpu.image);
  EXPECT_GE(m.psnrDb, 35.0);
}

// One plane of 1000 (k = 8) in zeros, isovalue 990: the surface is a sliver 0.02 voxel thick
// that steps of 0.2-0.3 voxel mostly straddle (ReferenceIso.FindsASurfaceThinnerThanTheStep
// shows it on the sample grid). Both renderers must find it at every pixel, at the same depth.
TEST_F(RaycasterTest, IsosurfaceThinnerThanTheStepIsFound) {
  OCTORAY_GL_TEST_PREAMBLE();
  static const std::filesystem::path path = [] {
    test::MemoryVolume source({40, 36, 18}, [](int64_t, int64_t, int64_t k) {
      return k == 8 ? 1000.0f : 0.0f;
    });
    return raycasterStore(source, "plate", 16);
  }();
  const volume::StoreReader store(path.string());
  RaycastOptions options;
  options.mode = RaycastMode::Iso;
  options.isoValue = 990;
  options.lodPixels = 0;
  const transfer::TransferFunction tf = transfer::findPreset("bone");
  const Camera camera = orbit(store, 30, 75, 24, Projection::Orthographic, 5.0);
  for (double stepMm : {0.41, 0.45, 0.49, 0.53, 0.57}) {  // 0.2-0.3 of the 2 mm z spacing
    options.stepMm = stepMm;
    const Pair p = renderBoth(store, camera, tf, options);
    const IsoAgreement a = isoAgreement(p.gpu.image, p.reference.image, 0.01);
    EXPECT_EQ(a.hitsBoth, 24 * 24) << "step " << stepMm << " mm: " << a.hitMismatch
                                   << " pixels hit in one renderer only";
    EXPECT_EQ(a.far, 0) << "step " << stepMm << " mm: depths differ by more than 0.01 mm";
  }
}


}  // namespace
}  // namespace octoray::gpu
