#version 330 core
// One Jacobi sweep of XPBD over the distance constraints of the grid springs (Macklin, Muller &
// Chentanez 2016, eq. 17-18, damping eq. 26; docs/EQUATIONS.md, "XPBD"), the same as
// deformgl/sim/xpbd.py XpbdSolver.substep, in float32. Every node gathers the corrections of its
// NB_COUNT neighbour constraints (the 18 of Mosegaard & Sorensen 2005, section 3.1, then the 6
// flexion neighbours), all from the same iterate u_p:
//   C = |x_i - x_j| - L,  u = (x_i - x_j)/|x_i - x_j|,  at = 1 / (k_s h^2)      (Macklin, Müller & Chentanez 2016, eq. 4)
//   d_lambda = -omega (C + at lambda + gs u . ((x_i - x_i^n) - (x_j - x_j^n)))
//              / ((1 + gs) n_s (w_i + w_j) + at),  gs = c_s / (k_s h),  n_s = max(n_i, n_j)
//   lambda' = lambda + d_lambda,  x_i' = x_i + sum w_i u d_lambda
// Node j computes the same d_lambda for the same spring (every term is symmetric in i, j), so
// the two copies of a spring's lambda, one per end, stay equal. Drags (DRAGS > 0) are vector
// constraints C = x - target with compliance 1/k_drag and their lambda in u_lambda_drag. Then the
// ground and spheres project x (lib/constraints.glsl, no velocity rule); fixed nodes keep x^n.
//
// With XPBD_TERMS the node also gathers the corrections of the physics terms' constraints
// (terms/xpbd.glsl xpbd_terms(), composed of the terms' chunks by deformgl/sim/terms/glsl.py
// compose_xpbd(); their multipliers' changes from the terms' own passes over the same iterate),
// and a node's constraint count n_i is its static count (u_node A) plus the terms' constraints
// active after the last sweep (u_p w), which the pass writes for the next sweep into the w of the
// new iterate.
//
// Textures: u_lambda0..NB_LAYERS-1 RGBA32F, the lambda of neighbour 4l + c in channel c of layer
// l (docs/ARCHITECTURE.md); written to render targets 1..NB_LAYERS, the drag lambda to the next.
#include "lib/node_flags.glsl"
#include "lib/node_texel.glsl"
#ifndef DRAGS
#define DRAGS 0
#endif
// NB_LAYERS and NB_COUNT: 5 and 18 (the default: structural and shear) or 6 and 24 (+ flexion).
#include "lib/neighbour_count.glsl"

uniform sampler2D u_node;               // R inverse mass (0 fixed), G flags, B load groups, A constraint count
uniform sampler2D u_p;                  // xyz iterate
uniform sampler2D u_x;                  // xyz x^n, the substep's start
uniform isampler2DArray u_neighbours;   // NB_LAYERS RGBA32I: neighbour node numbers (absent: the node itself)
uniform sampler2DArray u_stiffness;     // NB_LAYERS RGBA32F: k_s of the spring to each neighbour, N/m (0: none)
uniform vec3 u_rest;                    // rest length of the structural, shear, flexion class
uniform float u_h;                      // substep, s
uniform float u_omega;                  // Jacobi relaxation
#ifdef SPRING_DAMPING
uniform vec3 u_ratio;                   // c_s / k_s of each class, s
#endif
uniform sampler2D u_lambda0;
uniform sampler2D u_lambda1;
uniform sampler2D u_lambda2;
uniform sampler2D u_lambda3;
uniform sampler2D u_lambda4;
#if NB_LAYERS > 5
uniform sampler2D u_lambda5;
#endif
#if DRAGS > 0
uniform int u_drag_node[DRAGS];
uniform float u_drag_k[DRAGS];          // N/m
uniform vec3 u_drag_target[DRAGS];      // target at the substep's end
uniform sampler2D u_lambda_drag;        // xyz lambda of the node's drag
#endif
#include "lib/constraints.glsl"
#ifdef XPBD_TERMS
#include "terms/xpbd.glsl"
#endif

layout(location = 0) out vec4 o_p;
layout(location = 1) out vec4 o_lambda0;
layout(location = 2) out vec4 o_lambda1;
layout(location = 3) out vec4 o_lambda2;
layout(location = 4) out vec4 o_lambda3;
layout(location = 5) out vec4 o_lambda4;
#if NB_LAYERS > 5
layout(location = 6) out vec4 o_lambda5;
#if DRAGS > 0
layout(location = 7) out vec4 o_lambda_drag;
#endif
#elif DRAGS > 0
layout(location = 6) out vec4 o_lambda_drag;
#endif

vec4 read_lambda(int layer, ivec2 texel) {
    if (layer == 0) return texelFetch(u_lambda0, texel, 0);
    if (layer == 1) return texelFetch(u_lambda1, texel, 0);
    if (layer == 2) return texelFetch(u_lambda2, texel, 0);
    if (layer == 3) return texelFetch(u_lambda3, texel, 0);
#if NB_LAYERS > 5
    if (layer == 5) return texelFetch(u_lambda5, texel, 0);
#endif
    return texelFetch(u_lambda4, texel, 0);
}

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    vec4 node = texelFetch(u_node, texel, 0);
    int flags = int(node.g);
    vec4 lam_out[NB_LAYERS];
    if ((flags & FLAG_EXISTS) == 0) {
        o_p = texelFetch(u_p, texel, 0);
        o_lambda0 = o_lambda1 = o_lambda2 = o_lambda3 = o_lambda4 = vec4(0.0);
#if NB_LAYERS > 5
        o_lambda5 = vec4(0.0);
#endif
#if DRAGS > 0
        o_lambda_drag = vec4(0.0);
#endif
        return;
    }
    float wi = node.r;
    float h = u_h;
    vec4 pi = texelFetch(u_p, texel, 0);
    vec3 xi = pi.xyz;
#ifdef XPBD_TERMS
    float ni = node.a + pi.w;  // + the terms' active constraints after the last sweep
#else
    float ni = node.a;
#endif
    vec3 xni = texelFetch(u_x, texel, 0).xyz;
    vec3 dx = vec3(0.0);
    for (int layer = 0; layer < NB_LAYERS; ++layer) {
        ivec4 nb = texelFetch(u_neighbours, ivec3(texel, layer), 0);
        vec4 ks = texelFetch(u_stiffness, ivec3(texel, layer), 0);
        vec4 lam = read_lambda(layer, texel);
        for (int c = 0; c < 4; ++c) {
            int j = 4 * layer + c;
            if (j >= NB_COUNT || !(ks[c] > 0.0)) {
                continue;
            }
            int cls = j < 6 ? 0 : (j < 18 ? 1 : 2);
            ivec2 tj = node_texel(nb[c]);
            vec4 nodej = texelFetch(u_node, tj, 0);
            vec4 pj = texelFetch(u_p, tj, 0);
            vec3 xj = pj.xyz;
            vec3 d = xi - xj;
            float len = length(d);
            vec3 u = len > 0.0 ? d / len : vec3(0.0);
            float C = len - u_rest[cls];
            float at = 1.0 / (ks[c] * h * h);
#ifdef XPBD_TERMS
            float ns = max(ni, nodej.a + pj.w);
#else
            float ns = max(ni, nodej.a);
#endif
#ifdef SPRING_DAMPING
            float gs = u_ratio[cls] / h;
            float moved = dot(u, (xi - xni) - (xj - texelFetch(u_x, tj, 0).xyz));
            float dl = -u_omega * (C + at * lam[c] + gs * moved) / ((1.0 + gs) * ns * (wi + nodej.r) + at);
#else
            float dl = -u_omega * (C + at * lam[c]) / (ns * (wi + nodej.r) + at);
#endif
            lam[c] += dl;
            dx += (wi * dl) * u;
        }
        lam_out[layer] = lam;
    }
#if DRAGS > 0
    vec3 ld = texelFetch(u_lambda_drag, texel, 0).xyz;
    int self_node = texel_node(texel);
    for (int k = 0; k < DRAGS; ++k) {
        if (u_drag_node[k] == self_node) {
            float atd = 1.0 / (u_drag_k[k] * h * h);
            vec3 dld = -u_omega * (xi - u_drag_target[k] + atd * ld) / (ni * wi + atd);
            ld += dld;
            dx += wi * dld;
        }
    }
    o_lambda_drag = vec4(ld, 0.0);
#endif
    float counts = 0.0;
#ifdef XPBD_TERMS
    xpbd_terms(dx, counts, texel, flags, wi);
#endif
    vec3 p = xi + dx;
#ifdef CONSTRAINTS
    constrain(p);
#endif
    if ((flags & FLAG_FIXED) != 0) {
        p = xni;
    }
    o_p = vec4(p, counts);
    o_lambda0 = lam_out[0];
    o_lambda1 = lam_out[1];
    o_lambda2 = lam_out[2];
    o_lambda3 = lam_out[3];
    o_lambda4 = lam_out[4];
#if NB_LAYERS > 5
    o_lambda5 = lam_out[5];
#endif
}
