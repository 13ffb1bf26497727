#version 330 core
// A fragment stage with no outputs: OpenGL ES links no program without one, so the ES
// profile pairs it with the vertex-only transform-feedback programs (rasterizer discarded).
void main() {
}
