// The position-Verlet update of one node (Mosegaard & Sorensen 2005, 3.1; Movania & Feng 2012):
// x' = 2x - x_prev + dt^2 a, a = (g + m*gravity + pull - (c + alpha m) v)/m, v = (x - x_prev)/dt,
// with the packed normal at x (Mosegaard & Sorensen 2005, eq. 3) in w. Shared by sim/verlet.frag
// (one node per fragment) and sim/verlet_block.frag (a block of nodes per fragment), so both
// compute every node bit for bit alike (where the driver contracts a * b + c alike in both: GLSL
// 3.30 has no `precise`; tested on llvmpipe). PULLS = number of scripted pull groups; TERMS_HOOD:
// the node's 3x3x3 neighbourhood for the terms (lib/node_hood.glsl: hood_diagonals, which both passes
// provide); TERMS:
// the system's further physics terms (lib/term_node.glsl: a term table's row of a blocked node is
// its block's texel, member g_local's layers).
#ifndef PULLS
#define PULLS 0
#endif

uniform float u_dt;
uniform float u_damping;        // c, N*s/m
uniform float u_mass_damping;   // Rayleigh alpha, 1/s (force -alpha m v)
uniform vec3 u_gravity;
#if PULLS > 0
uniform vec3 u_pull_force[PULLS];  // N per node, or N/kg on a FLAG_PULLS_PER_KG node, this step
#endif
#ifdef TERMS
// the system's physics terms (deformgl/sim/terms; terms/active.glsl, composed by the host)
#include "terms/active.glsl"
#endif

// x: state texel at t; x_prev: position at t - dt; node: static node data (lib/node_flags.glsl)
// of an existing node; s: its spring sum; texel: its texel (the terms).
vec4 verlet_node(ivec2 texel, vec4 x, vec3 x_prev, vec4 node, SpringSum s) {
    int flags = int(node.g);
    float normal_code = pack_normal(s.unit_sum);  // Mosegaard & Sorensen 2005, eq. 3
    if ((flags & FLAG_FIXED) != 0) {
        return vec4(x.xyz, normal_code);
    }
    float m = node.r;
    vec3 f = s.force + m * u_gravity - (u_damping + u_mass_damping * m) * (x.xyz - x_prev) / u_dt;
#ifdef TERMS_HOOD
    hood_diagonals(texel, x.xyz);
#endif
#ifdef TERMS
#ifdef BLOCKED
    ivec3 term_at = ivec3(texel, block_member(g_local));
#else
    ivec3 term_at = ivec3(texel, 0);
#endif
    terms_force(f, TermNode(term_at, x.xyz, (x.xyz - x_prev) / u_dt, m, term_bits(flags), 1.0));
#endif
#if PULLS > 0
    float per = (flags & FLAG_PULLS_PER_KG) != 0 ? m : 1.0;
    for (int g = 0; g < PULLS; ++g) {
        f += float((flags >> (PULL_SHIFT + g)) & 1) * (per * u_pull_force[g]);
    }
#endif
    return vec4(2.0 * x.xyz - x_prev + (u_dt * u_dt / m) * f, normal_code);
}
