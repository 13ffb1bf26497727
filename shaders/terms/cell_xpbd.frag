#version 330 core
// XPBD cell pass: one Jacobi sweep of the cells' constraints (terms/cell_constraints.glsl;
// Macklin, Muller & Chentanez 2016, eq. 18), the multiplier half of
// deformgl/sim/terms/volume/xpbd_form.py CellConstraints.sweep, in float32. One fragment per node; the node
// that is corner 0 of a full cell (incident cell 7) owns that cell and its multipliers, all from
// the iterate u_p of this sweep:
//   volume (CELL_VOLUME):  d_lambda = -omega (J - 1 + at lambda) / (n_s sum_a w_a |grad_a|^2 + at),
//                          at = 1 / (kappa V h^2), n_s = max over the 8 corners of n_a
//   barrier per corner c (CELL_BARRIER), where J_c < J_b or lambda_c > 0:
//                          d_lambda = -omega (J_c - J_b + at lambda) / (n_s sum_t w_t |grad_t|^2 + at),
//                          lambda' = max(lambda + d_lambda, 0), at = 8 / (kappa_b V h^2),
//                          n_s = max over the tet's 4 nodes
// with n_a = the node's static count (u_node A) + its active barriers after the last sweep (u_p w).
// The node sweep (sim/xpbd/iterate.frag, terms/cell_xpbd.glsl) then applies w_a grad_a d_lambda at every corner.
//
// Textures at the owner's texel (docs/ARCHITECTURE.md, "XPBD cell multipliers"): lambda RGBA32F x 2
// (corners 0..3, 4..7), state RGBA32F (R volume lambda, G its change this sweep, B the mask of
// corners whose barrier lambda is > 0, A 1 when any multiplier of the cell changed this sweep, else
// 0), delta RGBA32F x 2 (the barriers' lambda change this sweep).
#include "lib/node_flags.glsl"
#include "lib/node_texel.glsl"
#include "terms/cell_constraints.glsl"

uniform sampler2D u_node;              // R inverse mass (0 fixed), G flags (64 << q: incident cell q), A constraint count
uniform sampler2D u_p;                 // xyz iterate, w active barriers at the node
uniform isampler2DArray u_cell_nodes;  // 7 RGBA32I layers: the 3x3x3 neighbourhood, slot 4 l + c
uniform sampler2D u_cell_lambda0;      // barrier lambda of corners 0..3 (last sweep)
uniform sampler2D u_cell_lambda1;      // barrier lambda of corners 4..7
uniform sampler2D u_cell_state;        // R volume lambda (last sweep)
uniform float u_h;                     // substep, s
uniform float u_omega;                 // Jacobi relaxation

layout(location = 0) out vec4 o_lambda0;
layout(location = 1) out vec4 o_lambda1;
layout(location = 2) out vec4 o_state;
layout(location = 3) out vec4 o_delta0;
layout(location = 4) out vec4 o_delta1;

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    int flags = int(texelFetch(u_node, texel, 0).g);
    o_lambda0 = o_lambda1 = o_state = o_delta0 = o_delta1 = vec4(0.0);
    if ((flags & FLAG_EXISTS) == 0 || (term_bits(flags) & 128u) == 0u) {
        return;  // owns no cell
    }
    // corner c = dx + 2 dy + 4 dz is neighbourhood slot 13 + dx + 3 dy + 9 dz
    ivec4 l3 = texelFetch(u_cell_nodes, ivec3(texel, 3), 0);
    ivec4 l4 = texelFetch(u_cell_nodes, ivec3(texel, 4), 0);
    ivec4 l5 = texelFetch(u_cell_nodes, ivec3(texel, 5), 0);
    ivec4 l6 = texelFetch(u_cell_nodes, ivec3(texel, 6), 0);
    int corner_node[8] = int[8](l3.y, l3.z, l4.x, l4.y, l5.z, l5.w, l6.y, l6.z);
    vec3 p[27];
    float w[8];
    float n[8];
    for (int c = 0; c < 8; ++c) {
        ivec2 tc = node_texel(corner_node[c]);
        vec4 node = texelFetch(u_node, tc, 0);
        vec4 x = texelFetch(u_p, tc, 0);
        CELL_CORNER(p, 7, c) = x.xyz;
        w[c] = node.r;
        n[c] = node.a + x.w;
    }
    float volume = u_cell_h * u_cell_h * u_cell_h;
    float h2 = u_h * u_h;
    vec4 state = texelFetch(u_cell_state, texel, 0);
    float lam_v = state.r;
    float d_v = 0.0;
#ifdef CELL_VOLUME
    mat3 cof;
    float J = centre_jacobian(p, 7, cof);
    float mass_v = 0.0;
    float ns_v = 0.0;
    for (int c = 0; c < 8; ++c) {
        vec3 g = centre_gradient(cof, c);
        mass_v += w[c] * dot(g, g);
        ns_v = max(ns_v, n[c]);
    }
    float at_v = 1.0 / (u_cell_kappa * volume * h2);
    d_v = -u_omega * (J - 1.0 + at_v * lam_v) / (ns_v * mass_v + at_v);
    lam_v += d_v;
#endif
    vec4 l0 = texelFetch(u_cell_lambda0, texel, 0);
    vec4 l1 = texelFetch(u_cell_lambda1, texel, 0);
    float lam[8] = float[8](l0.x, l0.y, l0.z, l0.w, l1.x, l1.y, l1.z, l1.w);
    float d[8] = float[8](0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    int active_mask = 0;
#ifdef CELL_BARRIER
    float at_b = 1.0 / (u_cell_barrier * volume * 0.125 * h2);
    for (int c = 0; c < 8; ++c) {
        mat3 dj;
        float det = corner_gradients(p, 7, c, dj);
        if (det < u_cell_jb || lam[c] > 0.0) {
            vec3 g = tet_gradient(dj, c, c);
            float mass = w[c] * dot(g, g) + w[c ^ 1] * dot(dj[0], dj[0]) + w[c ^ 2] * dot(dj[1], dj[1])
                       + w[c ^ 4] * dot(dj[2], dj[2]);
            float ns = max(max(n[c], n[c ^ 1]), max(n[c ^ 2], n[c ^ 4]));
            float dl = -u_omega * (det - u_cell_jb + at_b * lam[c]) / (ns * mass + at_b);
            float next = max(lam[c] + dl, 0.0);
            d[c] = next - lam[c];
            lam[c] = next;
        }
        if (lam[c] > 0.0) {
            active_mask |= 1 << c;
        }
    }
#endif
    o_lambda0 = vec4(lam[0], lam[1], lam[2], lam[3]);
    o_lambda1 = vec4(lam[4], lam[5], lam[6], lam[7]);
    bool changed = d_v != 0.0;
    for (int c = 0; c < 8; ++c) {
        changed = changed || d[c] != 0.0;
    }
    o_state = vec4(lam_v, d_v, float(active_mask), changed ? 1.0 : 0.0);
    o_delta0 = vec4(d[0], d[1], d[2], d[3]);
    o_delta1 = vec4(d[4], d[5], d[6], d[7]);
}
