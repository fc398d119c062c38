#pragma once
// The CPU reference renderer: the slow but right oracle for the GPU raycaster. It implements
// DESIGN.md's optical model in double precision on the full-resolution volume with a fine
// fixed step, and shares camera, transfer-function and shading code with nothing it checks:
// it evaluates the transfer function's control points itself, in double precision.
//
// Rays: the camera's ray (patient space, mm) is mapped into index space through the inverse of
// the full patientFromIndex affine (shear included) and clipped against the closed domain box
// [-0.5, dim - 0.5]^3; the ray parameter stays the distance in patient mm. Grazing rays (along a
// face, an edge, through a corner) count as inside.
//
// Direct volume rendering (RenderMode::Dvr): the clipped chord [tNear, tFar] is cut into
// n = ceil(length / step) equal steps of Δ = length / n <= step (so the steps sum to the chord
// exactly) and sampled at their midpoints. Per sample: classify (colour c, opacity α per the
// TF's unitDistanceMm), optionally scale α by the TF's gradient opacity and by boundary
// enhancement kC + kS·|∇f|^kE (|∇f| in value units per mm; the product clamped to [0, 1]),
// correct the opacity to the step, α' = 1 - (1 - α)^(Δ / unitDistanceMm) (through log1p /
// expm1, exact 0 for α = 0 and 1 for α = 1), shade c, and composite front to back with
// premultiplied colour: C += T α' c, T *= 1 - α'. The ray stops when 1 - T reaches
// `earlyTermination` (1.0: only when T is exactly 0, i.e. never approximated). Depth: the
// distance to the first sample with α' > 0.
//
// Pre-integrated DVR (RenderOptions::preintegration, paper 003 §5.3): the chord is cut into
// the same n steps, but the interpolant is sampled at the n + 1 step boundaries and each step
// is a segment along which the value runs linearly from its front to its back sample. The
// part of the segment whose values lie inside the TF's opacity support is integrated through
// the piecewise-linear TF (sub-steps in double precision, more where the segment spans TF
// points; transfer::integrateSegment's rule), giving its premultiplied colour and opacity;
// gradient opacity and boundary enhancement scale the segment's opacity per unit distance;
// shading (gradient at the segment's midpoint) multiplies the colour by ka + kd|n·l| and adds
// ks·spec·α. Sharp TFs no longer need a step finer than their features; only the interpolant
// is approximated (linear along each step).
//
// Ray-start jitter (RenderOptions::jitter): each step's sample sits at a fraction j of the
// step instead of its midpoint, j = rayJitter(x, y) per pixel, the same hash the GPU shader
// computes: coarse-step wood grain becomes noise.
//
// Shading (Material.shade): Phong with a headlight (light and eye along -ray direction, white
// light of intensity 1): c·(ka + kd·|n·l|) + ks·max(0, r·v)^p, two-sided. The normal is the
// normalised gradient of the trilinear interpolant, taken by central differences of ±1 voxel
// in index space (over an LOD cut: of +-h voxels of the leaf's level, reference_volume.h)
// and carried to patient space by the inverse transpose of patientFromIndex's
// linear part (anisotropic spacing and shear respected). Where the gradient is exactly zero
// (constant regions) the normal is undefined: diffuse and specular terms are 0, ambient stays;
// never a NaN.
//
// The converged truth (ReferenceRenderer::renderConverged): the picture at a step h, then
// h/2, h/4, ... until two consecutive pictures differ by at most ConvergenceRule::maxChange
// in every channel of every pixel and by a change whose PSNR (peak 1) reaches minPsnrDb; the
// finer one is the truth. Both the midpoint rule and pre-integration converge as O(step^2)
// on smooth data (tests/gpu/unit_reference_truth.cpp measures the rate against closed-form
// integrals), so the remaining error is about a third of the last change. Every accuracy
// number in docs/accuracy.md is against such a picture, never a same-step one.
//
// Isosurface (RenderMode::Iso): f(t) - iso is evaluated at the chord's ends and every fine
// step between; the first bracket with a sign change (either direction: the camera may sit
// inside the surface) is refined by bisection until it is shorter than 1e-6 voxel, the hit is
// the linear root in that final bracket. The colour is the TF colour at the isovalue, shaded
// as above with the gradient at the hit, opacity 1. Depth: distance to the hit. A chord that
// starts exactly on the isovalue hits at tNear.
//
// Maximum intensity projection (RenderMode::Mip): the exact maximum of the trilinear
// interpolant along the chord: the chord is split where it crosses any voxel-centre plane or a
// clamp plane; on each piece the interpolant is a cubic in t, maximised at the ends and at
// its critical points. The pixel is the TF's colour and opacity at the maximum (VTK's MIP),
// premultiplied; depth is the distance to the (first) maximum; `value` holds the maximum.
// Full-resolution samples only: render() refuses MIP over an LOD cut with coarse leaves (a
// leaf-level cut, as --frustum-cut reads, is the full volume where it has leaves).
//
// Rows run in parallel (TBB); each pixel depends only on its ray, so output is deterministic.

#include <cstdint>
#include <limits>
#include <vector>

#include "octoray/gpu/camera.h"
#include "octoray/gpu/image.h"
#include "octoray/gpu/reference/reference_volume.h"
#include "octoray/transfer/transfer_function.h"

namespace octoray::gpu::reference {

enum class RenderMode { Dvr, Iso, Mip };

struct BoundaryEnhancement {
  bool enabled = false;
  double kC = 0.0, kS = 1.0, kE = 1.0;  // alpha *= kC + kS * |grad|^kE  (|grad| per mm)
};

struct RenderOptions {
  RenderMode mode = RenderMode::Dvr;
  // Step along the ray in mm; 0 = 0.25 x the smallest spacing of the volume.
  double stepMm = 0;
  // Stop a ray when its accumulated opacity reaches this; 1.0 = never approximate.
  double earlyTermination = 0.99;
  // Shading follows the TF's Material.shade unless overridden here.
  enum class Shading { FromTransferFunction, On, Off } shading = Shading::FromTransferFunction;
  bool gradientOpacity = true;  // apply the TF's gradient-opacity points (if it has any)
  BoundaryEnhancement boundary;
  double isoValue = 0;  // RenderMode::Iso, physical units
  bool preintegration = false;  // DVR: integrate each step through the TF (see above)
  bool jitter = false;          // DVR: per-pixel sample offset rayJitter(x, y) (not with the above)
};

// The per-pixel offset of ray-start jitter in [0, 1): a 32-bit integer hash of the pixel
// (column x, row y from the top), the top 24 bits as a fraction (exact in float).
// raycast_classify.glsl computes the same function.
float rayJitter(uint32_t x, uint32_t y);

struct RenderStats {
  int64_t samples = 0;  // interpolant evaluations for classification / search
  int64_t raysHit = 0;  // rays whose chord through the domain is non-empty
  double stepMm = 0;    // the step actually used
};

struct RenderResult {
  Image image;
  std::vector<double> value;  // MIP: the maximum per pixel (NaN: missed); empty otherwise
  RenderStats stats;
};

// One ray against the closed domain box in index space; t in the ray's own units (patient mm
// for renderer rays). Empty when the ray misses or the chord lies behind tMin.
struct Chord {
  double tNear = 0, tFar = -1;
  bool empty() const { return !(tFar >= tNear); }
};
Chord clipToDomain(const Vec3& originIndex, const Vec3& directionIndex,
                   const std::array<int64_t, 3>& dims, double tMin = 0.0);

// Renders one ReferenceVolume; the volume must outlive the renderer. const and thread-safe:
// several frames may render from one renderer at once.
class ReferenceRenderer {
 public:
  explicit ReferenceRenderer(const ReferenceVolume& volume) : volume_(volume) {}

  // Throws octoray::Error for a camera that cannot form rays or bad options.
  RenderResult render(const Camera& camera, const transfer::TransferFunction& tf,
                      const RenderOptions& options) const;

  // The converged truth: render() driven to convergence by step halving (see
  // ConvergenceRule). options.stepMm is the first step (0: the default).
  struct ConvergedResult {
    RenderResult result;                // the last (finest) picture
    std::vector<double> stepsMm;        // every step rendered, coarsest first
    std::vector<double> changePsnrDb;   // between consecutive pictures (stepsMm.size() - 1)
    std::vector<double> changeMax;      // max |difference| of any RGBA channel, likewise
    bool converged = false;
    double estimatedMaxError = 0;       // changeMax.back() / 3: the O(step^2) rule's remainder
  };
  struct ConvergenceRule {
    double maxChange = 1.0 / 1024;      // stop when no channel of any pixel moves more than this
    double minPsnrDb = 70.0;            // and the change's PSNR (peak 1) reaches this
    int maxHalvings = 6;
  };
  ConvergedResult renderConverged(const Camera& camera, const transfer::TransferFunction& tf,
                                  const RenderOptions& options, const ConvergenceRule& rule) const;

 private:
  const ReferenceVolume& volume_;
};

// The TF evaluated in double precision from its control points (the rules of
// transfer_function.h: clamped ends, later point wins at a step, NaN -> transparent black).
struct Classification {
  double r = 0, g = 0, b = 0, alpha = 0;
};
Classification classify(const transfer::TransferFunction& tf, double value);
double gradientOpacity(const transfer::TransferFunction& tf, double magnitudePerMm);
// 1 - (1 - alpha)^ratio, exact at 0 and 1, accurate for alpha -> 0; 0 for ratio <= 0 (a
// path of zero length, e.g. a ray touching only a corner, absorbs nothing even at alpha 1).
double correctOpacity(double alpha, double ratio);

}  // namespace octoray::gpu::reference
