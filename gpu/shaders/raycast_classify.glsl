// Part of raycast.frag.glsl (included after its interface): the transfer function evaluated
// exactly from its control points, the pre-integration table's lookup and the ray-start jitter.

float interpolatePoints(int first, int count, float x, int channel) {
  if (x <= tfPoints[first].x || count == 1) return tfPoints[first][channel];
  for (int i = first + 1; i < first + count; ++i) {
    // The later point wins at a step: move on while x is at or beyond the next point.
    if (x < tfPoints[i].x) {
      vec4 a = tfPoints[i - 1], b = tfPoints[i];
      float w = (x - a.x) / (b.x - a.x);
      return a[channel] + w * (b[channel] - a[channel]);
    }
  }
  return tfPoints[first + count - 1][channel];
}

vec4 classifyExact(float value) {
  vec3 rgb = vec3(interpolatePoints(0, uColorPoints, value, 1),
                  interpolatePoints(0, uColorPoints, value, 2),
                  interpolatePoints(0, uColorPoints, value, 3));
  return vec4(rgb, interpolatePoints(uColorPoints, uOpacityPoints, value, 1));
}

#ifdef PREINTEGRATION
// The segment along which the value runs linearly from `front` to `back`: its mean colour and
// its extinction per unit distance counted over the whole segment (only the part of it whose
// values lie in the table's range has material: the fraction scales the extinction).
vec4 preintegrated(float front, float back) {
  float lo = uPreintegrationRange.x, hi = uPreintegrationRange.y;
  if (max(front, back) < lo || min(front, back) > hi) return vec4(0.0);
  float f = clamp(front, lo, hi), b = clamp(back, lo, hi);
  float span = abs(back - front);
  float fraction = span > 0.0 ? abs(b - f) / span : 1.0;
  vec2 bins = vec2(textureSize(uPreintegration, 0));
  vec2 uv = ((vec2(f, b) - lo) / (hi - lo) * (bins - 1.0) + 0.5) / bins;
  vec4 e = texture(uPreintegration, uv);
  return e.a > 0.0 ? vec4(e.rgb / e.a, e.a * fraction) : vec4(0.0);
}
#endif

#ifdef JITTER
// reference::rayJitter: lowbias32 of the pixel (column, row from the top), 24 bits.
float rayJitter(uint x, uint y) {
  uint h = (x * 0x8da6b343u) ^ (y * 0xd8163841u);
  h ^= h >> 16;
  h *= 0x7feb352du;
  h ^= h >> 15;
  h *= 0x846ca68bu;
  h ^= h >> 16;
  return float(h >> 8) * (1.0 / 16777216.0);
}
#endif
