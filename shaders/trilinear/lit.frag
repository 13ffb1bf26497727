#version 330 core
// Per-pixel Blinn-Phong of a transformed leaf (normals from trilinear/normals.glsl).
#include "lib/blinn_phong.glsl"

in vec3 v_world;
in vec3 v_normal;
out vec4 o_colour;

void main() {
    o_colour = vec4(blinn_phong(v_world, normalize(v_normal)), 1.0);
}
