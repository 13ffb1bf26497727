#version 330 core
// Second stage of the fragment two-stage mapping: each index fetches its vertex's mapped
// position and normal (and tangent, uv) from the targets render/mapped_premap.frag wrote
// (vertex v at lib/node_texel.glsl's node_texel(v)). Outputs as render/mapped_mesh.vert,
// for render/mapped_mesh.frag.
#include "lib/node_texel.glsl"

uniform sampler2D u_vertex_world;    // RGBA32F: xyz mapped position
uniform sampler2D u_vertex_normal;   // RGBA32F: xyz mapped normal
#ifdef NORMAL_MAP
uniform sampler2D u_vertex_tangent;  // RGBA32F: xyz tangent, w handedness
uniform sampler2D u_vertex_uv;       // RGBA32F: xy
out vec3 v_tangent;
out float v_handedness;
out vec2 v_uv;
#endif
uniform mat4 u_view_projection;
out vec3 v_world;
out vec3 v_normal;

void main() {
    ivec2 t = node_texel(gl_VertexID);
    v_world = texelFetch(u_vertex_world, t, 0).xyz;
    v_normal = texelFetch(u_vertex_normal, t, 0).xyz;
#ifdef NORMAL_MAP
    vec4 tangent = texelFetch(u_vertex_tangent, t, 0);
    v_tangent = tangent.xyz;
    v_handedness = tangent.w;
    v_uv = texelFetch(u_vertex_uv, t, 0).xy;
#endif
    gl_Position = u_view_projection * vec4(v_world, 1.0);
}
