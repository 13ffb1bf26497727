#version 330 core
// A detailed mesh deformed by the nodes through its triangle-basis binding
// (Mosegaard & Sorensen 2005, section 3.3.3, eq. 9): three vertex texture fetches give the
// current p'1, p'2, p'3 and, in alpha, their packed normals (Mosegaard & Sorensen 2005, eq. 3);
// r' = sum w_i p'_i (Mosegaard & Sorensen 2005, eq. 4); v' = r' + basis' * o_t with the
// constant basis (Mosegaard & Sorensen 2005, eq. 6) or, per vertex, the curvature-corrected
// one (Mosegaard & Sorensen 2005, eq. 8). Normals and tangents are rebuilt in the same basis
// (section 3.3.4). A degenerate deformed basis keeps the rest offset and vectors in world space.
// Variants: CURVATURE (compile the curvature-corrected basis, Mosegaard & Sorensen 2005, eq. 8,
// and the per-vertex choice; without it every vertex uses the constant basis), NORMAL_MAP
// (carry tangents and UVs for tangent-space normal mapping).
#include "lib/octahedral.glsl"
#include "lib/triangle_basis.glsl"

in ivec2 in_texel1;         // atlas texels of the vertex's three nodes
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
    vec3 r = in_weights.x * n1.xyz + in_weights.y * n2.xyz + in_weights.z * n3.xyz;
    mat3 basis;
    bool ok;
#ifdef CURVATURE
    if (in_curvature > 0.5) {
        ok = curvature_basis(n1.xyz, n2.xyz, in_weights, unpack_normal(n1.w), unpack_normal(n2.w),
                             unpack_normal(n3.w), basis);
    } else {
        ok = constant_basis(n1.xyz, n2.xyz, n3.xyz, basis);
    }
#else
    ok = constant_basis(n1.xyz, n2.xyz, n3.xyz, basis);
#endif
    v_world = r + (ok ? basis * in_offset : in_offset_world);
    v_normal = ok ? basis * in_normal : in_normal_world;
#ifdef NORMAL_MAP
    v_tangent = ok ? basis * in_tangent.xyz : in_tangent_world;
    v_handedness = in_tangent.w;
    v_uv = in_uv;
#endif
    gl_Position = u_view_projection * vec4(v_world, 1.0);
}
