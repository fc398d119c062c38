#version 450 core
// The image pyramid's finer levels (paper 002; "Adaptive sampling in the image plane" in
// raycast.frag.glsl), drawn before the raycasting pass of each level but the coarsest. A
// pixel whose ray the level above cast is copied from it; the three others of its 2 x 2 block
// are interpolated linearly between the two or four nearest pixels of the level above, unless
// the 2 x 2 pixels of the level above around the block differ by more than the error bound in
// any premultiplied channel. Then they are discarded: this pass leaves their stencil at 0 and
// the raycasting pass, whose early stencil test skips every other pixel, casts their rays.
// The block decides together, as SIMD lanes and GPU warps run neighbouring pixels together.
// The bound is relaxed where the paper's oracle says the data allows it: by d / spacing, where
// d is the smallest projected voxel (pixels) of the leaves the four coarse rays sampled and
// spacing = 2^(l+1) is the distance between them.
//
// Variants: STATS (the frame has a per-pixel counter target, zero for the pixels made here).

uniform sampler2D uCoarseColor, uCoarseAux;  // level l + 1
uniform float uLevelScale;                   // 2^l
uniform float uAdaptiveThreshold;

layout(location = 0) out vec4 outColor;  // as raycast.frag.glsl's outputs
layout(location = 1) out vec4 outAux;
#ifdef STATS
layout(location = 2) out vec4 outStats;
#endif

void main() {
  // Pixel (x, y) of this level lies at pixel (x / 2, y / 2) of the level above when both are
  // even, else midway between two or four of the 2 x 2 coarse pixels from there.
  ivec2 size = textureSize(uCoarseColor, 0);
  ivec2 xy = ivec2(gl_FragCoord.xy);
  ivec2 p0 = xy / 2;
  ivec2 q1 = min(p0 + 1, size - 1);
  vec4 c00 = texelFetch(uCoarseColor, p0, 0), c10 = texelFetch(uCoarseColor, ivec2(q1.x, p0.y), 0);
  vec4 c01 = texelFetch(uCoarseColor, ivec2(p0.x, q1.y), 0), c11 = texelFetch(uCoarseColor, q1, 0);
  vec4 a00 = texelFetch(uCoarseAux, p0, 0), a10 = texelFetch(uCoarseAux, ivec2(q1.x, p0.y), 0);
  vec4 a01 = texelFetch(uCoarseAux, ivec2(p0.x, q1.y), 0), a11 = texelFetch(uCoarseAux, q1, 0);
  bvec2 odd = bvec2(xy - 2 * p0);
  bool copy = !odd.x && !odd.y;

  vec4 spread = max(max(c00, c10), max(c01, c11)) - min(min(c00, c10), min(c01, c11));
  float contrast = max(max(spread.r, spread.g), max(spread.b, spread.a));
  float d = min(min(a00.z, a10.z), min(a01.z, a11.z));
  float spacing = 2.0 * uLevelScale;
  float bound = uAdaptiveThreshold * max(1.0, min(d / spacing, 16.0));
  if (!copy && contrast > bound) discard;  // cast by the raycasting pass

  // The nearest coarse pixels: along an axis where this pixel is even, only the first.
  vec4 n10 = odd.x ? c10 : c00, n01 = odd.y ? c01 : c00;
  vec4 n11 = odd.x ? (odd.y ? c11 : c10) : (odd.y ? c01 : c00);
  vec4 m10 = odd.x ? a10 : a00, m01 = odd.y ? a01 : a00;
  vec4 m11 = odd.x ? (odd.y ? a11 : a10) : (odd.y ? a01 : a00);
  outColor = 0.25 * (c00 + n10 + n01 + n11);
  float depth = min(min(a00.x, m10.x), min(m01.x, m11.x));
  float value = 0.25 * (a00.y + m10.y + m01.y + m11.y);
  float fragDepth = max(max(a00.w, m10.w), max(m01.w, m11.w));  // the farthest: never hides a brick
  outAux = copy ? a00 : vec4(depth, value, min(min(a00.z, m10.z), min(m01.z, m11.z)), fragDepth);
#ifdef STATS
  outStats = vec4(0.0);
#endif
}
