#version 330 core
// Per-pixel Blinn-Phong with the interpolated vertex normals. Where a vertex has no normal
// (Mosegaard & Sorensen 2005, eq. 3; v_has_normal < 1), the flat normal of the triangle (from derivatives) fills in its share.
#include "lib/blinn_phong.glsl"

in vec3 v_world;
in vec3 v_normal;
in float v_has_normal;
out vec4 o_colour;

void main() {
    vec3 flat_normal = cross(dFdx(v_world), dFdy(v_world));
    // a triangle seen edge-on has no screen-space normal: never normalise a zero vector (NaN)
    flat_normal = length(flat_normal) > 1e-30 ? normalize(flat_normal) : vec3(0.0, 0.0, 1.0);
    vec3 n = v_normal;
    if (dot(n, flat_normal) < 0.0) {
        flat_normal = -flat_normal;  // orient like the node normals
    }
    n = n + (1.0 - v_has_normal) * flat_normal + 1e-6 * flat_normal;
    n = length(n) > 1e-30 ? normalize(n) : flat_normal;
    o_colour = vec4(blinn_phong(v_world, n), 1.0);
}
