// Part of raycast.frag.glsl: Phong shading (DVR with SHADING, isosurfaces).

#if defined(SHADING) || defined(MODE_ISO)
vec3 phong(vec3 color, vec3 gradient, vec3 rayDir) {
  float magnitude = length(gradient);
  float diffuse = 0.0, specular = 0.0;
  if (magnitude > 0.0) {
    float nl = abs(dot(gradient / magnitude, rayDir));
    diffuse = nl;
    float rv = 2.0 * nl * nl - 1.0;
    specular = rv > 0.0 ? pow(rv, uMaterial.w) : 0.0;
  }
  return color * (uMaterial.x + uMaterial.y * diffuse) + vec3(uMaterial.z * specular);
}
#endif
