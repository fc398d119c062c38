#pragma once
// A 1D transfer function over physical values (Hounsfield units for CT): piecewise-linear
// colour and opacity control points, optional gradient-magnitude opacity, and the shading
// material the preset asks for. Values outside the control points take the nearest end
// point's colour and opacity (clamped), as VTK and 3D Slicer do. Control points are sorted
// by value; two points may share a value (a step, as in Slicer's uCT presets): at the step
// the later point applies. A NaN value evaluates to transparent black.

#include <array>
#include <cstddef>
#include <string>
#include <vector>

namespace octoray::transfer {

struct ColorPoint {
  double value = 0;  // physical units (HU)
  float r = 0, g = 0, b = 0;  // linear, [0, 1]
};

struct OpacityPoint {
  double value = 0;  // physical units (HU)
  float alpha = 0;   // [0, 1], opacity over unitDistanceMm of material
};

struct GradientOpacityPoint {
  double magnitude = 0;  // |gradient| in physical units per mm
  float alpha = 1;       // multiplier in [0, 1]
};

struct Material {
  bool shade = true;
  float ambient = 0.1f, diffuse = 0.9f, specular = 0.2f, specularPower = 10.0f;
};

// How the renderer samples the volume between voxels (Slicer's "interpolation").
enum class Interpolation { Nearest, Linear };

struct TransferFunction {
  std::string name;
  std::vector<ColorPoint> color;                       // sorted by value
  std::vector<OpacityPoint> opacity;                   // sorted by value
  std::vector<GradientOpacityPoint> gradientOpacity;   // sorted; empty = 1 everywhere
  Material material;
  double unitDistanceMm = 1.0;  // the path length over which `alpha` applies (Slicer/VTK)

  // Colour and opacity at a value (linear interpolation between control points).
  std::array<float, 4> evaluate(double value) const;
  float opacityAt(double value) const;
  float gradientOpacityAt(double magnitude) const;
  // True when opacity is exactly zero everywhere in [lo, hi] (exact, from the control points).
  bool transparentOver(double lo, double hi) const;

  std::string description;                          // what the preset is for (free text)
  Interpolation interpolation = Interpolation::Linear;
};

// The most control points one list (colour, opacity, gradient opacity) may hold: far above any
// real preset (Slicer's have under 20), and what every consumer handles in well under a second.
inline constexpr std::size_t kMaxControlPoints = 1'000'000;

// Checks every rule of docs/transfer-function-json.md: finite sorted values, alpha and colour
// in [0, 1], at least one colour and one opacity point, a sane material and a positive unit
// distance. Throws octoray::Error(path, "<field>: <what is wrong>") on the first violation.
void validate(const TransferFunction& tf, const std::string& path = {});

// The span of values over which the opacity ramp varies: from the last point of the leading
// constant run of opacity points to the first point of the trailing constant run. A constant
// opacity gives the span of all opacity points.
struct ValueRange {
  double lo = 0, hi = 0;
};
ValueRange opacityRampRange(const TransferFunction& tf);

// Window/level applied to a preset: the affine map of values that sends the centre of
// opacityRampRange(tf) to `level` and its width to `window` (both in the TF's physical units,
// e.g. HU). Every colour and opacity point moves with it, so the colours stay attached to
// the ramp; the clamped ends stay clamped. A ramp of zero width is only moved to `level`.
// Throws octoray::Error when window is not positive and finite or level is not finite.
TransferFunction withWindowLevel(const TransferFunction& tf, double window, double level);

}  // namespace octoray::transfer
