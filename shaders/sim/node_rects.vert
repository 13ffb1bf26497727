#version 330 core
// Rectangles around the existing nodes of each z-slice tile, so padding and empty space around
// the object cost no fragment work (two triangles per tile).
in vec2 in_texel_corner;   // rectangle corner in texel units
uniform vec2 u_target_size;
void main() {
    gl_Position = vec4(in_texel_corner / u_target_size * 2.0 - 1.0, 0.0, 1.0);
}
