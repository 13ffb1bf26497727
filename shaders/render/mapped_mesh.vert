#version 330 core
// A detailed mesh deformed by the nodes through its triangle-basis binding, mapped in the drawing
// vertex shader (Mosegaard & Sorensen 2005, section 3.3.3): three vertex texture fetches, then
// lib/map_vertex.glsl (Mosegaard & Sorensen 2005, eq. 4, 6, 8, 9).
// Variants: CURVATURE (compile the curvature-corrected basis, Mosegaard & Sorensen 2005, eq. 8,
// and the per-vertex choice; without it every vertex uses the constant basis), NORMAL_MAP
// (carry tangents and UVs for tangent-space normal mapping).
#include "lib/map_vertex.glsl"

in ivec2 in_texel1;         // node texels of the vertex's three nodes
in ivec2 in_texel2;
in ivec2 in_texel3;
in vec3 in_weights;         // Mosegaard & Sorensen 2005, eq. 4
in vec3 in_offset;          // Mosegaard & Sorensen 2005, eq. 7: offset in the vertex's basis
in vec3 in_offset_world;    // Mosegaard & Sorensen 2005, eq. 5: rest offset, world space
                            // (the degenerate fallback)
in vec3 in_normal;          // vertex normal in the basis
in vec3 in_normal_world;
#ifdef CURVATURE
in float in_curvature;      // 1: curvature-corrected basis, 0: constant
                            // (Mosegaard & Sorensen 2005, eq. 8 and eq. 6)
#endif
#ifdef NORMAL_MAP
in vec4 in_tangent;         // xyz in the basis, w handedness
in vec3 in_tangent_world;
in vec2 in_uv;
out vec3 v_tangent;
out float v_handedness;
out vec2 v_uv;
#endif

uniform sampler2D u_position;   // RGBA32F state: xyz position, w packed normal
uniform mat4 u_view_projection;

out vec3 v_world;
out vec3 v_normal;

void main() {
    vec4 n1 = texelFetch(u_position, in_texel1, 0);
    vec4 n2 = texelFetch(u_position, in_texel2, 0);
    vec4 n3 = texelFetch(u_position, in_texel3, 0);
#ifdef CURVATURE
    float curvature = in_curvature;
#else
    float curvature = 0.0;
#endif
#ifdef NORMAL_MAP
    vec3 tangent = in_tangent.xyz, tangent_world = in_tangent_world;
#else
    vec3 tangent = vec3(0.0), tangent_world = vec3(0.0);
#endif
    MappedVertex m = map_vertex(n1, n2, n3, in_weights, curvature, in_offset, in_offset_world, in_normal,
                                in_normal_world, tangent, tangent_world);
    v_world = m.world;
    v_normal = m.normal;
#ifdef NORMAL_MAP
    v_tangent = m.tangent;
    v_handedness = in_tangent.w;
    v_uv = in_uv;
#endif
    gl_Position = u_view_projection * vec4(v_world, 1.0);
}
