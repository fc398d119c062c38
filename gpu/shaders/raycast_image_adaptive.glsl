// Part of raycast.frag.glsl: the image pyramid's finer levels (see "Adaptive sampling in the
// image plane" in raycast.frag.glsl). Returns true when this pixel was copied or
// interpolated from the level above (its outputs written); false when its ray must be cast.
#ifdef IMAGE_ADAPTIVE
bool synthesizedFromCoarse() {
  // Pixel (x, y) of this level lies at pixel (x / 2, y / 2) of the level above when both
  // are even (its ray was cast there: copied), else midway between two or four of them.
  ivec2 size = textureSize(uCoarseColor, 0);
  ivec2 xy = ivec2(gl_FragCoord.xy);
  ivec2 p0 = xy / 2;
  ivec2 odd = xy - 2 * p0;
  ivec2 p1 = min(p0 + odd, size - 1);
  vec4 c00 = texelFetch(uCoarseColor, p0, 0), c10 = texelFetch(uCoarseColor, ivec2(p1.x, p0.y), 0);
  vec4 c01 = texelFetch(uCoarseColor, ivec2(p0.x, p1.y), 0), c11 = texelFetch(uCoarseColor, p1, 0);
  vec4 a00 = texelFetch(uCoarseAux, p0, 0), a10 = texelFetch(uCoarseAux, ivec2(p1.x, p0.y), 0);
  vec4 a01 = texelFetch(uCoarseAux, ivec2(p0.x, p1.y), 0), a11 = texelFetch(uCoarseAux, p1, 0);
  bool copy = odd == ivec2(0);
  // The three other pixels of the 2 x 2 block decide together, from the 2 x 2 coarse pixels
  // around the block: neighbouring pixels cast or interpolate together, as SIMD lanes and
  // GPU warps run them.
  ivec2 q1 = min(p0 + 1, size - 1);
  vec4 b10 = texelFetch(uCoarseColor, ivec2(q1.x, p0.y), 0), b01 = texelFetch(uCoarseColor, ivec2(p0.x, q1.y), 0);
  vec4 b11 = texelFetch(uCoarseColor, q1, 0);
  vec4 spread = max(max(c00, b10), max(b01, b11)) - min(min(c00, b10), min(b01, b11));
  float contrast = max(max(spread.r, spread.g), max(spread.b, spread.a));
  float d = min(min(a00.z, texelFetch(uCoarseAux, ivec2(q1.x, p0.y), 0).z),
                min(texelFetch(uCoarseAux, ivec2(p0.x, q1.y), 0).z, texelFetch(uCoarseAux, q1, 0).z));
  float spacing = 2.0 * uLevelScale;
  float bound = uAdaptiveThreshold * max(1.0, min(d / spacing, 16.0));
  if (copy || contrast <= bound) {
    outColor = 0.25 * (c00 + c10 + c01 + c11);
    float depth = min(min(a00.x, a10.x), min(a01.x, a11.x));
    float value = 0.25 * (a00.y + a10.y + a01.y + a11.y);
    float fragDepth = max(max(a00.w, a10.w), max(a01.w, a11.w));  // the farthest: never hides a brick
    outAux = copy ? a00 : vec4(depth, value, min(min(a00.z, a10.z), min(a01.z, a11.z)), fragDepth);
    gl_FragDepth = outAux.w;
#ifdef STATS
    outStats = vec4(0.0);
#endif
    return true;
  }
  return false;
}
#endif
