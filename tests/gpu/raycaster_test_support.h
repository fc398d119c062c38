#pragma once
// What the GPU raycaster tests (unit_gl_raycaster*.cpp) share: the test stores (built once per
// test binary run), orbit cameras, the isosurface-depth and MIP-maximum comparisons, and the
// fixture that renders a picture with both renderers (the reference's options from
// referenceOptions, raycaster.h).

#include <epoxy/gl.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <limits>
#include <memory>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "gl_test_support.h"
#include "memory_volume.h"
#include "octoray/core/error.h"
#include "octoray/dicom/formats.h"
#include "octoray/gpu/camera.h"
#include "octoray/gpu/gpu_renderer.h"
#include "octoray/gpu/image_metrics.h"
#include "octoray/gpu/reference/reference_renderer.h"
#include "octoray/gpu/spatial_index.h"
#include "octoray/transfer/transfer_function_io.h"
#include "octoray/volume/phantom.h"
#include "octoray/volume/store_builder.h"
#include "octoray/volume/store_reader.h"
#include "test_paths.h"
#include "test_stores.h"

namespace octoray::gpu::raycaster_test {

using reference::ReferenceRenderer;
using reference::ReferenceVolume;
using reference::RenderMode;

// The test stores, each built once per test binary run (border 2: central differences).
inline std::filesystem::path raycasterStore(VolumeSource& source, const std::string& name, int brickSize) {
  return test::buildTestStore(source, "gl_raycaster_" + name, brickSize);
}

inline const std::filesystem::path& phantomStore() {
  static const std::filesystem::path path = [] {
    volume::PhantomOptions options;
    options.dims = {96, 88, 72};
    options.spacingMm = {0.6, 0.55, 0.8};
    options.seed = 7;
    return test::buildPhantomTestStore(options, "gl_raycaster_phantom", 16);
  }();
  return path;
}

// A linear ramp in index space on a sheared grid (MemoryVolume's patientFromIndex has a
// shear): trilinear interpolation reproduces it exactly, so any seam between bricks, a wrong
// border or a half-texel shift shows against the reference.
inline const std::filesystem::path& rampStore() {
  static const std::filesystem::path path = [] {
    test::MemoryVolume source({70, 50, 40}, [](int64_t i, int64_t j, int64_t k) {
      return static_cast<float>(-900 + 10 * i + 14 * j + 17 * k);
    });
    return raycasterStore(source, "ramp", 16);
  }();
  return path;
}

inline Camera orbit(const volume::StoreReader& store, double azimuth, double elevation, int size,
                    Projection projection = Projection::Perspective, double zoom = 1.0) {
  OrbitParameters o;
  o.azimuthDegrees = azimuth;
  o.elevationDegrees = elevation;
  o.width = o.height = size;
  o.projection = projection;
  o.zoom = zoom;
  return orbitCamera({store.layout().levelDims(store.layout().leafLevel()), store.patientFromIndex()}, o);
}

inline int64_t nonFinite(const Frame& frame) {
  int64_t n = 0;
  for (float v : frame.image.rgba) n += std::isfinite(v) ? 0 : 1;
  return n;
}

inline transfer::TransferFunction rampTf(bool shade) {
  transfer::TransferFunction tf;
  tf.name = "ramp";
  tf.color = {{-900, 0.1f, 0.2f, 0.9f}, {0, 0.9f, 0.8f, 0.2f}, {1200, 1.0f, 0.3f, 0.1f}};
  tf.opacity = {{-900, 0.0f}, {-600, 0.02f}, {1200, 0.15f}};
  tf.material.shade = shade;
  tf.unitDistanceMm = 1.0;
  return tf;
}

// Isosurface depths of a GPU frame against the reference's: pixels hit by both, pixels hit by
// one only, and pixels whose depths differ by more than `tolerance` mm.
struct IsoAgreement {
  int64_t hitsBoth = 0, hitMismatch = 0, far = 0;
};
inline IsoAgreement isoAgreement(const Image& gpu, const Image& reference, double tolerance) {
  IsoAgreement a;
  for (std::size_t i = 0; i < gpu.depth.size(); ++i) {
    const bool g = std::isfinite(gpu.depth[i]), r = std::isfinite(reference.depth[i]);
    if (g != r) {
      ++a.hitMismatch;
      continue;
    }
    if (!g) continue;
    ++a.hitsBoth;
    if (std::abs(gpu.depth[i] - reference.depth[i]) > tolerance) ++a.far;
  }
  return a;
}

// MIP maxima of a GPU frame against the reference's. Where the reference's maximum is
// invisible (zero opacity), the working set may lack the bricks that hold it (they cannot
// show): the GPU may then miss or find a lower, equally invisible maximum (`invisibleShown`
// counts those that became visible). Visible maxima must be equal to `oneStep`.
struct MipAgreement {
  int64_t hits = 0, differ = 0, missed = 0, invisibleShown = 0;
  double worst = 0;
};
inline MipAgreement mipAgreement(const std::vector<float>& gpu, const std::vector<double>& reference,
                                 const transfer::TransferFunction& tf, double oneStep) {
  const auto visible = [&](double v) { return !std::isnan(v) && tf.evaluate(v)[3] > 0; };
  MipAgreement a;
  for (std::size_t i = 0; i < gpu.size(); ++i) {
    const double r = reference[i], g = gpu[i];
    if (!visible(r)) {
      a.invisibleShown += visible(g) ? 1 : 0;
      continue;
    }
    if (std::isnan(g)) {
      ++a.missed;
      continue;
    }
    ++a.hits;
    a.worst = std::max(a.worst, std::abs(r - g));
    if (std::abs(r - g) > oneStep) ++a.differ;
  }
  return a;
}

class RaycasterTest : public GlTest {
 protected:
  // Renders with both renderers; checks finiteness and the GL error log.
  struct Pair {
    Frame gpu;
    reference::RenderResult reference;
  };
  Pair renderBoth(const volume::StoreReader& store, const Camera& camera,
                  const transfer::TransferFunction& tf, const RaycastOptions& options) {
    GpuRenderer renderer(store);
    Pair p{renderer.render(camera, tf, options), {}};
    const ReferenceVolume volume = ReferenceVolume::fromStore(store);
    p.reference = ReferenceRenderer(volume).render(camera, tf, referenceOptions(options));
    EXPECT_EQ(nonFinite(p.gpu), 0) << "NaN or infinite colour";
    EXPECT_TRUE(context_->takeErrors().empty());
    return p;
  }
};

#define OCTORAY_GL_TEST_PREAMBLE() OCTORAY_REQUIRE_CONTEXT(context_)

}  // namespace octoray::gpu::raycaster_test
