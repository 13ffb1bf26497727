#version 330 core
// First stage of the fragment two-stage mapping: one fragment per detailed-mesh vertex (vertex v
// at node_texel(v), lib/node_texel.glsl) maps it from its three nodes
// (lib/map_vertex.glsl: Mosegaard & Sorensen 2005, eq. 4, 6, 8, 9) into RGBA32F targets, which
// render/mapped_premapped.vert then draws. The same function as render/mapped_mesh.vert, once
// per vertex and in the renderer's parallel fragment threads (on llvmpipe, vertex shading runs
// on one thread, once per index it meets). Variants: CURVATURE, NORMAL_MAP (as mapped_mesh.vert).
#include "lib/map_vertex.glsl"
#include "lib/node_texel.glsl"

uniform sampler2D u_position;          // RGBA32F state: xyz position, w packed normal
uniform isampler2D u_vertex_texels;    // RGBA32I: state texels of the three nodes as x | y << 16; A 0
uniform sampler2DArray u_vertex_data;  // RGBA32F layers (deformgl/render/premap.py): 0 weights (w: curvature
                                       // flag), 1 offset, 2 offset_world, 3 normal, 4 normal_world;
                                       // NORMAL_MAP: 5 tangent (w handedness), 6 tangent_world, 7 uv
layout(location = 0) out vec4 o_world;     // xyz mapped position
layout(location = 1) out vec4 o_normal;    // xyz mapped normal (not normalised)
#ifdef NORMAL_MAP
layout(location = 2) out vec4 o_tangent;   // xyz mapped tangent, w handedness
layout(location = 3) out vec4 o_uv;        // xy
#endif

void main() {
    ivec2 t = ivec2(gl_FragCoord.xy);
    ivec4 nodes = texelFetch(u_vertex_texels, t, 0);
    vec4 w = texelFetch(u_vertex_data, ivec3(t, 0), 0);
    vec4 n1 = texelFetch(u_position, packed_texel(nodes.x), 0);
    vec4 n2 = texelFetch(u_position, packed_texel(nodes.y), 0);
    vec4 n3 = texelFetch(u_position, packed_texel(nodes.z), 0);
#ifdef NORMAL_MAP
    vec4 tangent = texelFetch(u_vertex_data, ivec3(t, 5), 0);
    vec3 tangent_world = texelFetch(u_vertex_data, ivec3(t, 6), 0).xyz;
#else
    vec4 tangent = vec4(0.0);
    vec3 tangent_world = vec3(0.0);
#endif
    MappedVertex m = map_vertex(n1, n2, n3, w.xyz, w.w, texelFetch(u_vertex_data, ivec3(t, 1), 0).xyz,
                                texelFetch(u_vertex_data, ivec3(t, 2), 0).xyz,
                                texelFetch(u_vertex_data, ivec3(t, 3), 0).xyz,
                                texelFetch(u_vertex_data, ivec3(t, 4), 0).xyz, tangent.xyz, tangent_world);
    o_world = vec4(m.world, 1.0);
    o_normal = vec4(m.normal, 0.0);
#ifdef NORMAL_MAP
    o_tangent = vec4(m.tangent, tangent.w);
    o_uv = vec4(texelFetch(u_vertex_data, ivec3(t, 7), 0).xy, 0.0, 0.0);
#endif
}
