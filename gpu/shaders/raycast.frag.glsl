#version 450 core
// The single-pass raycaster (paper 003 §5, DESIGN.md "Rendering"). One invocation per pixel
// walks the spatial index (gpu/include/octoray/gpu/spatial_index.h documents the encoding and
// the traversal; traverseRay there mirrors the loop below operation for operation) front to
// back and samples each data leaf's brick in the pool.
//
// Variants (the #define prelude, see gpu_renderer.cpp): exactly one of MODE_DVR, MODE_ISO,
// MODE_MIP; SHADING (Phong; gradients exist only then), GRADIENT_OPACITY, BOUNDARY_ENHANCEMENT,
// SILHOUETTE_ENHANCEMENT (view-dependent transparency), GRADIENT_POOL (gradients read from the
// RGBA8 pool instead of 6 value fetches), PREINTEGRATION (DVR classifies each segment between
// consecutive samples through the pre-integration table; no CELL_SKIPPING with it), JITTER
// (DVR samples at a per-pixel fraction of their step), IMAGE_ADAPTIVE (the pass is one level of
// the image pyramid: see "Adaptive sampling in the image plane" below), STATS (per-pixel counters), FEEDBACK (per-leaf ray counts), PERSPECTIVE;
// BRICK_SIZE, BORDER and GRADIENT_DELTA are numbers.
//
// The per-mode and per-feature functions live in the raycast_*.glsl parts, pasted in where
// this file #includes them (GlProgram::build resolves the lines; compile errors name the part):
// classify (the transfer function), pool (bricks, values, gradients), shading, iso and mip (one
// leaf's maximum). The leaf walk and the DVR and isosurface marches stay here: they share the
// walk's local state. The image pyramid's interpolated pixels are another program's
// (image_adaptive.frag.glsl), so that the pixels not cast never run this one.
//
// Units: t is the distance along the ray in patient mm; octree space q is the unit cube of
// the index; texel space is the pool texture's (texel centres at i + 0.5).

layout(std430, binding = 0) readonly buffer IndexNodes { uint nodes[]; };
layout(std430, binding = 1) readonly buffer IndexLeaves { uint leaves[]; };
// Transfer-function control points in physical units, for evaluations made once per pixel
// (MIP, isosurface) or on the rare shading path (gradient opacity): colour points
// (value, r, g, b), then opacity points (value, alpha, 0, 0), then gradient-opacity points
// (magnitude, alpha, 0, 0).
layout(std430, binding = 2) readonly buffer TfPoints { vec4 tfPoints[]; };
#ifdef FEEDBACK
// Ray-guided feedback (GigaVoxels): per leaf record, [0] rays that sampled the leaf before
// terminating, [1] rays that wanted finer data there (voxels projecting above uLodPixels).
layout(std430, binding = 4) buffer Feedback { uint feedback[]; };
uniform float uLodPixels;
#endif
#if defined(FEEDBACK) || defined(IMAGE_ADAPTIVE)
uniform float uLeafVoxelMm;  // the leaf level's largest voxel edge (mm)
uniform float uPixelScale;   // perspective: pixel size per mm of depth; orthographic: mm per pixel
#endif
#ifdef IMAGE_ADAPTIVE
// Adaptive sampling in the image plane (Kraus et al. 2007, paper 002), coarse to fine: pixel
// (x, y) of pyramid level l is the ray through image pixel (2^l x, 2^l y). The coarsest level
// casts every ray; on each finer one image_adaptive.frag.glsl first copies or interpolates
// from the level above what the error bound allows and leaves the stencil at 0 where it does
// not, and this pass casts only those rays: the early stencil test skips the others before
// any of this shader runs. With early tests gl_FragDepth has no effect, so the depth-buffer
// value goes to outAux.w, and depth_from_aux.frag.glsl fills the depth buffer from it.
layout(early_fragment_tests) in;
uniform float uLevelScale;    // 2^l
// [0] rays cast, [1] samples taken (with STATS)
layout(std430, binding = 5) buffer AdaptiveCounters { uint adaptiveCounters[]; };
float rayDepth;               // this pixel's depth-buffer value
#define FRAG_DEPTH rayDepth
#else
#define FRAG_DEPTH gl_FragDepth
#endif
#ifdef STATS
layout(std430, binding = 3) buffer Touched { uint touched[]; };
#endif

uniform vec3 uEye;            // patient mm
uniform vec3 uForward, uRight, uUp;
uniform vec2 uHalfExtent;     // perspective: tan(fov/2) * (aspect, 1); orthographic: mm
uniform vec2 uViewport;       // width, height in pixels
uniform mat3 uQFromPatient;   // linear part, patient mm -> octree space
uniform vec3 uQOffset;        // octree-space position of the patient origin
uniform vec3 uDomainMax;      // the volume's domain in octree space: [0, uDomainMax]
uniform vec3 uClipMin;        // the clip box in octree space (the domain when not clipping)
uniform vec3 uClipMax;
uniform mat3 uNormalFromIndex;  // patient gradient from a leaf-index gradient
uniform int uLeafLevel;
uniform int uMaxIterations;
uniform float uStepMm;        // the finest step; each ray's chord is cut into equal steps <= it
uniform float uInvUnitDistance;
uniform float uEarlyTermination;
uniform float uNear, uFar;    // gl_FragDepth mapping (mm along the view axis)

uniform sampler3D uPool;      // GL_LINEAR, values of the bricks
uniform vec3 uPoolInvSize;    // 1 / pool size in texels
uniform ivec2 uSlotGrid;      // slots per row (x) and per layer (x * y)
uniform float uValueScale, uValueOffset;  // physical = texel * scale + offset
#ifdef GRADIENT_POOL
uniform sampler3D uGradientPool;
uniform float uGradientScale;
#endif

uniform sampler1D uTf;        // rgb, extinction -ln(1 - alpha) per unit distance
#if defined(MODE_MIP) && defined(CELL_SKIPPING)
// The pool value below which a maximum shows black (gpu::mipVisibleFrom): cells and groups
// of cells wholly below it are not evaluated (a ray that meets nothing above it stays empty,
// as one through empty nodes of the working set does).
uniform float uMipFloor;
#endif
#ifdef CELL_SKIPPING
uniform sampler3D uCellRange; // (min, max) texel value per CELL_VOXELS^3 cell of every slot
uniform sampler1D uTfNonZero; // entry i: uTf entries below i with opacity
#endif
uniform vec2 uTfMap;          // tf coordinate = value * uTfMap.x + uTfMap.y
#ifdef PREINTEGRATION
// transfer::SegmentExtinctionTable over [range.x, range.y] (the TF's opacity support within
// the data's range): (front, back) -> (mean colour x extinction, mean extinction per unit).
uniform sampler2D uPreintegration;
uniform vec2 uPreintegrationRange;
#endif
uniform int uColorPoints, uOpacityPoints, uGradientPoints;

uniform vec4 uMaterial;       // ambient, diffuse, specular, specular power
uniform vec3 uBoundary;       // kC, kS, kE
uniform vec3 uSilhouette;     // kC, kS, kE
uniform float uIsoValue;

layout(location = 0) out vec4 outColor;  // premultiplied
// depth of the first contribution (mm), value; IMAGE_ADAPTIVE: the oracle's d (pixels) and the
// pixel's depth-buffer value
layout(location = 1) out vec4 outAux;
#ifdef STATS
layout(location = 2) out vec4 outStats;  // samples, contributing, leaves visited, data leaves
#endif

const float kInfinity = 1.0 / 0.0;
const uint kInner = 2u;
const uint kDataLeaf = 1u;
const uint kNull = 0xFFFFFFFFu;
#ifdef STATS
vec4 stats;  // this pixel's counters (outStats), raised by the parts below
#endif

#include "raycast_classify.glsl"
#include "raycast_pool.glsl"
#include "raycast_shading.glsl"
#include "raycast_iso.glsl"
#include "raycast_mip.glsl"

void main() {
#ifdef IMAGE_ADAPTIVE
  // The ray through the centre of image pixel (2^l x, 2^l y).
  vec2 pixel = floor(gl_FragCoord.xy) * uLevelScale + 0.5;
  float oracle = kInfinity;  // the smallest projected voxel (pixels) of the leaves sampled
#else
  vec2 pixel = gl_FragCoord.xy;
#endif
  // The ray through this pixel's centre (Camera::ray; row 0 of the image is the top row).
  vec2 s = (2.0 * pixel / uViewport - 1.0) * uHalfExtent;
#ifdef PERSPECTIVE
  vec3 origin = uEye;
  vec3 dir = normalize(uForward + s.x * uRight + s.y * uUp);
#else
  vec3 origin = uEye + s.x * uRight + s.y * uUp;
  vec3 dir = uForward;
#endif
  vec3 qo = uQFromPatient * origin + uQOffset;
  vec3 dq = uQFromPatient * dir;

  outColor = vec4(0.0);
  outAux = vec4(kInfinity, 0.0, kInfinity, 1.0);
  FRAG_DEPTH = 1.0;
#ifdef IMAGE_ADAPTIVE
  atomicAdd(adaptiveCounters[0], 1u);
#endif
#ifdef STATS
  stats = vec4(0.0);
  outStats = stats;
#endif

  // Clip to the domain (clipOctreeDomain), or to the clip box inside it.
  float t0 = 0.0, t1 = kInfinity;
  vec3 inv;
  for (int a = 0; a < 3; ++a) {
    float d = dq[a];
    inv[a] = d != 0.0 ? 1.0 / d : 0.0;
    if (d == 0.0) {
      if (qo[a] < uClipMin[a] || qo[a] > uClipMax[a]) return;
      continue;
    }
    float tn = (uClipMin[a] - qo[a]) * inv[a], tf = (uClipMax[a] - qo[a]) * inv[a];
    t0 = max(t0, min(tn, tf));
    t1 = min(t1, max(tn, tf));
  }
  if (!(t1 >= t0)) return;

  // The chord is cut into n equal steps of delta <= uStepMm, sampled at their midpoints (the
  // CPU reference's rule); fine cell k belongs to the leaf holding its midpoint.
  float steps = max(1.0, ceil((t1 - t0) / uStepMm));
  float delta = (t1 - t0) / steps;
  int n = int(steps);

#ifdef MODE_DVR
  float transmittance = 1.0;
  float firstDepth = kInfinity;
  vec3 accum = vec3(0.0);
#ifdef JITTER
  // Where in its step each sample sits (0.5: the midpoint).
  float jit = rayJitter(uint(pixel.x), uint(uViewport.y) - 1u - uint(pixel.y));
#else
  float jit = 0.5;
#endif
#ifdef PREINTEGRATION
  float front = 0.0;  // the value at fine step boundary frontK (-1: none yet)
  int frontK = -1;
#endif
#endif
#ifdef MODE_MIP
  float best = -kInfinity;
  float bestT = t0;
  bool started = false;
#endif
#ifdef MODE_ISO
  // The ray's last iso sample and the one before it (t, excess), carried from leaf to leaf for
  // the thin-surface test (t < 0: none).
  vec2 isoLast = vec2(-1.0, 0.0), isoBefore = vec2(-1.0, 0.0);
#endif
  bool done = false;
  float tLast = t0;

  uint entry = 0u;
  int level = 0;
  vec3 boxMin = vec3(0.0);
  float dim = 1.0;
  float t = t0;
  for (int iteration = 0; iteration < uMaxIterations && t < t1 && !done; ++iteration) {
    // Down traversal by box subdivision: the child whose slab holds t on every axis.
    uint w = nodes[entry];
    while ((w >> 30) == kInner) {
      dim *= 0.5;
      uint child = 0u;
      for (int a = 0; a < 3; ++a) {
        float mid = boxMin[a] + dim;
        float tm = (mid - qo[a]) * inv[a];
        bool upper = dq[a] > 0.0 ? t >= tm : (dq[a] < 0.0 ? t < tm : qo[a] >= mid);
        if (upper) {
          boxMin[a] = mid;
          child |= 1u << a;
        }
      }
      entry = (w & 0x3FFFFFFFu) + child;
      w = nodes[entry];
      ++level;
    }
    // Exit: the nearest far plane, ties to the lowest axis.
    float tExit = kInfinity;
    int face = -1;
    for (int a = 0; a < 3; ++a) {
      if (dq[a] == 0.0) continue;
      float tf = ((dq[a] > 0.0 ? boxMin[a] + dim : boxMin[a]) - qo[a]) * inv[a];
      if (tf < tExit) {
        tExit = tf;
        face = 2 * a + (dq[a] > 0.0 ? 1 : 0);
      }
    }
    uint record = (w & 0x3FFFFFFFu) * 8u;
    float tEnd = min(tExit, t1);
#ifdef STATS
    if (tEnd > t) stats.z += 1.0;
#endif
    if ((w >> 30) == kDataLeaf && tEnd > t) {
#ifdef STATS
      stats.w += 1.0;
      touched[record / 8u] = 1u;
#endif
      // The brick drawn: the leaf's own, or (hidden leaves) an ancestor's dataUp levels up.
      uint slotWord = leaves[record];
      uint slot = slotWord & 0xFFFFFFu;
      int dataUp = int(slotWord >> 24u);
      float dataDim = dim * exp2(float(dataUp));
      vec3 dataMin = floor(boxMin / dataDim) * dataDim;
      int levelsUp = uLeafLevel - level + dataUp;
      float levelScale = exp2(float(levelsUp));
#ifdef IMAGE_ADAPTIVE
      {
#ifdef PERSPECTIVE
        float pixelMm = max(t * dot(dir, uForward), 1e-6) * uPixelScale;
#else
        float pixelMm = uPixelScale;
#endif
        oracle = min(oracle, uLeafVoxelMm * levelScale / pixelMm);  // image pixels
      }
#endif
#ifdef FEEDBACK
#ifdef IMAGE_ADAPTIVE
      // A ray of pyramid level l stands for up to 4^l pixels (conservative: counting more
      // pixels keeps a brick, never drops one).
      uint rayWeight = uint(uLevelScale * uLevelScale);
#else
      const uint rayWeight = 1u;
#endif
      atomicAdd(feedback[record / 4u], rayWeight);
      if (levelsUp > 0) {
#ifdef PERSPECTIVE
        float footprint = max(t * dot(dir, uForward), 1e-6) * uPixelScale;
#else
        float footprint = uPixelScale;
#endif
        if (uLodPixels <= 0.0 || uLeafVoxelMm * levelScale > uLodPixels * footprint) {
          atomicAdd(feedback[record / 4u + 1u], rayWeight);
        }
      }
#endif
      // texel(t) = p0 + t * p1 inside this leaf's slot.
      float texelsPerQ = float(BRICK_SIZE) / dataDim;
      vec3 p0 = slotOrigin(slot) + float(BORDER) + (qo - dataMin) * texelsPerQ;
      vec3 p1 = dq * texelsPerQ;
      int k0 = clamp(int(ceil((t - t0) / delta - 0.5)), 0, n);
      int k1 = clamp(int(ceil((tEnd - t0) / delta - 0.5)), 0, n);
      int m = 1 << levelsUp;  // fine steps per sample at this leaf's level (§5.3)

#ifdef MODE_DVR
#ifdef CELL_SKIPPING
      // The leaf's brick in its own voxels: x(t) = b0 + t * b1, voxel centres at i + 0.5.
      vec3 b0 = (qo - dataMin) * texelsPerQ, b1 = p1;
      int kLimit = k0;  // samples below kLimit lie in a cell known to hold some opacity
#else
      int kLimit = k1;
#endif
      int k = k0;
      while (k < k1) {
#ifdef CELL_SKIPPING
        // Cell by cell (CELL_VOXELS^3 voxels of the brick): skip those whose values all map
        // to zero opacity; stop at the first that does not, and sample up to its exit. The
        // first sample at or past an exit is found taking every group as full, which can
        // only keep a sample, never drop one.
        while (k >= kLimit && k < k1) {
          float tk = t0 + (float(k) + jit * float(min(m, k1 - k))) * delta;
          vec3 cell = clamp(floor((b0 + tk * b1) / float(CELL_VOXELS)), vec3(0.0), vec3(float(kCells - 1)));
          float exitT = tEnd;
          for (int a = 0; a < 3; ++a) {
            if (b1[a] != 0.0) {
              float plane = (cell[a] + (b1[a] > 0.0 ? 1.0 : 0.0)) * float(CELL_VOXELS);
              exitT = min(exitT, (plane - b0[a]) / b1[a]);
            }
          }
          int next = k + max(int(ceil(((exitT - t0) / delta - float(k) - jit * float(m)) / float(m))), 1) * m;
          if (exitT > tk && cellTransparent(slot, cell)) {
            k = next;
          } else {
            kLimit = next;
          }
        }
        if (k >= k1) break;
#endif
        // The cheap loop: one fetch and one classification per sample until a sample has
        // opacity (shading work stays out of it: llvmpipe runs pixels in lock-step).
        vec4 c = vec4(0.0);
        float g = 1.0, ts = 0.0;
        vec3 texel = vec3(0.0);
        float value = 0.0;
        int kEnd = min(kLimit, k1);
        for (;;) {
          g = float(min(m, k1 - k));
#ifdef PREINTEGRATION
          // The segment of fine steps k .. k + g: its front value carried over from the
          // segment before when that one ended here (in this leaf or the previous one).
          if (frontK != k) front = valueAt(p0 + (t0 + float(k) * delta) * p1);
          value = valueAt(p0 + (t0 + (float(k) + g) * delta) * p1);
          c = preintegrated(front, value);
          front = value;
          frontK = k + int(g);
          ts = t0 + (float(k) + 0.5 * g) * delta;
          texel = p0 + ts * p1;  // shading's gradient: at the segment's midpoint
#else
          ts = t0 + (float(k) + jit * g) * delta;
          texel = p0 + ts * p1;
          value = valueAt(texel);
          c = texture(uTf, value * uTfMap.x + uTfMap.y);
#endif
#ifdef STATS
          stats.x += 1.0;
#endif
          if (c.a > 0.0) break;
          k += m;
          if (k >= kEnd) break;
        }
        if (!(c.a > 0.0)) continue;  // no opacity up to kEnd
        float extinction = c.a;  // -ln(1 - alpha) per unit distance
#ifdef NEEDS_GRADIENT
        vec3 grad = gradientAt(texel, levelScale);
        float magnitude = length(grad);
        float factor = 1.0;
#ifdef GRADIENT_OPACITY
        factor *= interpolatePoints(uColorPoints + uOpacityPoints, uGradientPoints, magnitude, 1);
#endif
#ifdef BOUNDARY_ENHANCEMENT
        factor *= uBoundary.x + uBoundary.y * pow(magnitude, uBoundary.z);
#endif
#ifdef SILHOUETTE_ENHANCEMENT
        float facing = magnitude > 0.0 ? abs(dot(grad / magnitude, dir)) : 0.0;
        factor *= uSilhouette.x + uSilhouette.y * pow(1.0 - facing, uSilhouette.z);
#endif
        if (factor != 1.0) {
          float alpha = clamp((1.0 - exp(-extinction)) * factor, 0.0, 1.0);
          extinction = alpha < 1.0 ? -log(1.0 - alpha) : 1e4;
        }
#ifdef SHADING
        c.rgb = phong(c.rgb, grad, dir);
#endif
#endif
        float alphaStep = 1.0 - exp(-extinction * g * delta * uInvUnitDistance);
        if (alphaStep > 0.0) {
#ifdef STATS
          stats.y += 1.0;
#endif
          if (firstDepth == kInfinity) firstDepth = ts;
          accum += (transmittance * alphaStep) * c.rgb;
          transmittance *= 1.0 - alphaStep;
          tLast = ts;
          if (1.0 - transmittance >= uEarlyTermination) {
            done = true;
            break;
          }
        }
        k += m;
      }
#endif  // MODE_DVR

#ifdef MODE_ISO
      // Brackets between consecutive step boundaries t0 + k delta (k0 .. k1, every m).
      if (k1 > k0) {
        float ta = t0 + float(k0) * delta;
        float fa = valueAt(p0 + ta * p1) - uIsoValue;
        float samples = 1.0;
        // The sample before ta: the previous leaf's, when that leaf ended where this one starts.
        vec2 before = isoLast.x >= 0.0 && abs(isoLast.x - ta) <= 1e-3 * delta ? isoBefore
                                                                            : vec2(-1.0, 0.0);
        float hit = fa == 0.0 ? ta : -1.0;
        // A tight loop of one fetch per sample runs until a bracket (a sign change) or a
        // possible dip (isoDip's first test passes); what those need runs outside it, where
        // the other pixels of a SIMD group do not pay for it (../shared/LLVMPIPE.md).
        int k = k0;
        while (k < k1 && hit < 0.0) {
          float tb = ta, fb = fa;
          bool bracket = false, dip = false;
          for (; k < k1; k += m) {
            int kb = min(k + m, k1);
            tb = kb == n ? t1 : t0 + float(kb) * delta;
            fb = valueAt(p0 + tb * p1) - uIsoValue;
            samples += 1.0;
            if (fb == 0.0 || (fa < 0.0) != (fb < 0.0)) {
              bracket = true;
              break;
            }
            float s = fa < 0.0 ? -1.0 : 1.0;
            float g0 = s * before.y, g1 = s * fa, g2 = s * fb;
            if (before.x >= 0.0 && g0 > g1 && g2 >= g1) {
              float ha = ta - before.x, hb = tb - ta;
              float slope = kIsoDipSlopeSafety * max((g0 - g1) / ha, (g2 - g1) / hb);
              if (min(g0 + g1 - slope * ha, g1 + g2 - slope * hb) <= 0.0) {
                dip = true;
                break;
              }
            }
            before = vec2(ta, fa);
            ta = tb;
            fa = fb;
          }
          if (bracket) {
            hit = fb == 0.0 ? tb : isoRoot(p0, p1, ta, tb, fa, fb, samples);
          } else if (dip) {
            // Where this leaf's brick has texels to interpolate (border included).
            vec3 lo = slotOrigin(slot) + 0.5, hi = lo + float(BRICK_SIZE + 2 * BORDER - 1);
            float tMin = -kInfinity, tMax = kInfinity;
            for (int a = 0; a < 3; ++a) {
              if (p1[a] != 0.0) {
                float ta0 = (lo[a] - p0[a]) / p1[a], ta1 = (hi[a] - p0[a]) / p1[a];
                tMin = max(tMin, min(ta0, ta1));
                tMax = min(tMax, max(ta0, ta1));
              }
            }
            if (before.x >= tMin) {
              float s = fa < 0.0 ? -1.0 : 1.0;
              float fHit;
              float xv = isoDip(p0, p1, s, vec3(before.x, ta, tb), s * vec3(before.y, fa, fb), tMin,
                                tMax, samples, fHit);
              if (xv >= 0.0) {
                hit = fHit == 0.0 ? xv : isoRoot(p0, p1, before.x, xv, before.y, fHit, samples);
              }
            }
            before = vec2(ta, fa);
            ta = tb;
            fa = fb;
            k += m;
          }
        }
        isoBefore = before;
        isoLast = vec2(ta, fa);
#ifdef STATS
        stats.x += samples;
#endif
        if (hit >= 0.0) {
          vec4 c = classifyExact(uIsoValue);
#ifdef SHADING
          c.rgb = phong(c.rgb, gradientAt(p0 + hit * p1, levelScale), dir);
#endif
          outColor = vec4(c.rgb, 1.0);
          outAux = vec4(hit, uIsoValue, 0.0, 0.0);
#ifdef STATS
          stats.y += 1.0;
#endif
          tLast = hit;
          done = true;
        }
      }
#endif  // MODE_ISO

#ifdef MODE_MIP
      mipLeaf(p0, p1, t, tEnd, slot, uintBitsToFloat(leaves[record + 7u]), k0, k1, m, t0, delta, best,
              bestT, started);
#endif
    }
    if (face < 0 || !(tExit < t1) || done) break;
    uint neighbour = leaves[record + 1u + uint(face)];
    if (neighbour == kNull) break;
    // Neighbour jump: shift the box across the exit face, snap it to the neighbour's level.
    boxMin[face >> 1] += (face & 1) != 0 ? dim : -dim;
    level = int(neighbour >> 27);
    dim = exp2(-float(level));
    boxMin = floor(boxMin / dim) * dim;
    entry = neighbour & 0x07FFFFFFu;
    t = tExit;
  }

#ifdef MODE_DVR
  outColor = vec4(accum, 1.0 - transmittance);
  outAux = vec4(firstDepth, 0.0, 0.0, 0.0);
#endif
#ifdef MODE_MIP
  if (started) {
    vec4 c = classifyExact(best * uValueScale + uValueOffset);
    outColor = vec4(c.rgb * c.a, c.a);
    outAux = vec4(bestT, best * uValueScale + uValueOffset, 0.0, 0.0);
    tLast = bestT;
    done = c.a > 0.0;
  }
#endif
  if (done) {
    float z = max(tLast * dot(dir, uForward), uNear);
#ifdef PERSPECTIVE
    FRAG_DEPTH = clamp((1.0 / z - 1.0 / uNear) / (1.0 / uFar - 1.0 / uNear), 0.0, 1.0);
#else
    FRAG_DEPTH = clamp((z - uNear) / (uFar - uNear), 0.0, 1.0);
#endif
  }
#ifdef IMAGE_ADAPTIVE
  outAux.z = oracle;
  outAux.w = rayDepth;
#ifdef STATS
  atomicAdd(adaptiveCounters[1], uint(stats.x));
#endif
#endif
#ifdef STATS
  outStats = stats;
#endif
}
