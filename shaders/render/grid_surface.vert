#version 330 core
// One-to-one mapping (Mosegaard & Sorensen 2005, section 3.2): every surface vertex is a node;
// its position and packed normal (Mosegaard & Sorensen 2005, eq. 3) are fetched from the state texture (vertex texture fetch).
// A node of a one-node-thin sheet (a cloth) has no Mosegaard & Sorensen 2005, eq. 3 normal (its neighbours' unit vectors
// cancel in the plane): it takes the sheet's normal, cross(p(u+) - p(u-), p(v+) - p(v-)), from
// its neighbours in the plane (deformgl/render/sheet_normals.py); every other node names itself
// four times, the difference is zero and it keeps the packed normal.
#include "lib/octahedral.glsl"

in ivec2 in_texel;              // the node's texel in the layout
in ivec4 in_across_u;           // texels of its neighbours after (xy) and before (zw) it along the sheet's u
in ivec4 in_across_v;           // the same along v (u x v: the side the sheet's squares face)
uniform sampler2D u_position;   // RGBA32F: xyz position, w packed normal
uniform mat4 u_view_projection;

out vec3 v_world;
out vec3 v_normal;              // zero where the node has no defined normal
out float v_has_normal;         // 1 where it has one, 0 where not

void main() {
    vec4 node = texelFetch(u_position, in_texel, 0);
    vec3 du = texelFetch(u_position, in_across_u.xy, 0).xyz - texelFetch(u_position, in_across_u.zw, 0).xyz;
    vec3 dv = texelFetch(u_position, in_across_v.xy, 0).xyz - texelFetch(u_position, in_across_v.zw, 0).xyz;
    vec3 sheet = cross(du, dv);
    // (scale-free: a sheet folded flat onto itself, or any node naming itself, has none)
    bool on_sheet = length(sheet) > 1e-6 * length(du) * length(dv);
    v_world = node.xyz;
    v_normal = on_sheet ? normalize(sheet) : unpack_normal(node.w);
    v_has_normal = (on_sheet || has_normal(node.w)) ? 1.0 : 0.0;
    gl_Position = u_view_projection * vec4(node.xyz, 1.0);
}
