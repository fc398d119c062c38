// Part of raycast.frag.glsl: reading the brick pool (slots, cell ranges, values, gradients).

vec3 slotIndex(uint slot) {
  uint sx = slot % uint(uSlotGrid.x);
  uint sy = (slot / uint(uSlotGrid.x)) % uint(uSlotGrid.y / uSlotGrid.x);
  uint sz = slot / uint(uSlotGrid.y);
  return vec3(sx, sy, sz);
}

vec3 slotOrigin(uint slot) { return slotIndex(slot) * float(BRICK_SIZE + 2 * BORDER); }

#ifdef CELL_SKIPPING
const int kCells = BRICK_SIZE / CELL_VOXELS;

// True when no sample inside `cell` of the slot's brick can have opacity: the uTf entries
// that linear filtering may read for values in the cell's range (one more on each side for
// rounding) are all transparent.
bool cellTransparent(uint slot, vec3 cell) {
  vec2 range = texelFetch(uCellRange, ivec3(slotIndex(slot) * float(kCells) + cell), 0).rg;
  vec2 c = (range * uValueScale + uValueOffset) * uTfMap.x + uTfMap.y;
  float lo = min(c.x, c.y) * float(TF_TABLE_SIZE) - 0.5, hi = max(c.x, c.y) * float(TF_TABLE_SIZE) - 0.5;
  int first = clamp(int(floor(lo)) - 1, 0, TF_TABLE_SIZE - 1);
  int last = clamp(int(floor(hi)) + 2, 0, TF_TABLE_SIZE - 1);
  return texelFetch(uTfNonZero, last + 1, 0).r == texelFetch(uTfNonZero, first, 0).r;
}
#endif

float valueAt(vec3 texel) {
  return texture(uPool, texel * uPoolInvSize).r * uValueScale + uValueOffset;
}

#if defined(SHADING) || defined(GRADIENT_OPACITY) || defined(BOUNDARY_ENHANCEMENT) || \
    defined(SILHOUETTE_ENHANCEMENT) || defined(MODE_ISO)
#define NEEDS_GRADIENT
// Patient-space gradient (value units per mm) at a texel position of a leaf whose samples
// are `levelScale` leaf voxels apart.
vec3 gradientAt(vec3 texel, float levelScale) {
#ifdef GRADIENT_POOL
  vec4 g = texture(uGradientPool, texel * uPoolInvSize);
  vec3 dir = g.xyz * 2.0 - 1.0;
  float len = length(dir);
  return len > 0.0 ? dir * (g.w * uGradientScale / len) : vec3(0.0);
#else
  const float h = GRADIENT_DELTA;
  vec3 gi = vec3(valueAt(texel + vec3(h, 0, 0)) - valueAt(texel - vec3(h, 0, 0)),
                 valueAt(texel + vec3(0, h, 0)) - valueAt(texel - vec3(0, h, 0)),
                 valueAt(texel + vec3(0, 0, h)) - valueAt(texel - vec3(0, 0, h)));
  return uNormalFromIndex * (gi / (2.0 * h * levelScale));
#endif
}
#endif
