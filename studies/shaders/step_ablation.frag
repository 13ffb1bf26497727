#version 330 core
// Ablation of the foundation's step pass (sim/verlet.frag) for `python -m studies.step_profile`: the
// same fetches in the same order, cut off after stage STAGE, to measure what a step costs:
//   0  one fetch of the node's own position (the floor of a pass)
//   1  + previous position and node data (the step's own texels)
//   2  + the 5 neighbour-index texels (compact layouts that are not dense)
//   3  + the 18 neighbours' positions (summed)
//   4  + the spring sums of Mosegaard & Sorensen 2005, eq. 1/2 (length, unit vector per neighbour)
// Neighbours as in lib/springs.glsl: from u_neighbours, or with DENSE from node-number offsets
// (the node itself where the mask says the neighbour is absent).
// The output is meaningless; it only keeps the compiler from removing the work.
#ifndef STAGE
#define STAGE 4  // the whole cut-down step
#endif

uniform sampler2D u_position;
uniform sampler2D u_previous;
uniform sampler2D u_node;
#include "lib/node_texel.glsl"
#ifdef DENSE
uniform ivec3 u_strides;
#else
uniform isampler2DArray u_neighbours;
#endif

out vec4 o_value;

const ivec3 OFFSETS[18] = ivec3[18](
    ivec3(1, 0, 0), ivec3(-1, 0, 0), ivec3(0, 1, 0), ivec3(0, -1, 0), ivec3(0, 0, 1), ivec3(0, 0, -1),
    ivec3(1, 1, 0), ivec3(1, -1, 0), ivec3(-1, 1, 0), ivec3(-1, -1, 0),
    ivec3(1, 0, 1), ivec3(1, 0, -1), ivec3(-1, 0, 1), ivec3(-1, 0, -1),
    ivec3(0, 1, 1), ivec3(0, 1, -1), ivec3(0, -1, 1), ivec3(0, -1, -1));

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    vec4 x = texelFetch(u_position, texel, 0);
    vec4 acc = x;
#if STAGE >= 1
    vec4 node = texelFetch(u_node, texel, 0);
    acc += texelFetch(u_previous, texel, 0) + node;
#endif
#if STAGE >= 2
    int nb[18];
#ifdef DENSE
    int self_node = texel_node(texel);
    uint mask = uint(node.b);
    for (int j = 0; j < 18; ++j) {
        nb[j] = ((mask >> j) & 1u) != 0u ? self_node + OFFSETS[j].x * u_strides.x + OFFSETS[j].y * u_strides.y
                                           + OFFSETS[j].z * u_strides.z : self_node;
    }
#else
    for (int l = 0; l < 5; ++l) {
        ivec4 n = texelFetch(u_neighbours, ivec3(texel, l), 0);
        for (int c = 0; c < 4 && 4 * l + c < 18; ++c) {
            nb[4 * l + c] = n[c];
        }
    }
#endif
    for (int j = 0; j < 18; ++j) {
        acc.w += float(nb[j]);  // every index used, or the compiler drops the unused fetches
    }
#endif
#if STAGE == 3
    for (int j = 0; j < 18; ++j) {
        acc += texelFetch(u_position, node_texel(nb[j]), 0);
    }
#elif STAGE >= 4
    vec3 s = vec3(0.0), p = vec3(0.0);
    for (int j = 0; j < 18; ++j) {
        vec3 d = x.xyz - texelFetch(u_position, node_texel(nb[j]), 0).xyz;
        s += d / max(length(d), 1e-30);
        p += d;
    }
    acc.xyz += s + p;
#endif
    o_value = acc;
}
