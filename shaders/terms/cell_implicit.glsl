// The cells' part of the backward-Euler system of one node (terms/cell.glsl with TERMS_IMPLICIT),
// matrix-free, gathered from the node's (up to 8) full incident cells: the float32 twin of
// deformgl/sim/terms/volume/hessian.py cell_product (the Gauss-Newton part of the Hessian; why, and the
// derivation: that module's docstring). Each term is w/2 (J - J0)^2 of a determinant J over nodes
// t; with g_t = dJ/dx_t its Gauss-Newton block is w g_t g_u^T, so
//   (H y)_a = sum over the node's terms of w (sum_t g_t . y_t) g_a:
//   CELL_CENTRE, the centre term of a cell: J = det F, F = S / (4h) with S's column k the sum of
//     the cell's 4 edges along +k, g_t = cof(F) s_t / (4h), w = V kappa, and
//     sum_t g_t . y_t = cof(S) : dS / (4h)^3, dS the same edge sums of y;
//   CELL_BARRIER, the barrier of corner c where J_c < J_b: J_c = det [e_0 e_1 e_2] / h^3, e_k the
//     tet's edge along +k (tet_edges below), w = V/8 kappa_b, the node at the
//     edge's end of bit k set gets + (e_{k+1} x e_{k+2}) / h^3, the other one minus that, so
//     sum_t g_t . y_t = sum_k (e_{k+1} x e_{k+2}) . de_k / h^3, de_k the same edge of y;
// and the node's own 3x3 block sum w g_a g_a^T (the preconditioners': diagonal xx yy zz,
// off-diagonal xy xz yz). The host defines CELL_CENTRE where kappa > 0 (what terms/cell_forces.glsl
// compiles too): llvmpipe runs a uniform branch's body anyway, so a term that is zero is not compiled.
//
// The node's 3x3x3 neighbourhood comes from the pass (lib/term_node.glsl hood_positions,
// hood_vector), relative to the node (J, F and the edges only take differences), which keeps float32
// rounding at the scale of h. Every index is a literal (the 8 cells and 27 slots unrolled by
// macros): llvmpipe keeps a dynamically indexed local array in memory.
//
// cell_diagonal finds whether any barrier term holds the node (`held`, which the step's first pass
// stores); cell_product, in the later passes, skips the barriers of the other nodes (and, without
// CELL_CENTRE, the whole gather).

// Adds w (g . y) g_a to hy and w g_a g_a^T to the block (diag, off).
void cell_term(float w, float gy, vec3 ga, inout vec3 hy, inout vec3 diag, inout vec3 off) {
    hy += (w * gy) * ga;
    diag += w * ga * ga;
    off += w * (ga.xxy * ga.yzz);
}

// The edges e_k of the tet of corner c of a cell (y: its 8 corners; terms/cell_forces.glsl
// cell_tet's, all three) and its unscaled determinant h^3 J_c = det [e_0 e_1 e_2].
float tet_edges(vec3 y[8], int c, out vec3 e0, out vec3 e1, out vec3 e2) {
    e0 = y[c | 1] - y[c & 6];
    e1 = y[c | 2] - y[c & 5];
    e2 = y[c | 4] - y[c & 3];
    return dot(e0, cross(e1, e2));
}

// The barrier of the tet of corner c on its node at corner a (a == c or a = c ^ 2^k; literals),
// x and y the cell's 8 corners. Returns whether it is held (J_c < J_b).
bool barrier_corner(vec3 x[8], vec3 y[8], int c, int a, inout vec3 hy, inout vec3 diag, inout vec3 off) {
    vec3 e0, e1, e2;
    float h3 = u_cell_h * u_cell_h * u_cell_h;
    float det = tet_edges(x, c, e0, e1, e2);
    if (det >= u_cell_jb * h3) {
        return false;
    }
    vec3 g0 = cross(e1, e2), g1 = cross(e2, e0), g2 = cross(e0, e1);
    vec3 d0, d1, d2;
    tet_edges(y, c, d0, d1, d2);
    float gy = (dot(g0, d0) + dot(g1, d1) + dot(g2, d2)) / h3;
    vec3 s = cell_sign(a);
    vec3 ga = (a == c ? s.x * g0 + s.y * g1 + s.z * g2
               : (a == (c ^ 1) ? s.x * g0 : (a == (c ^ 2) ? s.y * g1 : s.z * g2))) / h3;
    cell_term(h3 * 0.125 * u_cell_barrier, gy, ga, hy, diag, off);
    return true;
}

// The centre term of one cell (x, y: its 8 corners) on its corner a (a literal).
void centre_corner(vec3 x[8], vec3 y[8], int a, inout vec3 hy, inout vec3 diag, inout vec3 off) {
    vec3 f0 = (x[1] - x[0]) + (x[3] - x[2]) + (x[5] - x[4]) + (x[7] - x[6]);
    vec3 f1 = (x[2] - x[0]) + (x[3] - x[1]) + (x[6] - x[4]) + (x[7] - x[5]);
    vec3 f2 = (x[4] - x[0]) + (x[5] - x[1]) + (x[6] - x[2]) + (x[7] - x[3]);
    vec3 d0 = (y[1] - y[0]) + (y[3] - y[2]) + (y[5] - y[4]) + (y[7] - y[6]);
    vec3 d1 = (y[2] - y[0]) + (y[3] - y[1]) + (y[6] - y[4]) + (y[7] - y[5]);
    vec3 d2 = (y[4] - y[0]) + (y[5] - y[1]) + (y[6] - y[2]) + (y[7] - y[3]);
    vec3 c0 = cross(f1, f2), c1 = cross(f2, f0), c2 = cross(f0, f1);
    float q3 = 64.0 * u_cell_h * u_cell_h * u_cell_h;   // (4h)^3
    float gy = (dot(c0, d0) + dot(c1, d1) + dot(c2, d2)) / q3;
    vec3 s = cell_sign(a);
    cell_term(q3 * (1.0 / 64.0) * u_cell_kappa, gy, (s.x * c0 + s.y * c1 + s.z * c2) / q3, hy, diag, off);
}

// The barriers of the 4 tets of one cell that hold its corner a (a literal); whether one is active.
bool barrier_corners(vec3 x[8], vec3 y[8], int a, inout vec3 hy, inout vec3 diag, inout vec3 off) {
    bool held = barrier_corner(x, y, a, a, hy, diag, off);
    held = barrier_corner(x, y, a ^ 1, a, hy, diag, off) || held;
    held = barrier_corner(x, y, a ^ 2, a, hy, diag, off) || held;
    return barrier_corner(x, y, a ^ 4, a, hy, diag, off) || held;
}

#define CELL_EIGHT(P, Q) vec3[8](CELL_CORNER(P, Q, 0), CELL_CORNER(P, Q, 1), CELL_CORNER(P, Q, 2), CELL_CORNER(P, Q, 3), CELL_CORNER(P, Q, 4), CELL_CORNER(P, Q, 5), CELL_CORNER(P, Q, 6), CELL_CORNER(P, Q, 7))
#define CELL_CENTRE_TERM(Q) if (((cells >> (Q)) & 1u) != 0u) { vec3 xq[8] = CELL_EIGHT(p, Q); vec3 yq[8] = CELL_EIGHT(y, Q); centre_corner(xq, yq, 7 - (Q), hy, diag, off); }
#define CELL_BARRIER_TERM(Q) if (((cells >> (Q)) & 1u) != 0u) { vec3 xq[8] = CELL_EIGHT(p, Q); vec3 yq[8] = CELL_EIGHT(y, Q); held = barrier_corners(xq, yq, 7 - (Q), hy, diag, off) || held; }

// H_cells y at the node (p: positions, y: the vector, both the 27 of the neighbourhood), the
// node's 3x3 block of H_cells, and whether a barrier term holds the node; `barrier` false skips
// the barriers (a node none of whose barrier terms is active). The barriers sit in a loop run
// once or never rather than in an if: llvmpipe runs an if's body for every fragment, but leaves
// a loop that no fragment of the group still runs.
vec3 cell_hessian(vec3 p[27], vec3 y[27], uint cells, bool barrier, out vec3 diag, out vec3 off,
                  out bool held) {
    vec3 hy = vec3(0.0);
    diag = vec3(0.0);
    off = vec3(0.0);
    held = false;
#ifdef CELL_CENTRE
    CELL_CENTRE_TERM(0) CELL_CENTRE_TERM(1) CELL_CENTRE_TERM(2) CELL_CENTRE_TERM(3)
    CELL_CENTRE_TERM(4) CELL_CENTRE_TERM(5) CELL_CENTRE_TERM(6) CELL_CENTRE_TERM(7)
#endif
#ifdef CELL_BARRIER
    for (int once = barrier ? 0 : 1; once < 1; ++once) {
        CELL_BARRIER_TERM(0) CELL_BARRIER_TERM(1) CELL_BARRIER_TERM(2) CELL_BARRIER_TERM(3)
        CELL_BARRIER_TERM(4) CELL_BARRIER_TERM(5) CELL_BARRIER_TERM(6) CELL_BARRIER_TERM(7)
    }
#endif
    return hy;
}

// (H_cells y)_n added to q: the product passes (n.held: SETUP's flag; 1 in SETUP itself).
void cell_product(inout vec3 q, TermNode n, vec3 y) {
    bool barrier = n.held > 0.5;
    vec3 hy = vec3(0.0);
    vec3 diag, off;
    bool held;
#ifdef CELL_CENTRE
    vec3 p[27], yv[27];
    hood_positions(n, p);
    hood_vector(n, yv);
    hy = cell_hessian(p, yv, n.bits, barrier, diag, off, held);
#else
    for (int once = barrier ? 0 : 1; once < 1; ++once) {   // (the gathers too: see cell_hessian)
        vec3 p[27], yv[27];
        hood_positions(n, p);
        hood_vector(n, yv);
        hy = cell_hessian(p, yv, n.bits, true, diag, off, held);
    }
#endif
    q += hy;
}

// The node's 3x3 block of H_cells added to (d, off), and whether a barrier term holds it.
void cell_diagonal(inout vec3 d, inout vec3 off, inout float held, TermNode n) {
    vec3 p[27], zero[27];
    hood_positions(n, p);
    for (int slot = 0; slot < 27; ++slot) {
        zero[slot] = vec3(0.0);
    }
    vec3 dk, ok;
    bool h;
    cell_hessian(p, zero, n.bits, true, dk, ok, h);
    d += dk;
    off += ok;
    held = h ? 1.0 : held;
}
