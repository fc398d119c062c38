#version 450 core
// Occlusion queries (occlusion.h): the front faces of a leaf's bounding box, given in camera
// space (x right, y up, z mm along the view axis), projected with the raycaster's depth
// mapping so that they test against the depth of each ray's last sample.

layout(location = 0) in vec3 aCamera;
uniform mat4 uClipFromCamera;

void main() { gl_Position = uClipFromCamera * vec4(aCamera, 1.0); }
