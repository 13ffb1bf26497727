// The lattice's volumetric term and inversion barrier on one node, gathered from its (up to 8)
// full incident cells: the float32 twin of deformgl/sim/terms/volume/energy.py volume_forces() (derivation
// there and in docs/EQUATIONS.md, "Any Poisson's ratio"). Per full cell of rest volume V = h^3:
//   centre term   E = V kappa/2 (J - 1)^2, J = det F at the cell centre,
//                 F = sum_c x_c (x) G_c, G_c = s_c / (4h)      (one-point volumetric quadrature;
//                 Smith, de Goes & Kim 2018, eq. 14, alpha = 1); force on corner a:
//                 -V kappa (J - 1) cof(F) G_a
//   corner barrier per corner c: E_c = V/8 kappa_b/2 (J_b - J_c)^2 where J_c < J_b, J_c the
//                 trilinear Jacobian at the corner, det [e_0 e_1 e_2] / h^3 with e_k the cell edge
//                 from c along axis k oriented by -s_c[k]
// Corner c = dx + 2 dy + 4 dz of a cell sits at its lower corner + h (dx, dy, dz); its sign
// vector is s_c = 2 (dx, dy, dz) - 1. Incident cell q = qx + 2 qy + 4 qz of a node is the cell
// whose lower corner is the node's neighbour at offset (qx - 1, qy - 1, qz - 1); the node is its
// corner 7 - q.
//
// The including shader provides the 27 positions of the node's 3x3x3 neighbourhood in
// cell_p[(dx + 1) + 3 (dy + 1) + 9 (dz + 1)] (the node itself at 13; an absent node may hold any
// finite value: only full cells are read) and the bit mask of its full incident cells, and calls
// cell_forces(cell_p, cells). Node data come through the backend's own layout functions
// (lib/node_texel.glsl), so this file knows no texture.

#ifndef CELL_FORCES_GLSL
#define CELL_FORCES_GLSL

uniform float u_cell_h;        // h, m
uniform float u_cell_kappa;    // kappa = lambda - mu, Pa (0 at nu = 1/4)
uniform float u_cell_barrier;  // kappa_b, Pa
uniform float u_cell_jb;       // J_b: the corner Jacobian below which the barrier acts

vec3 cell_sign(int c) {
    return vec3(float(((c >> 0) & 1) * 2 - 1), float(((c >> 1) & 1) * 2 - 1), float(((c >> 2) & 1) * 2 - 1));
}

// Position of corner c of incident cell q.
#define CELL_CORNER(P, Q, C) P[(((Q) & 1) + ((C) & 1)) + 3 * ((((Q) >> 1) & 1) + (((C) >> 1) & 1)) + 9 * ((((Q) >> 2) & 1) + (((C) >> 2) & 1))]

// d det(F_c) / d x of corner c's neighbour along each axis k (columns 0..2) and the corner's
// det F_c. The node at corner c moves by minus their sum.
float corner_gradients(vec3 p[27], int q, int c, out mat3 dj) {
    vec3 s = cell_sign(c);
    vec3 xc = CELL_CORNER(p, q, c);
    float inv_h = 1.0 / u_cell_h;
    vec3 e0 = (CELL_CORNER(p, q, c ^ 1) - xc) * (-s.x * inv_h);
    vec3 e1 = (CELL_CORNER(p, q, c ^ 2) - xc) * (-s.y * inv_h);
    vec3 e2 = (CELL_CORNER(p, q, c ^ 4) - xc) * (-s.z * inv_h);
    vec3 g0 = cross(e1, e2), g1 = cross(e2, e0), g2 = cross(e0, e1);
    dj = mat3(g0 * (-s.x * inv_h), g1 * (-s.y * inv_h), g2 * (-s.z * inv_h));
    return dot(e0, g0);
}

// The barrier force on corner `a` from the tet of corner c (a == c or a neighbour of c).
vec3 barrier_term(vec3 p[27], int q, int c, int a, float weight) {
    mat3 dj;
    float det = corner_gradients(p, q, c, dj);
    if (det >= u_cell_jb) {
        return vec3(0.0);
    }
    float push = weight * (u_cell_jb - det);   // V/8 kappa_b (J_b - J) >= 0
    if (a == c) {
        return -push * (dj[0] + dj[1] + dj[2]);
    }
    int k = (a ^ c) == 1 ? 0 : ((a ^ c) == 2 ? 1 : 2);
    return push * dj[k];
}

// Compile-time choice of the terms (cell_corner_force): an including shader that defines
// CELL_CENTRE and/or CELL_BARRIER gets those terms only, unconditionally (the fragment backend
// defines the terms whose modulus is > 0: llvmpipe runs a uniform branch's body anyway, so a
// skipped term must not be compiled); one that defines neither gets both, each behind a test of
// its modulus (u_cell_kappa > 0, u_cell_barrier > 0).
#if !defined(CELL_CENTRE) && !defined(CELL_BARRIER)
#define CELL_CENTRE
#define CELL_BARRIER
#define CELL_TERMS_CHECKED
#endif

// The tet of corner c of a cell (y: its 8 corners): h^3 det F_c = det [e_0 e_1 e_2] with e_k its
// edge along +axis k (from the corner with bit k clear to the one with it set: the reference's
// e_k oriented by -s_c[k], times h), as e_k . g_k with g_k = d det / d e_k the cross product of
// the other two edges (cyclic: e_1 x e_2, e_2 x e_0, e_0 x e_1), which is returned: the one
// gradient a neighbour of c along k needs.
float cell_tet(vec3 y[8], int c, int k, out vec3 g) {
    vec3 e0 = y[c | 1] - y[c & 6];
    vec3 e1 = y[c | 2] - y[c & 5];
    vec3 e2 = y[c | 4] - y[c & 3];
    if (k == 0) {
        g = cross(e1, e2);
        return dot(e0, g);
    }
    if (k == 1) {
        g = cross(e2, e0);
        return dot(e1, g);
    }
    g = cross(e0, e1);
    return dot(e2, g);
}

// The barrier's scalar factor of a tet whose unscaled determinant is det = h^3 J_c:
// V/8 kappa_b (J_b - J_c) / h^3 with V = h^3, i.e. weight (jb3 - det) / h^3 (weight = kappa_b / 8,
// jb3 = J_b h^3), and 0 where J_c >= J_b (branch-free: llvmpipe would run the branch anyway).
// The force on a node of the tet is this factor times +-(a cross product of two unscaled edges).
float cell_push(float det, float weight, float jb3) {
    return weight * max(jb3 - det, 0.0) / (u_cell_h * u_cell_h * u_cell_h);
}

// The force of both terms of one cell (y: its 8 corners) on its corner a, computing only what
// corner a needs: the cell's F for the centre term, the 4 corner Jacobians of the tets holding a
// (corners a, a^1, a^2, a^4) for the barrier. Called with a literal a (cell_forces unrolls its
// cells), so every index folds to a constant and the arrays stay registers. Edges are taken
// unscaled (h folds into the scalar factors).
vec3 cell_corner_force(vec3 y[8], int a) {
    vec3 f = vec3(0.0);
    float h = u_cell_h;
    vec3 s = cell_sign(a);
#ifdef CELL_CENTRE
#ifdef CELL_TERMS_CHECKED
    if (u_cell_kappa > 0.0)
#endif
    {
        // F = sum_c y_c (x) s_c / (4h): column k is the sum S_k of the cell's four edges along k
        // over 4h, J = det S / (4h)^3, cof F = cof S / (4h)^2
        vec3 f0 = (y[1] - y[0]) + (y[3] - y[2]) + (y[5] - y[4]) + (y[7] - y[6]);
        vec3 f1 = (y[2] - y[0]) + (y[3] - y[1]) + (y[6] - y[4]) + (y[7] - y[5]);
        vec3 f2 = (y[4] - y[0]) + (y[5] - y[1]) + (y[6] - y[2]) + (y[7] - y[3]);
        vec3 c0 = cross(f1, f2), c1 = cross(f2, f0), c2 = cross(f0, f1);
        float q = 4.0 * h;
        float j = dot(f0, c0) / (q * q * q);
        // -V kappa (J - 1) cof(F) G_a, G_a = s_a / (4h), V = h^3: -kappa (J - 1) h^3 / (4h)^3 cof S s_a
        float push = -u_cell_kappa * (j - 1.0) * (1.0 / 64.0);
        f += push * (s.x * c0 + s.y * c1 + s.z * c2);
    }
#endif
#ifdef CELL_BARRIER
#ifdef CELL_TERMS_CHECKED
    if (u_cell_barrier > 0.0)
#endif
    {
        // -V/8 kappa_b (J_c - J_b) d J_c / d x: with unscaled edges u_k = h e_k, d J_c / d u_k is
        // the cross product of the other two over h^3, and u_k moves by -s_c[k] with its far
        // node; the corner c itself gets minus the sum over k (volume.py volume_forces)
        float weight = 0.125 * u_cell_barrier;  // V/8 kappa_b / h^3 (V = h^3)
        float jb3 = u_cell_jb * h * h * h;
        // corner a's own tet: all three gradients
        vec3 e0 = y[a | 1] - y[a & 6], e1 = y[a | 2] - y[a & 5], e2 = y[a | 4] - y[a & 3];
        vec3 g0 = cross(e1, e2);
        f += cell_push(dot(e0, g0), weight, jb3) * (s.x * g0 + s.y * cross(e2, e0) + s.z * cross(e0, e1));
        // the tets of a's neighbours along x, y, z: one gradient each
        vec3 g;
        float det = cell_tet(y, a ^ 1, 0, g);
        f += (cell_push(det, weight, jb3) * s.x) * g;
        det = cell_tet(y, a ^ 2, 1, g);
        f += (cell_push(det, weight, jb3) * s.y) * g;
        det = cell_tet(y, a ^ 4, 2, g);
        f += (cell_push(det, weight, jb3) * s.z) * g;
    }
#endif
    return f;
}

// Incident cell Q (a literal) of the node: its corners from the neighbourhood, the node at corner 7 - Q.
#define CELL_NODE_TERM(Q) { vec3 y[8] = vec3[8](CELL_CORNER(p, Q, 0), CELL_CORNER(p, Q, 1), CELL_CORNER(p, Q, 2), CELL_CORNER(p, Q, 3), CELL_CORNER(p, Q, 4), CELL_CORNER(p, Q, 5), CELL_CORNER(p, Q, 6), CELL_CORNER(p, Q, 7)); vec3 t = cell_corner_force(y, 7 - (Q)); f += ((cells >> Q) & 1u) != 0u ? t : vec3(0.0); }

// The force of both terms on the node (N) from its full incident cells (bit q of `cells`),
// p its 3x3x3 neighbourhood (see the header; relative to the node for float32 precision).
// Unrolled over the 8 cells with literal indices: llvmpipe keeps a dynamically indexed local
// array in memory, which made the looped form 3.8x slower.
vec3 cell_forces(vec3 p[27], uint cells) {
    vec3 f = vec3(0.0);
    CELL_NODE_TERM(0)
    CELL_NODE_TERM(1)
    CELL_NODE_TERM(2)
    CELL_NODE_TERM(3)
    CELL_NODE_TERM(4)
    CELL_NODE_TERM(5)
    CELL_NODE_TERM(6)
    CELL_NODE_TERM(7)
    return f;
}

#endif
