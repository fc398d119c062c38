#version 450 core
// Occlusion queries: nothing is written; GL_SAMPLES_PASSED counts the fragments that pass the
// depth test.

void main() {}
