#version 450 core
// One triangle that covers the whole viewport, with no vertex buffer: draw 3 vertices with an
// empty vertex array. gl_VertexID 0, 1, 2 -> clip positions (-1,-1), (3,-1), (-1,3); the
// rasteriser clips it to the screen square. vNdc is the fragment's normalised device position.

out vec2 vNdc;

void main() {
  vNdc = vec2(gl_VertexID == 1 ? 3.0 : -1.0, gl_VertexID == 2 ? 3.0 : -1.0);
  gl_Position = vec4(vNdc, 0.0, 1.0);
}
