#version 330 core
// One-to-one mapping (Mosegaard & Sorensen 2005, section 3.2): every surface vertex is a node;
// its position and packed normal (Mosegaard & Sorensen 2005, eq. 3) are fetched from the state texture (vertex texture fetch).
#include "lib/octahedral.glsl"

in ivec2 in_texel;              // the node's texel in the atlas
uniform sampler2D u_position;   // RGBA32F: xyz position, w packed normal
uniform mat4 u_view_projection;

out vec3 v_world;
out vec3 v_normal;              // zero where the node has no defined normal
out float v_has_normal;         // 1 where it has one, 0 where not

void main() {
    vec4 node = texelFetch(u_position, in_texel, 0);
    v_world = node.xyz;
    v_normal = unpack_normal(node.w);
    v_has_normal = has_normal(node.w) ? 1.0 : 0.0;
    gl_Position = u_view_projection * vec4(node.xyz, 1.0);
}
