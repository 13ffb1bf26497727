// A sheet's bending (deformgl/sim/terms/bending.py SheetBending; docs/EQUATIONS.md "Cloth bending"): the
// discrete plate energy E = 1/2 sum_c x_c^T B x_c (Bergou et al. 2006), f = -B x, read through the
// 24 grid neighbours (the 18 of NEIGHBOUR_OFFSETS, then the 6 at 2h along the axes; NB_LAYERS 6):
//   f_n -= c_j (x_n - x_j),   c_j = -B[n, j]   (rows of B sum to 0; an absent neighbour is the
//   node itself, d = 0),
// and implicit Euler's (B y)_n = sum_j c_j (y_n - y_j), its diagonal sum_j c_j.
// Table u_bending_c: NB_LAYERS RGBA32F layers per node, c_j in channel j % 4 of layer j / 4
// (SheetBending.neighbour_coefficients; 0 where B does not couple the two).
uniform sampler2DArray u_bending_c;
vec4 bending_c[6];  // the node's coefficients, fetched once (bending_begin)

void bending_begin(TermNode n) {
    bending_c[0] = term_table(u_bending_c, NB_LAYERS, 0, n);
    bending_c[1] = term_table(u_bending_c, NB_LAYERS, 1, n);
    bending_c[2] = term_table(u_bending_c, NB_LAYERS, 2, n);
    bending_c[3] = term_table(u_bending_c, NB_LAYERS, 3, n);
    bending_c[4] = term_table(u_bending_c, NB_LAYERS, 4, n);
    bending_c[5] = term_table(u_bending_c, NB_LAYERS, 5, n);
}

void bending_neighbour(inout vec3 f, TermNode n, int j, vec3 d) {
    f -= bending_c[j / 4][j % 4] * d;
}

void bending_force(inout vec3 f, TermNode n) {
}

void bending_neighbour_product(inout vec3 sk, inout vec3 dk, TermNode n, int j, vec3 dy) {
    float c = bending_c[j / 4][j % 4];
    sk += c * dy;
    dk += vec3(c);
}

void bending_product(inout vec3 q, TermNode n, vec3 y) {
}

void bending_diagonal(inout vec3 d, inout vec3 off, inout float held, TermNode n) {
}
