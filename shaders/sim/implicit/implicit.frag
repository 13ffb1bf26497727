#version 330 core
// The passes of a backward-Euler step on the node grid (docs/EQUATIONS.md "Implicit Euler";
// float64 reference deformgl/sim/implicit.py; host deformgl/sim/backends/implicit_gpu.py):
// Preconditioned conjugate gradients on A dv = b, A = M + dt C + dt^2 H, matrix-free
// (sim/implicit/system.glsl): Jacobi, P^-1 = 1 / diag(A), or with PRECOND_BLOCK block-Jacobi,
// P^-1 = the inverse of A's 3x3 diagonal block per node. One define selects the pass:
//   SETUP      b = dt (f(x, v, t + dt) - dt H v), P^-1, and per texel R: b . P^-1 b, G: b . b
//   WARM       (the scaled warm start) q = A dv_prev, and per texel R: dv_prev . q, G: b . dv_prev
//   INIT       r = b - A dv (the warm start), p = P^-1 r, and per texel R: r . P^-1 r, G: r . r; with
//              WARM_SCALED dv = s dv_prev, s = (b . dv_prev) / (dv_prev . A dv_prev) (0 if that
//              is not > 0), the multiple of the last step's dv nearest the solution in the A norm,
//              r = b - s q (no product here), and dv is written too
//   MATVEC     q = A p, and p . q per texel
//   UPDATE     alpha = rz / pq; dv += alpha p, r -= alpha q, and per texel R: r . P^-1 r, G: r . r
//   DIRECTION  beta = rz_new / rz; p = P^-1 r + beta p
//   FINAL      v' = v + dv, x' = x + dt v', then the constraints (CONSTRAINTS)
//   TRUE_RESIDUAL  per texel R and G: r . r of the true residual r = b - A dv (after the
//              iterations, with a tolerance: the step's report, not CG's updated r)
//   MG_SMOOTH  the multigrid cycle's smoothing on this (the finest) level, x' = x + w D^-1 (rhs - A x),
//              D^-1 the block inverse SETUP wrote (PRECOND_BLOCK); with FROM_ZERO x' = w D^-1 rhs
//   MG_RESIDUAL  res = rhs - A x on this level (the coarse levels: sim/implicit/multigrid.frag)
// MULTIGRID (INIT, UPDATE, DIRECTION): P^-1 is the V-cycle, run between the passes: INIT and
// UPDATE leave r . z to multigrid.frag's RZ, DIRECTION reads z = M^-1 r from u_z.
// TERMS (SETUP, WARM, INIT, MATVEC, TRUE_RESIDUAL, MG_*): the system's physics terms
// (deformgl/sim/terms), their forces in f (sim/integrators/forces.glsl, with TERMS_HOOD the node's
// neighbourhood from the 27-node table u_hood_nodes: HOOD_NODES), K y and the node's block
// (sim/implicit/system.glsl); with TERMS_HELD the flag they set in SETUP travels in b's w.
// The scalars rz, pq, rz_new are 1x1 textures (R; rz and rz_new G: r . r, the stopping test's)
// reduced on the GPU (sim/implicit/reduce.frag).
// Fixed nodes and padding texels write 0 to every CG vector (FINAL: x bit for bit, v = 0).
// Without a pass define the pass is SETUP (the first of a step).
#if !defined(SETUP) && !defined(WARM) && !defined(INIT) && !defined(MATVEC) && !defined(UPDATE) && !defined(DIRECTION) && !defined(FINAL) && !defined(TRUE_RESIDUAL) && !defined(MG_SMOOTH) && !defined(MG_RESIDUAL)
#define SETUP
#endif
#include "lib/node_flags.glsl"

uniform sampler2D u_node;   // RGBA32F static: R mass kg, G flags (1 exists, 2 fixed; the terms' node
                            // bits 6-13, lib/node_flags.glsl), B load groups
uniform sampler2D u_x;      // xyz position at t
uniform sampler2D u_v;      // xyz velocity at t
uniform float u_dt;
#if defined(INIT) || defined(WARM) || defined(TRUE_RESIDUAL) || ((defined(MATVEC) || defined(MG_SMOOTH) || defined(MG_RESIDUAL)) && defined(TERMS_HELD))
uniform sampler2D u_b;      // xyz right-hand side; w (TERMS_HELD): the terms' flag, set in SETUP
#endif
#define EVAL_X(T) texelFetch(u_x, T, 0).xyz
#define EVAL_V(T) texelFetch(u_v, T, 0).xyz
// the neighbour and weight textures, the class uniforms and a = f / m (SETUP's f)
#include "sim/integrators/forces.glsl"
#include "sim/implicit/system.glsl"

#if ((defined(INIT) || defined(UPDATE) || defined(DIRECTION)) && !defined(MULTIGRID)) || defined(MG_SMOOTH)
uniform sampler2D u_inv;    // xyz 1 / diag(A); PRECOND_BLOCK: the diagonal of the block's inverse
#ifdef PRECOND_BLOCK
uniform sampler2D u_inv_off; // xyz the block inverse's off-diagonal (xy, xz, yz)
#endif
#endif
#if defined(INIT) && defined(WARM_SCALED)
uniform sampler2D u_q;      // xyz A dv_prev (WARM)
uniform sampler2D u_warm;   // 1x1 R: dv_prev . A dv_prev, G: b . dv_prev
#endif
#if defined(UPDATE) || defined(FINAL)
uniform sampler2D u_dv;     // xyz dv so far
#endif
#if defined(UPDATE) || defined(DIRECTION)
uniform sampler2D u_r;      // xyz residual
uniform sampler2D u_p;      // xyz search direction
uniform sampler2D u_rz;     // 1x1 R: r . P^-1 r before this iteration's update
#endif
#ifdef UPDATE
uniform sampler2D u_q;      // xyz A p
uniform sampler2D u_pq;     // 1x1 R: p . q
#endif
#ifdef DIRECTION
uniform sampler2D u_rz_new; // 1x1 R: r . P^-1 r after the update
#endif
#if defined(MG_SMOOTH) || defined(MG_RESIDUAL)
uniform sampler2D u_mg_rhs; // xyz the cycle's right-hand side on this level (CG's r)
#endif
#ifdef MG_SMOOTH
uniform float u_omega;      // the smoother's damping w (deformgl/sim/multigrid.py)
#endif
#if defined(DIRECTION) && defined(MULTIGRID)
uniform sampler2D u_z;      // xyz M^-1 r, the V-cycle's
#endif
#ifdef FINAL
#define VELOCITY
#include "lib/constraints.glsl"
#endif

layout(location = 0) out vec4 o_0;
#if defined(SETUP) || defined(INIT) || defined(MATVEC) || defined(UPDATE) || defined(FINAL) || defined(WARM)
layout(location = 1) out vec4 o_1;
#endif
#if defined(SETUP) || defined(INIT) || defined(UPDATE)
layout(location = 2) out vec4 o_2;
#endif
#if (defined(SETUP) && defined(PRECOND_BLOCK)) || (defined(INIT) && defined(WARM_SCALED))
layout(location = 3) out vec4 o_3;
#endif

float scalar(sampler2D s) {
    return texelFetch(s, ivec2(0, 0), 0).r;
}

#if defined(INIT) || defined(UPDATE) || defined(DIRECTION)
// z = P^-1 r at this texel
vec3 precondition(ivec2 texel, vec3 r) {
#if defined(MULTIGRID) && defined(DIRECTION)
    return texelFetch(u_z, texel, 0).xyz;
#elif defined(MULTIGRID)
    return vec3(0.0);   // (not used: RZ sums r . z once the cycle has run)
#elif defined(PRECOND_BLOCK)
    return apply_preconditioner(texelFetch(u_inv, texel, 0).xyz, texelFetch(u_inv_off, texel, 0).xyz, r);
#else
    return texelFetch(u_inv, texel, 0).xyz * r;
#endif
}
#endif

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    vec4 node = texelFetch(u_node, texel, 0);
    int flags = int(node.g);
    bool inactive = (flags & FLAG_EXISTS) == 0 || (flags & FLAG_FIXED) != 0;
#ifdef FINAL
    vec4 x = texelFetch(u_x, texel, 0);
    if (inactive) {
        o_0 = x;
        o_1 = vec4(0.0);
        return;
    }
    vec3 v1 = texelFetch(u_v, texel, 0).xyz + texelFetch(u_dv, texel, 0).xyz;
    vec3 x1 = x.xyz + u_dt * v1;
#ifdef CONSTRAINTS
    constrain(x1, v1);
#endif
    o_0 = vec4(x1, 0.0);
    o_1 = vec4(v1, 0.0);
#else
    if (inactive) {
        o_0 = vec4(0.0);
#if defined(SETUP) || defined(INIT) || defined(MATVEC) || defined(UPDATE) || defined(WARM)
        o_1 = vec4(0.0);
#endif
#if defined(SETUP) || defined(INIT) || defined(UPDATE)
        o_2 = vec4(0.0);
#endif
#if (defined(SETUP) && defined(PRECOND_BLOCK)) || (defined(INIT) && defined(WARM_SCALED))
        o_3 = vec4(0.0);
#endif
        return;
    }
    float m = node.r;
    vec3 xi = texelFetch(u_x, texel, 0).xyz;
    float dt = u_dt;
#if defined(SETUP)
    vec3 vi = texelFetch(u_v, texel, 0).xyz;
    vec3 sk, sc, dk, dc, ok, oc;
    spring_sums(texel, xi, vi, m, sk, sc, dk, dc, ok, oc);   // u_vec is v: sk = H_springs v
    float kd = node_drag_stiffness(texel_node(texel));
    vec3 hv = sk + kd * vi;
    vec3 f = m * grid_acceleration(texel, xi, vi, m, int(node.b));
    float flag = 0.0;   // b's w: the terms' flag (TERMS_HELD; the cells': a barrier term holds the node)
#ifdef TERMS
    // the physics terms' K v and their block of the node (their forces are in f: forces.glsl)
    TermNode term_node = TermNode(ivec3(texel, 0), xi, vi, m, term_bits(flags), 1.0);
    vec3 term_kv = vec3(0.0), term_dk = vec3(0.0), term_ok = vec3(0.0);
    terms_product(term_kv, term_node, vi);
    terms_diagonal(term_dk, term_ok, flag, term_node);
    hv += term_kv;
    dk += term_dk;
    ok += term_ok;
#endif
    vec3 b = dt * (f - dt * hv);
    vec3 diag = vec3(m + dt * node_damping(m) + dt * dt * kd) + (dt * dt) * dk + dt * dc;
#ifdef PRECOND_BLOCK
    vec3 off = (dt * dt) * ok + dt * oc;
    mat3 inverse_block = inverse(mat3(diag.x, off.x, off.y,
                                      off.x, diag.y, off.z,
                                      off.y, off.z, diag.z));
    vec3 inv = vec3(inverse_block[0][0], inverse_block[1][1], inverse_block[2][2]);
    vec3 inv_off = vec3(inverse_block[1][0], inverse_block[2][0], inverse_block[2][1]);
    o_0 = vec4(b, flag);
    o_1 = vec4(inv, 0.0);
    o_2 = vec4(dot(b, apply_preconditioner(inv, inv_off, b)), dot(b, b), 0.0, 0.0);
    o_3 = vec4(inv_off, 0.0);
#else
    vec3 inv = 1.0 / diag;
    o_0 = vec4(b, flag);
    o_1 = vec4(inv, 0.0);
    o_2 = vec4(dot(b, inv * b), dot(b, b), 0.0, 0.0);
#endif
#elif defined(WARM)
    vec3 dv = texelFetch(u_vec, texel, 0).xyz;     // u_vec is the last step's dv
    vec3 q = apply_system(texel, xi, dv, m);
    o_0 = vec4(q, 0.0);
    o_1 = vec4(dot(dv, q), dot(texelFetch(u_b, texel, 0).xyz, dv), 0.0, 0.0);
#elif defined(INIT)
    vec3 dv = texelFetch(u_vec, texel, 0).xyz;     // u_vec is dv (the last step's)
#ifdef WARM_SCALED
    vec4 w = texelFetch(u_warm, ivec2(0, 0), 0);
    float s = w.r > 0.0 ? w.g / w.r : 0.0;
    dv *= s;
    vec3 r = texelFetch(u_b, texel, 0).xyz - s * texelFetch(u_q, texel, 0).xyz;
    o_3 = vec4(dv, 0.0);
#else
    vec3 r = texelFetch(u_b, texel, 0).xyz - apply_system(texel, xi, dv, m);
#endif
    vec3 z = precondition(texel, r);   // (MULTIGRID: 0, and RZ_INIT writes p)
    o_0 = vec4(r, 0.0);
    o_1 = vec4(z, 0.0);
    o_2 = vec4(dot(r, z), dot(r, r), 0.0, 0.0);
#elif defined(MATVEC)
    vec3 p = texelFetch(u_vec, texel, 0).xyz;      // u_vec is p
    vec3 q = apply_system(texel, xi, p, m);
    o_0 = vec4(q, 0.0);
    o_1 = vec4(dot(p, q));
#elif defined(TRUE_RESIDUAL)
    vec3 r = texelFetch(u_b, texel, 0).xyz - apply_system(texel, xi, texelFetch(u_vec, texel, 0).xyz, m);
    o_0 = vec4(dot(r, r), dot(r, r), 0.0, 0.0);   // (u_vec is dv)
#elif defined(UPDATE)
    float pq = scalar(u_pq);
    float alpha = pq != 0.0 ? scalar(u_rz) / pq : 0.0;
    vec3 p = texelFetch(u_p, texel, 0).xyz;
    vec3 r = texelFetch(u_r, texel, 0).xyz - alpha * texelFetch(u_q, texel, 0).xyz;
    o_0 = vec4(texelFetch(u_dv, texel, 0).xyz + alpha * p, 0.0);
    o_1 = vec4(r, 0.0);
    o_2 = vec4(dot(r, precondition(texel, r)), dot(r, r), 0.0, 0.0);
#elif defined(DIRECTION)
    float rz = scalar(u_rz);
    float beta = rz != 0.0 ? scalar(u_rz_new) / rz : 0.0;
    vec3 z = precondition(texel, texelFetch(u_r, texel, 0).xyz);
    o_0 = vec4(z + beta * texelFetch(u_p, texel, 0).xyz, 0.0);
#elif defined(MG_SMOOTH)
    vec3 res = texelFetch(u_mg_rhs, texel, 0).xyz;
#ifdef FROM_ZERO
    vec3 y = vec3(0.0);
#else
    vec3 y = texelFetch(u_vec, texel, 0).xyz;      // u_vec is the cycle's x on this level
    res -= apply_system(texel, xi, y, m);
#endif
    o_0 = vec4(y + u_omega * apply_preconditioner(texelFetch(u_inv, texel, 0).xyz,
                                                  texelFetch(u_inv_off, texel, 0).xyz, res), 0.0);
#elif defined(MG_RESIDUAL)
    vec3 y = texelFetch(u_vec, texel, 0).xyz;
    o_0 = vec4(texelFetch(u_mg_rhs, texel, 0).xyz - apply_system(texel, xi, y, m), 0.0);
#endif
#endif
}
