#version 330 core
// Per-pixel Blinn-Phong. The interpolated vertex normal is used where defined; where it is not
// (zero: nodes without an eq. 3 normal), the flat normal of the triangle from derivatives.
#include "lib/blinn_phong.glsl"

in vec3 v_world;
in vec3 v_normal;
out vec4 o_colour;

void main() {
    vec3 n = v_normal;
    if (dot(n, n) < 1e-6) {
        n = cross(dFdx(v_world), dFdy(v_world));
    }
    n = normalize(n);
    o_colour = vec4(blinn_phong(v_world, n), 1.0);
}
