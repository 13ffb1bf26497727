#version 330 core
// One position-Verlet step of the grid spring-mass system, one node per fragment (Mosegaard &
// Sorensen 2005, 3.1; the update is sim/verlet_node.glsl). Writes the new position and, in alpha,
// the packed normal at x (Mosegaard & Sorensen 2005, eq. 3).
// Drawn over the compact layout's texture (sim/fullscreen.vert); texels past the last node are
// empty and keep their value. Variants: SPRING_WEIGHTS (per-spring stiffness; with
// SPRING_WEIGHT_LEVELS from the node texture's alpha; see springs.glsl), PULLS = number of scripted pull groups (0 compiles no pull code), TERMS: the system's
// physics terms (sim/verlet_node.glsl), with TERMS_HOOD (HOOD_DIAGONALS) the
// node's 3x3x3 neighbourhood kept for them from the neighbour positions the springs fetched and the 8
// body diagonals (lib/node_hood.glsl).
#ifndef COMPACT
#define COMPACT  // (the one layout of the one-node pass; a standalone compile gets it too)
#endif
#include "lib/node_flags.glsl"
#include "lib/octahedral.glsl"
#include "lib/springs.glsl"

uniform sampler2D u_position;   // RGBA32F: xyz position at t, w packed normal
uniform sampler2D u_previous;   // RGBA32F: xyz position at t - dt
uniform sampler2D u_node;       // RGBA32F static node data (node_flags.glsl)
#ifdef TERMS_HOOD
#define HOOD_POSITION(T) texelFetch(u_position, T, 0).xyz
#include "lib/node_hood.glsl"
#endif
// (lib/term_node.glsl: another node's state by number, for the terms that read it)
#define TERM_POSITION(T) texelFetch(u_position, T, 0).xyz
#define TERM_VELOCITY(T) ((texelFetch(u_position, T, 0).xyz - texelFetch(u_previous, T, 0).xyz) / u_dt)
#include "sim/verlet_node.glsl"

layout(location = 0) out vec4 o_position;

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    vec4 x = texelFetch(u_position, texel, 0);
    vec4 node = texelFetch(u_node, texel, 0);
    if ((int(node.g) & FLAG_EXISTS) == 0) {
        o_position = x;
        return;
    }
    SpringSum s = spring_sum(u_position, texel, x.xyz, uint(node.b), uint(node.a));
    o_position = verlet_node(texel, x, texelFetch(u_previous, texel, 0).xyz, node, s);
}
