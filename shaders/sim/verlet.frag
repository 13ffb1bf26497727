#version 330 core
// One position-Verlet step of the grid spring-mass system (Mosegaard & Sorensen 2005, 3.1;
// Movania & Feng 2012): x' = 2x - x_prev + dt^2 a, a = (g + m*gravity + pull - (c + alpha m) v)/m,
// v = (x - x_prev)/dt. Writes the new position and, in alpha, the packed normal at x (Mosegaard & Sorensen 2005, eq. 3).
// Variants: NEIGHBOUR_BRANCH and SPRING_WEIGHTS (per-spring stiffness; with SPRING_WEIGHT_LEVELS from the node
// texture's alpha; see springs.glsl), DRAW_POINTS (only existing nodes are drawn, so
// no empty-node test), PULLS = number of scripted pull groups (0 compiles no pull code), CELLS (compact layouts
// only) with CELL_CENTRE and/or CELL_BARRIER: the lattice's volumetric term (deformgl/sim/volume.py) of the
// node's full incident cells, from the neighbour positions the springs fetched and the 8 body diagonals
// (sim/cells/node_hood.glsl, lib/cell_forces.glsl).
#ifndef PULLS
#define PULLS 0
#endif
#include "lib/atlas.glsl"
#include "lib/node_flags.glsl"
#include "lib/octahedral.glsl"
#include "lib/springs.glsl"

uniform sampler2D u_position;   // RGBA32F: xyz position at t, w packed normal
uniform sampler2D u_previous;   // RGBA32F: xyz position at t - dt
uniform sampler2D u_node;       // RGBA32F static node data (node_flags.glsl)
uniform float u_dt;
uniform float u_damping;        // c, N*s/m
uniform float u_mass_damping;   // Rayleigh alpha, 1/s (force -alpha m v)
uniform vec3 u_gravity;
#if PULLS > 0
uniform vec3 u_pull_force[PULLS];  // N per node, this step
#endif
#ifdef CELLS
#ifndef COMPACT
#error "CELLS needs a compact layout (COMPACT): the z-slice atlas has no cell term"
#endif
#define CELL_POSITION(T) texelFetch(u_position, T, 0).xyz
#include "sim/cells/node_hood.glsl"
#endif

layout(location = 0) out vec4 o_position;

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    vec4 x = texelFetch(u_position, texel, 0);
    vec4 node = texelFetch(u_node, texel, 0);
    int flags = int(node.g);
#ifndef DRAW_POINTS
    if ((flags & FLAG_EXISTS) == 0) {
        o_position = x;
        return;
    }
#endif
    SpringSum s = spring_sum(u_position, texel, x.xyz, uint(node.b), uint(node.a));
    float normal_code = pack_normal(s.unit_sum);  // Mosegaard & Sorensen 2005, eq. 3
    if ((flags & FLAG_FIXED) != 0) {
        o_position = vec4(x.xyz, normal_code);
        return;
    }
    vec3 x_prev = texelFetch(u_previous, texel, 0).xyz;
    float m = node.r;
    vec3 f = s.force + m * u_gravity - (u_damping + u_mass_damping * m) * (x.xyz - x_prev) / u_dt;
#ifdef CELLS
    f += hood_cell_force(texel, x.xyz, cell_bits(flags));
#endif
#if PULLS > 0
    for (int g = 0; g < PULLS; ++g) {
        f += float((flags >> (PULL_SHIFT + g)) & 1) * u_pull_force[g];
    }
#endif
    o_position = vec4(2.0 * x.xyz - x_prev + (u_dt * u_dt / m) * f, normal_code);
}
