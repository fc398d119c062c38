// What a raycast's options may hold (validateRaycast), and the conversions between them and the
// CPU reference's: the options themselves, apart from the GL raycaster that draws with them.
#include "octoray/gpu/raycaster.h"

#include <fmt/format.h>

#include <cmath>

#include "octoray/core/error.h"

namespace octoray::gpu {

namespace {

// The two renderers name their modes and shading overrides alike, in the same order.
static_assert(static_cast<int>(RaycastMode::Dvr) == static_cast<int>(reference::RenderMode::Dvr) &&
              static_cast<int>(RaycastMode::Iso) == static_cast<int>(reference::RenderMode::Iso) &&
              static_cast<int>(RaycastMode::Mip) == static_cast<int>(reference::RenderMode::Mip));
static_assert(static_cast<int>(RaycastOptions::Shading::FromTransferFunction) ==
                  static_cast<int>(reference::RenderOptions::Shading::FromTransferFunction) &&
              static_cast<int>(RaycastOptions::Shading::On) == static_cast<int>(reference::RenderOptions::Shading::On) &&
              static_cast<int>(RaycastOptions::Shading::Off) == static_cast<int>(reference::RenderOptions::Shading::Off));

// The fields both option types have, from one to the other (either direction).
template <class To, class From>
To sharedOptions(const From& from) {
  To to;
  to.mode = static_cast<decltype(to.mode)>(from.mode);
  to.stepMm = from.stepMm;
  to.earlyTermination = from.earlyTermination;
  to.shading = static_cast<decltype(to.shading)>(from.shading);
  to.gradientOpacity = from.gradientOpacity;
  to.boundary.enabled = from.boundary.enabled;
  to.boundary.kC = from.boundary.kC;
  to.boundary.kS = from.boundary.kS;
  to.boundary.kE = from.boundary.kE;
  to.isoValue = from.isoValue;
  to.preintegration = from.preintegration;
  to.jitter = from.jitter;
  return to;
}

}  // namespace

reference::RenderOptions referenceOptions(const RaycastOptions& options) {
  return sharedOptions<reference::RenderOptions>(options);
}

RaycastOptions raycastOptions(const reference::RenderOptions& options) {
  return sharedOptions<RaycastOptions>(options);
}

void validateRaycast(const Camera& camera, const transfer::TransferFunction& tf,
                     const RaycastOptions& options) {
  camera.validate();
  if (!(options.earlyTermination > 0 && options.earlyTermination <= 1)) {
    throw Error("", fmt::format("early termination {} must be in (0, 1]", options.earlyTermination));
  }
  if (!(options.stepMm >= 0 && std::isfinite(options.stepMm))) {
    throw Error("", fmt::format("step {} mm must be positive (or 0 for the default)", options.stepMm));
  }
  if (options.mode == RaycastMode::Iso && !std::isfinite(options.isoValue)) {
    throw Error("", "the isovalue must be finite");
  }
  if (!(tf.unitDistanceMm > 0 && std::isfinite(tf.unitDistanceMm))) {
    throw Error("", fmt::format("transfer function \"{}\": unit distance must be positive", tf.name));
  }
  if (options.preintegration && options.jitter) {
    throw Error("", "pre-integration and jitter are alternatives: choose one");
  }
  if (tf.color.empty() || tf.opacity.empty()) {
    throw Error("", fmt::format("transfer function \"{}\" has no colour or no opacity points", tf.name));
  }
  for (const Enhancement* e : {&options.boundary, &options.silhouette}) {
    if (e->enabled && !(std::isfinite(e->kC) && std::isfinite(e->kS) && std::isfinite(e->kE) && e->kE >= 0)) {
      throw Error("", "enhancement: kC, kS must be finite and kE finite and >= 0");
    }
  }

  if (!(options.lodPixels >= 0 && std::isfinite(options.lodPixels))) {
    throw Error("", fmt::format("--lod-pixels {} must be 0 or positive", options.lodPixels));
  }
  if (!(options.imageAdaptive >= 0 && std::isfinite(options.imageAdaptive))) {
    throw Error("", fmt::format("image-adaptive threshold {} must be 0 (off) or positive", options.imageAdaptive));
  }
  if (options.imageAdaptive > 0 && !(options.imageAdaptiveLevels >= 1 && options.imageAdaptiveLevels <= 4)) {
    throw Error("", fmt::format("image-adaptive levels {} must be in [1, 4]", options.imageAdaptiveLevels));
  }
  if (options.clip.enabled) {
    for (int a = 0; a < 3; ++a) {
      const double lo = options.clip.lo[static_cast<std::size_t>(a)], hi = options.clip.hi[static_cast<std::size_t>(a)];
      if (!(std::isfinite(lo) && std::isfinite(hi) && lo < hi)) {
        throw Error("", fmt::format("clip box axis {}: [{}, {}] must be finite with lo < hi", a, lo, hi));
      }
    }
  }
}

}  // namespace octoray::gpu
