// Acceleration a = F / m of one grid node for the fragment-pass integrators
// (Movania & Feng 2012, eq. 1-3; the lost formulas in docs/EQUATIONS.md), the same function as
// deformgl/sim/springs.py forces() and deformgl/sim/integrators.py acceleration(), in float32.
//
// Topology is implicit on the node grid (Mosegaard & Sorensen 2005, section 3.1): neighbour j of
// node i is looked up in u_neighbours, NB_LAYERS RGBA32I layers of node numbers in the order of
// deformgl/grid/nodes.py NEIGHBOUR_OFFSETS (6 structural at h, 12 shear at h*sqrt(2)), followed with
// FLEXION by the 6 flexion neighbours at 2h along +x, -x, +y, -y, +z, -z (Movania & Feng 2012,
// section 3). An absent neighbour points at the node itself: d = 0 gives u = 0 and no force,
// exactly as the reference's zero-length rule, so no neighbour mask is needed.
//
// Per spring, d = x_i - x_j, u = d/|d| (0 for |d| = 0), class stiffness k, rest length L,
// spring damping c_s (one value per class, as deformgl/sim/springs.py from_grid builds them;
// with SPRING_WEIGHTS each spring's k and c_s are the class's times its weight w_j):
//   f = k (L - |d|) u - c_s ((v_i - v_j) . u) u        (Movania & Feng 2012, eq. 2; damping only with
//                                                      SPRING_DAMPING; lib/spring_force.glsl)
// per node: m g + wind_drag (wind - v) (WIND) - c v (Movania & Feng 2012, eq. 1), loads and drags
// (lib/node_forces.glsl). Fixed nodes never call this.
//
// DENSE grids (every node of the box exists: blocks, cloth sheets) need no neighbour texture:
// neighbour j of node n is node n + u_offsets[j] where bit j of the node's neighbour mask (u_node
// alpha) is set, else the node itself (the same zero force).
//
// The including stage defines EVAL_X(T) and EVAL_V(T): position and velocity of the node at
// texel T in the state at which forces are evaluated, and declares u_node.
// NB_LAYERS and NB_COUNT: 5 and 18 (the default: structural and shear) or 6 and 24 (+ flexion).

#include "lib/neighbour_count.glsl"
#ifdef DENSE
uniform int u_offsets[NB_COUNT];  // node-number offset of each neighbour
#else
uniform isampler2DArray u_neighbours;
#endif
uniform vec3 u_k;           // stiffness of the structural, shear, flexion class, N/m
uniform vec3 u_rest;        // rest length of each class
#ifdef SPRING_DAMPING
uniform vec3 u_c;           // spring damping of each class, N*s/m
#endif
#ifdef SPRING_WEIGHTS
// NB_LAYERS layers RGBA32F: weight w_j of the spring to neighbour j (4 per layer, in neighbour
// order): its stiffness is w_j u_k[class] and its damping w_j u_c[class] (the calibrated
// lattice of deformgl/sim/materials.py: the share of full cells that contain the spring).
uniform sampler2DArray u_weights;
#endif
#include "lib/node_forces.glsl"
#include "lib/node_texel.glsl"
#include "lib/spring_force.glsl"

// The spring of class cls to the neighbour at texel tj (lib/spring_force.glsl).
vec3 class_spring_force(ivec2 tj, vec3 xi, vec3 vi, int cls) {
#ifdef SPRING_DAMPING
    return spring_force(xi - EVAL_X(tj), u_rest[cls], u_k[cls], u_c[cls], vi - EVAL_V(tj));
#else
    return spring_force(xi - EVAL_X(tj), u_rest[cls], u_k[cls], 0.0, vec3(0.0));
#endif
}

vec3 grid_acceleration(ivec2 texel, vec3 xi, vec3 vi, float m, int groups) {
    vec3 f = vec3(0.0);
#ifdef DENSE
    int self_node = texel_node(texel);
    int mask = int(texelFetch(u_node, texel, 0).a);
#endif
    for (int layer = 0; layer < NB_LAYERS; ++layer) {
#ifndef DENSE
        ivec4 nb = texelFetch(u_neighbours, ivec3(texel, layer), 0);
#endif
#ifdef SPRING_WEIGHTS
        vec4 w = texelFetch(u_weights, ivec3(texel, layer), 0);
#endif
        for (int c = 0; c < 4; ++c) {
            int j = 4 * layer + c;
            if (j >= NB_COUNT) {
                break;
            }
#ifdef DENSE
            int other = ((mask >> j) & 1) != 0 ? self_node + u_offsets[j] : self_node;
#else
            int other = nb[c];
#endif
            int cls = j < 6 ? 0 : (j < 18 ? 1 : 2);
#ifdef SPRING_WEIGHTS
            f += w[c] * class_spring_force(node_texel(other), xi, vi, cls);
#else
            f += class_spring_force(node_texel(other), xi, vi, cls);
#endif
        }
    }
    add_node_forces(f, texel_node(texel), groups, xi, vi, m);
    return f / m;
}
