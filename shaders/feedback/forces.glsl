// Acceleration a = F / m of one node (Movania & Feng 2012, eq. 1-3; the lost formulas as in
// docs/EQUATIONS.md), the same function as deformgl/sim/springs.py forces() and
// deformgl/sim/integrators.py acceleration().
//
// Per spring to neighbour j (rest length L, stiffness k, spring damping c_s), d = x_i - x_j,
// u = d/|d| (0 for |d| = 0):  f = k (L - |d|) u  - c_s ((v_i - v_j) . u) u
// (Movania & Feng 2012, eq. 2; lib/spring_force.glsl)
// per node: m g + wind_drag (wind - v) (WIND) - c v (Movania & Feng 2012, eq. 1) + loads and drags
// (lib/node_forces.glsl); with FEEDBACK_TERMS, the system's physics terms that have a
// transform-feedback chunk (terms/feedback.glsl feedback_terms(), composed of the terms' chunks by
// deformgl/sim/terms/glsl.py compose_feedback()).
// Fixed nodes have a = 0.
//
// The stage shader defines, before including this file:
//   vec4 eval_x(int j)   position (w mass) of node j at which forces are evaluated
//   vec3 eval_v(int j)   its velocity (only with SPRING_DAMPING)
//
// Neighbour lists (CSR), RGBA32I/R32I/RGBA32F 2D textures, NEAREST, read with texelFetch:
//   u_nodes   (NODE_ROW x rows)     node n: x = first list entry, y = count, z = 1 if fixed,
//                                   w = load-group bits
//   u_other   (SPRING_ROW x rows)   entry e: the other node j
//   u_springs (SPRING_ROW x rows)   entry e: x = L, y = k, z = c_s
// Each spring appears twice (once in the list of each end), so a node sums its own forces.
// NODE_ROW and SPRING_ROW: texels per row of those textures (deformgl: powers of two; defaults
// 1024 and 4096, the largest it uses).
#ifndef NODE_ROW
#define NODE_ROW 1024
#endif
#ifndef SPRING_ROW
#define SPRING_ROW 4096
#endif
#include "lib/node_texel.glsl"

uniform isampler2D u_nodes;
uniform isampler2D u_other;
uniform sampler2D u_springs;
#include "lib/node_forces.glsl"
#include "lib/spring_force.glsl"
#ifdef FEEDBACK_TERMS
#include "terms/feedback.glsl"
#endif

ivec4 node_info(int n) {
    return texelFetch(u_nodes, node_texel(n), 0);
}

vec3 list_acceleration(int i, ivec4 info, vec4 xi, vec3 vi) {
    if (info.z != 0) {
        return vec3(0.0);
    }
    vec3 f = vec3(0.0);
    for (int e = info.x; e < info.x + info.y; ++e) {
        ivec2 st = row_texel(e, SPRING_ROW);
        int j = texelFetch(u_other, st, 0).r;
        vec4 s = texelFetch(u_springs, st, 0);
#ifdef SPRING_DAMPING
        f += spring_force(xi.xyz - eval_x(j).xyz, s.x, s.y, s.z, vi - eval_v(j));
#else
        f += spring_force(xi.xyz - eval_x(j).xyz, s.x, s.y, 0.0, vec3(0.0));
#endif
    }
#ifdef FEEDBACK_TERMS
    feedback_terms(f, i, xi.xyz);
#endif
    add_node_forces(f, i, info.w, xi.xyz, vi, xi.w);
    return f / xi.w;
}
