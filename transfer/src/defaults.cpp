#include "octoray/transfer/defaults.h"

#include <cmath>
#include <cstddef>
#include <optional>

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

double automaticIsoValue(const std::vector<int>& histogram, double lo, double hi) {
  const std::size_t bins = histogram.size();
  double total = 0, weighted = 0;
  for (std::size_t b = 0; b < bins; ++b) {
    total += histogram[b];
    weighted += static_cast<double>(b) * histogram[b];
  }
  // Maximise the between-class variance w0 w1 (m0 - m1)^2 over the split after bin t, in bin
  // units. Empty bins after the best split give the same classes, so the same variance: the
  // threshold is the middle of that run of equal maxima (a 0/1 mask's is 0.5, not just above 0;
  // OpenCV's THRESH_OTSU takes the first).
  double below = 0, belowWeighted = 0, best = 0;
  std::optional<std::size_t> first, last;
  for (std::size_t t = 0; t + 1 < bins; ++t) {
    below += histogram[t];
    belowWeighted += static_cast<double>(t) * histogram[t];
    const double above = total - below;
    if (below == 0 || above == 0) continue;
    const double difference = belowWeighted / below - (weighted - belowWeighted) / above;
    const double between = below * above * difference * difference;
    if (between > best) {
      best = between;
      first = last = t;
    } else if (between == best && last && t == *last + 1 && histogram[t] == 0) {
      last = t;
    }
  }
  if (!first) return 0.5 * (lo + hi);
  const double edge = 0.5 * static_cast<double>(*first + *last) + 1;  // in bins
  return lo + edge * (hi - lo) / static_cast<double>(bins);
}

}  // namespace octoray::transfer
