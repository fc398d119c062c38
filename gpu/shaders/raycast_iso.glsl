// Part of raycast.frag.glsl: the isosurface's root finding (isoRoot) and the thin-surface
// test (isoDip), each the twin of the CPU reference's rule of the same name.

#ifdef MODE_ISO
// The isosurface's crossing inside [lo, hi], whose excesses (value - isovalue) flo and fhi
// differ in sign: bisection, the last step the linear root (the reference's rule, marchIso).
float isoRoot(vec3 p0, vec3 p1, float lo, float hi, float flo, float fhi, inout float samples) {
  for (int i = 0; i < 40; ++i) {
    float mid = 0.5 * (lo + hi);
    if (mid <= lo || mid >= hi) break;
    float fm = valueAt(p0 + mid * p1) - uIsoValue;
    samples += 1.0;
    if (fm == 0.0) return mid;
    if ((fm < 0.0) == (flo < 0.0)) {
      lo = mid;
      flo = fm;
    } else {
      hi = mid;
      fhi = fm;
    }
  }
  return lo + (hi - lo) * (flo / (flo - fhi));
}

// A surface thinner than the step: three consecutive samples x.x < x.y < x.z whose excesses
// times s are g, all positive, the middle one the smallest, may straddle a dip of the
// interpolant through zero that no sample sees (a ray grazing thin bone). The reference's
// isoDip, the same rule. With L the steepest slope seen between the points, the Piyavskii-
// Shubert bound min over [a, b] >= (g(a) + g(b) - L' (b - a)) / 2 with L' = 2 L (slopes may be
// steeper than any seen) decides whether a dip is possible; the probe goes where the bound
// with L itself has its argmin (exact for a symmetric tent, the shape of the trilinear
// interpolant along an axis), or with L' where that bound stays above zero. A probe replaces
// one of the three; at most kIsoDipProbes. Returns the first probe with g <= 0 (its excess in
// fHit), or -1. Probes are kept in [tMin, tMax], where the brick has texels.
const int kIsoDipProbes = 4;
const float kIsoDipSlopeSafety = 2.0;
float isoDipArgmin(vec3 x, vec3 g, float slope, out float bound) {
  float boundA = 0.5 * (g.x + g.y - slope * (x.y - x.x));
  float boundB = 0.5 * (g.y + g.z - slope * (x.z - x.y));
  bound = min(boundA, boundB);
  return boundA <= boundB ? 0.5 * (x.x + x.y) + (g.x - g.y) / (2.0 * slope)
                          : 0.5 * (x.y + x.z) + (g.y - g.z) / (2.0 * slope);
}
float isoDip(vec3 p0, vec3 p1, float s, vec3 x, vec3 g, float tMin, float tMax, inout float samples,
             out float fHit) {
  fHit = 0.0;
  float slope = 0.0;
  for (int probe = 0; probe < kIsoDipProbes; ++probe) {
    slope = max(slope, max((g.x - g.y) / (x.y - x.x), (g.z - g.y) / (x.z - x.y)));
    if (!(slope > 0.0)) return -1.0;
    float safeBound, bound;
    float xSafe = isoDipArgmin(x, g, kIsoDipSlopeSafety * slope, safeBound);
    if (safeBound > 0.0) return -1.0;
    float xv = isoDipArgmin(x, g, slope, bound);
    if (bound > 0.0) xv = xSafe;
    xv = clamp(xv, tMin, tMax);
    if (xv <= x.x || xv >= x.z || xv == x.y) return -1.0;
    float f = valueAt(p0 + xv * p1) - uIsoValue;
    samples += 1.0;
    float gv = s * f;
    if (gv <= 0.0) {
      fHit = f;
      return xv;
    }
    if (xv < x.y) {
      if (gv < g.y) {
        x = vec3(x.x, xv, x.y);
        g = vec3(g.x, gv, g.y);
      } else {
        x.x = xv;
        g.x = gv;
      }
    } else if (gv < g.y) {
      x = vec3(x.y, xv, x.z);
      g = vec3(g.y, gv, g.z);
    } else {
      x.z = xv;
      g.z = gv;
    }
  }
  return -1.0;
}
#endif
