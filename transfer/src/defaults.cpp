#include "octoray/transfer/defaults.h"

#include <cmath>

#include <fmt/format.h>

#include "octoray/core/error.h"
#include "octoray/transfer/transfer_function_io.h"

namespace octoray::transfer {

namespace {

// Slicer's "bone" colour (GenericAnatomyColors: 241, 214, 145), the colour clinicians know
// for a bone surface model.
constexpr float kBoneR = 241.0f / 255.0f, kBoneG = 214.0f / 255.0f, kBoneB = 145.0f / 255.0f;

TransferFunction boneSurface() {
  TransferFunction tf;
  tf.name = "default-bone-surface";
  tf.description = "Opaque bone-coloured surface (Slicer's bone colour), shaded.";
  tf.color = {{0.0, kBoneR, kBoneG, kBoneB}};
  tf.opacity = {{0.0, 1.0f}};
  tf.material = Material{true, 0.15f, 0.85f, 0.3f, 20.0f};
  return tf;
}

TransferFunction greyRamp(const std::string& name, double lo, double hi, double opaqueFrom) {
  TransferFunction tf;
  tf.name = name;
  tf.color = {{lo, 0, 0, 0}, {hi, 1, 1, 1}};
  if (opaqueFrom <= lo) {
    tf.opacity = {{lo, 1.0f}};
    tf.material.shade = false;
  } else {
    tf.opacity = {{opaqueFrom, 0.0f}, {hi, 0.8f}};
  }
  return tf;
}

}  // namespace

DefaultTransferFunction defaultTransferFunction(DefaultMode mode, bool hounsfield, double lo,
                                                double hi) {
  if (mode == DefaultMode::Iso) {
    return {boneSurface(), "a bone-coloured surface material"};
  }
  if (hounsfield) {
    if (mode == DefaultMode::Dvr) return {findPreset("bone"), "the bone preset"};
    TransferFunction tf = greyRamp("default-mip-ct", -200.0, 1000.0, -200.0);
    tf.description = "Grey ramp for MIP: -200 HU black to 1000 HU white.";
    return {tf, "a grey ramp from -200 HU (black) to 1000 HU (white)"};
  }
  if (!(std::isfinite(lo) && std::isfinite(hi) && lo < hi)) {
    throw Error("", fmt::format("no default transfer function for values in [{}, {}]: give "
                                "--preset or --tf",
                                lo, hi));
  }
  if (mode == DefaultMode::Mip) {
    TransferFunction tf = greyRamp("default-mip", lo, hi, lo);
    return {tf, fmt::format("a grey ramp over the values {:g}..{:g}", lo, hi)};
  }
  TransferFunction tf = greyRamp("default-dvr", lo, hi, lo + 0.25 * (hi - lo));
  return {tf, fmt::format("a grey ramp over the values {:g}..{:g}, transparent below {:g}", lo,
                          hi, lo + 0.25 * (hi - lo))};
}

}  // namespace octoray::transfer
