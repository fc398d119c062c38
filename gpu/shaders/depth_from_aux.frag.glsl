#version 450 core
// The image-adaptive frame's depth buffer, from the depth-buffer values its passes carried
// in the aux target's w (raycast.frag.glsl's early stencil test leaves gl_FragDepth unused),
// for the occlusion queries that test bricks against it (occlusion.h).

uniform sampler2D uAux;

void main() {
  gl_FragDepth = texelFetch(uAux, ivec2(gl_FragCoord.xy), 0).w;
}
