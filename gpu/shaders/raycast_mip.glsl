// Part of raycast.frag.glsl: maximum intensity projection over one data leaf.
#ifdef MODE_MIP
// The trilinear interpolant inside one cell from its 8 texels (lo: z = 0 as x + 2y order,
// hi: z = 1), at fractional position f (clamped to the cell).
float trilinearCell(vec3 f, vec4 lo, vec4 hi) {
  f = clamp(f, 0.0, 1.0);
  vec4 z = mix(lo, hi, f.z);
  vec2 y = mix(z.xy, z.zw, f.y);
  return mix(y.x, y.y, f.x);
}

// One data leaf's part [t, tEnd) of the ray (texel(t) = p0 + t * p1 in the leaf's slot; samples
// k0 .. k1 of the chord, every m, for MIP_SAMPLED), whose brick's largest value is leafMax:
// raises the ray's maximum `best` (a pool value, at bestT; none before `started`).
//
// The exact maximum of the trilinear interpolant: the segment is cut where it crosses a
// texel-centre plane; on each piece the interpolant is a cubic in t, evaluated from the
// cell's 8 texels (no filtering hardware involved) at the ends and its critical points.
void mipLeaf(vec3 p0, vec3 p1, float t, float tEnd, uint slot, float leafMax, int k0, int k1,
             int m, float t0, float delta, inout float best, inout float bestT, inout bool started) {
#ifdef MIP_SAMPLED
  // The sampled maximum (MipMethod::Sampled): the interpolant at the samples of the
  // leaf's step only, as other raycasters do; never above the exact maximum.
  if (!started || leafMax > best * uValueScale + uValueOffset) {
    for (int k = k0; k < k1; k += m) {
      float ts = t0 + (float(k) + 0.5 * float(min(m, k1 - k))) * delta;
      float v = texture(uPool, (p0 + ts * p1) * uPoolInvSize).r;
#ifdef STATS
      stats.x += 1.0;
#endif
      if (!started || v > best) {
        best = v;
        bestT = ts;
        started = true;
      }
    }
  }
#else
  if (!started || leafMax > best * uValueScale + uValueOffset) {
    float ta = t;
    vec3 u0 = p0 - 0.5;  // cell space: texel centres at integers
    vec3 invP = vec3(p1.x != 0.0 ? 1.0 / p1.x : 0.0, p1.y != 0.0 ? 1.0 / p1.y : 0.0,
                     p1.z != 0.0 ? 1.0 / p1.z : 0.0);
    // The cell holding the segment's start, entered in the ray's direction; then a 3D DDA
    // from cell to cell (planes' t recomputed from the cell each time: no drift).
    vec3 ua = u0 + ta * p1;
    vec3 cell = floor(ua);
    for (int a = 0; a < 3; ++a) {
      if (p1[a] < 0.0 && ua[a] == cell[a]) cell[a] -= 1.0;
    }
    vec3 slotLo = slotOrigin(slot);
    vec3 slotHi = slotLo + float(BRICK_SIZE + 2 * BORDER - 2);
#ifdef CELL_SKIPPING
    // Cells are grouped by CELL_VOXELS per axis, group g holding the cells whose brick
    // voxel index k has floor((k + 1) / CELL_VOXELS) = g: all their texels lie in the
    // range of the brick's skipping cell g (its voxels and one more on each side). A group
    // whose largest texel cannot raise the maximum, or shows black (below uMipFloor), is
    // crossed in one step, to the plane where the DDA would have left its last cell (the
    // same t the DDA computes: the visible maxima and their positions stay exact).
    vec3 cellBase = slotLo + float(BORDER);
    vec3 checkedGroup = vec3(-1.0);
    float groupMax = kInfinity;  // the largest texel of checkedGroup
#endif
    for (int piece = 0; piece < 4 * (BRICK_SIZE + 2); ++piece) {
#ifdef CELL_SKIPPING
      vec3 group = floor((cell - cellBase + 1.0) / float(CELL_VOXELS));
      if (group != checkedGroup) {
        checkedGroup = group;
        groupMax = kInfinity;
        if (all(greaterThanEqual(group, vec3(0.0))) && all(lessThan(group, vec3(float(kCells))))) {
          groupMax = texelFetch(uCellRange, ivec3(slotIndex(slot) * float(kCells) + group), 0).g;
#ifdef STATS
          stats.x += 1.0;
#endif
        }
      }
      // Checked at every cell: the maximum may rise past the group's inside it.
      if (groupMax < uMipFloor || (started && groupMax <= best)) {
        // The plane where the ray leaves the group's last cell on each axis.
        vec3 first = cellBase + group * float(CELL_VOXELS) - 1.0;
        vec3 tPlane = vec3(kInfinity);
        for (int a = 0; a < 3; ++a) {
          if (p1[a] != 0.0) {
            tPlane[a] = ((p1[a] > 0.0 ? first[a] + float(CELL_VOXELS) : first[a]) - u0[a]) * invP[a];
          }
        }
        float tg = min(min(tPlane.x, tPlane.y), tPlane.z);
        if (!(tg < tEnd)) break;
        int a = tPlane.x <= tPlane.y ? (tPlane.x <= tPlane.z ? 0 : 2) : (tPlane.y <= tPlane.z ? 1 : 2);
        // The cell entered there: across the exit axis the next group's first cell,
        // on the others the cell holding the point, kept inside the group.
        vec3 ug = u0 + tg * p1;
        vec3 next = floor(ug);
        for (int b = 0; b < 3; ++b) {
          if (p1[b] < 0.0 && ug[b] == next[b]) next[b] -= 1.0;
        }
        next = clamp(next, first, first + float(CELL_VOXELS - 1));
        next[a] = p1[a] > 0.0 ? first[a] + float(CELL_VOXELS) : first[a] - 1.0;
        cell = next;
        ta = max(ta, tg);
        continue;
      }
#endif
      vec3 tNext = vec3(kInfinity);
      for (int a = 0; a < 3; ++a) {
        if (p1[a] != 0.0) tNext[a] = ((p1[a] > 0.0 ? cell[a] + 1.0 : cell[a]) - u0[a]) * invP[a];
      }
      float tb = min(min(tNext.x, tNext.y), min(tNext.z, tEnd));
      if (tb > ta) {
        vec3 c0 = clamp(cell, slotLo, slotHi);
        ivec3 ic = ivec3(c0);
        vec4 lo = vec4(texelFetch(uPool, ic, 0).r, texelFetch(uPool, ic + ivec3(1, 0, 0), 0).r,
                       texelFetch(uPool, ic + ivec3(0, 1, 0), 0).r,
                       texelFetch(uPool, ic + ivec3(1, 1, 0), 0).r);
        vec4 hi = vec4(texelFetch(uPool, ic + ivec3(0, 0, 1), 0).r,
                       texelFetch(uPool, ic + ivec3(1, 0, 1), 0).r,
                       texelFetch(uPool, ic + ivec3(0, 1, 1), 0).r,
                       texelFetch(uPool, ic + ivec3(1, 1, 1), 0).r);
        // The interpolant never exceeds its cell's largest texel: a cell that cannot
        // raise the maximum found so far needs no evaluation (exact; most cells behind
        // the first bright one).
#ifdef STATS
        stats.x += 1.0;
#endif
        vec4 top4 = max(lo, hi);
        float top = max(max(top4.x, top4.y), max(top4.z, top4.w));
#ifdef CELL_SKIPPING
        if (top >= uMipFloor && (!started || top > best)) {
#else
        if (!started || top > best) {
#endif
          float h = tb - ta;
          float v0 = trilinearCell(u0 + ta * p1 - c0, lo, hi);
          float v1 = trilinearCell(u0 + (ta + h / 3.0) * p1 - c0, lo, hi);
          float v2 = trilinearCell(u0 + (ta + 2.0 * h / 3.0) * p1 - c0, lo, hi);
          float v3 = trilinearCell(u0 + tb * p1 - c0, lo, hi);
          if (!started) {
            best = v0;
            bestT = ta;
            started = true;
          }
          float d1 = v1 - v0, d2 = v2 - 2.0 * v1 + v0, d3 = v3 - 3.0 * v2 + 3.0 * v1 - v0;
          float qa = 0.5 * d3, qb = d2 - d3, qc = d1 - 0.5 * d2 + d3 / 3.0;
          float scale = abs(qa) + abs(qb) + abs(qc);
          float r0 = -1.0, r1 = -1.0;
          if (abs(qa) > 1e-6 * scale) {
            float disc = qb * qb - 4.0 * qa * qc;
            if (disc >= 0.0) {
              float q = -0.5 * (qb + (qb >= 0.0 ? sqrt(disc) : -sqrt(disc)));
              r0 = q / qa;
              if (q != 0.0) r1 = qc / q;
            }
          } else if (abs(qb) > 1e-6 * scale) {
            r0 = -qc / qb;
          }
          if (r0 > 0.0 && r0 < 3.0) {
            float tr = ta + r0 * h / 3.0, vr = trilinearCell(u0 + tr * p1 - c0, lo, hi);
            if (vr > best) { best = vr; bestT = tr; }
          }
          if (r1 > 0.0 && r1 < 3.0) {
            float tr = ta + r1 * h / 3.0, vr = trilinearCell(u0 + tr * p1 - c0, lo, hi);
            if (vr > best) { best = vr; bestT = tr; }
          }
          if (v3 > best) { best = v3; bestT = tb; }
        }
        ta = tb;
      }
      if (tb >= tEnd) break;
      int a = tNext.x <= tNext.y ? (tNext.x <= tNext.z ? 0 : 2) : (tNext.y <= tNext.z ? 1 : 2);
      cell[a] += p1[a] > 0.0 ? 1.0 : -1.0;
    }
  }
#endif  // MIP_SAMPLED
}
#endif
