// The mapping of one detailed-mesh vertex from its triangle-basis binding (Mosegaard & Sorensen
// 2005, section 3.3.3, eq. 9): the current p'1, p'2, p'3 and, in alpha, their packed normals
// (Mosegaard & Sorensen 2005, eq. 3); r' = sum w_i p'_i (Mosegaard & Sorensen 2005, eq. 4);
// v' = r' + basis' * o_t with the constant basis (Mosegaard & Sorensen 2005, eq. 6) or, per
// vertex, the curvature-corrected one (Mosegaard & Sorensen 2005, eq. 8). Normals and tangents
// are rebuilt in the same basis (section 3.3.4). A degenerate deformed basis keeps the rest
// offset and vectors in world space. Variant CURVATURE: compile the curvature-corrected basis
// and the per-vertex choice (without it every vertex uses the constant basis).
// Shared by render/mapped_mesh.vert (the mapping in the drawing vertex shader, and its transform
// feedback) and render/mapped_premap.frag (the mapping in a fragment pass).
#include "lib/octahedral.glsl"
#include "lib/triangle_basis.glsl"

struct MappedVertex {
    vec3 world;
    vec3 normal;
    vec3 tangent;
};

// n1..n3: the three nodes' state texels; w: Mosegaard & Sorensen 2005, eq. 4 weights;
// curvature: > 0.5 for the curvature-corrected basis; offset, normal, tangent: in the basis;
// offset_world, normal_world, tangent_world: the rest values in world space (the fallback).
MappedVertex map_vertex(vec4 n1, vec4 n2, vec4 n3, vec3 w, float curvature, vec3 offset, vec3 offset_world,
                        vec3 normal, vec3 normal_world, vec3 tangent, vec3 tangent_world) {
    vec3 r = w.x * n1.xyz + w.y * n2.xyz + w.z * n3.xyz;
    mat3 basis;
    bool ok;
#ifdef CURVATURE
    if (curvature > 0.5) {
        ok = curvature_basis(n1.xyz, n2.xyz, w, unpack_normal(n1.w), unpack_normal(n2.w),
                             unpack_normal(n3.w), basis);
    } else {
        ok = constant_basis(n1.xyz, n2.xyz, n3.xyz, basis);
    }
#else
    ok = constant_basis(n1.xyz, n2.xyz, n3.xyz, basis);
#endif
    MappedVertex m;
    m.world = r + (ok ? basis * offset : offset_world);
    m.normal = ok ? basis * normal : normal_world;
    m.tangent = ok ? basis * tangent : tangent_world;
    return m;
}
