#version 330 core
// Per-pixel Blinn-Phong of the mapped detailed mesh; with NORMAL_MAP, the normal is perturbed
// by a tangent-space normal map (RGB = n * 0.5 + 0.5, z along the surface normal) through the
// deformed tangent frame (Mosegaard & Sorensen 2005, 3.3.4).
#include "lib/blinn_phong.glsl"

in vec3 v_world;
in vec3 v_normal;
#ifdef NORMAL_MAP
in vec3 v_tangent;
in float v_handedness;
in vec2 v_uv;
uniform sampler2D u_normal_map;
uniform float u_normal_map_strength;  // 0: no perturbation, 1: as stored
#endif
out vec4 o_colour;

void main() {
    // interpolated normals can cancel: never normalise a zero vector (NaN)
    vec3 n = length(v_normal) > 1e-30 ? normalize(v_normal) : vec3(0.0, 0.0, 1.0);
#ifdef NORMAL_MAP
    vec3 t = v_tangent - dot(v_tangent, n) * n;
    t = length(t) > 1e-30 ? normalize(t) : normalize(cross(n, abs(n.x) < 0.9 ? vec3(1.0, 0.0, 0.0) : vec3(0.0, 1.0, 0.0)));
    vec3 b = cross(n, t) * v_handedness;
    vec3 m = texture(u_normal_map, v_uv).xyz * 2.0 - 1.0;
    m.xy *= u_normal_map_strength;
    n = normalize(mat3(t, b, n) * m);
#endif
    o_colour = vec4(blinn_phong(v_world, n), 1.0);
}
