// The cells' XPBD constraints in the node sweep (the term's XPBD chunk, deformgl/sim/terms/volume/xpbd_form.py
// XPBD; compiled with TERM_CELL through terms/xpbd.glsl into sim/xpbd/iterate.frag): each node
// gathers the corrections w_i grad_i C d_lambda of the constraints of its full incident cells
// (terms/cell_constraints.glsl), whose d_lambda the cell pass (terms/cell_xpbd.frag) computed from
// the same iterate, and counts its active barriers after this sweep. The node's incident cells are
// its term bits (lib/node_flags.glsl term_bits, 1 << q: cell q).
#include "terms/cell_constraints.glsl"
uniform isampler2DArray u_cell_nodes;   // 7 RGBA32I layers: the 3x3x3 neighbourhood, slot 4 l + c
uniform sampler2D u_cell_state;         // this sweep's, at a cell's owner: G volume d_lambda, B active-barrier mask, A changed
uniform sampler2D u_cell_delta0;        // this sweep's barrier d_lambda of corners 0..3
uniform sampler2D u_cell_delta1;        // 4..7

// The owner texels of the node's 8 incident cells: cell q's corner 0 is neighbourhood slot
// qx + 3 qy + 9 qz (0, 1, 3, 4, 9, 10, 12, 13: layers 0..3 of u_cell_nodes).
void cell_owners(ivec2 texel, out ivec2 owner[8]) {
    ivec4 l0 = texelFetch(u_cell_nodes, ivec3(texel, 0), 0);
    ivec4 l1 = texelFetch(u_cell_nodes, ivec3(texel, 1), 0);
    ivec4 l2 = texelFetch(u_cell_nodes, ivec3(texel, 2), 0);
    ivec4 l3 = texelFetch(u_cell_nodes, ivec3(texel, 3), 0);
    owner[0] = node_texel(l0.x);
    owner[1] = node_texel(l0.y);
    owner[2] = node_texel(l0.w);
    owner[3] = node_texel(l1.x);
    owner[4] = node_texel(l2.y);
    owner[5] = node_texel(l2.z);
    owner[6] = node_texel(l3.x);
    owner[7] = node_texel(l3.y);
}

// The correction of the constraints of incident cell q (the node is its corner 7 - q) on the
// node, from this sweep's multiplier changes at the cell's owner.
vec3 cell_correction(vec3 p[27], int q, ivec2 owner, float wi) {
    int a = 7 - q;
    vec3 dx = vec3(0.0);
#ifdef CELL_VOLUME
    float d_v = texelFetch(u_cell_state, owner, 0).g;
    if (d_v != 0.0) {
        mat3 cof;
        centre_jacobian(p, q, cof);
        dx += (wi * d_v) * centre_gradient(cof, a);
    }
#endif
#ifdef CELL_BARRIER
    vec4 d0 = texelFetch(u_cell_delta0, owner, 0);
    vec4 d1 = texelFetch(u_cell_delta1, owner, 0);
    float d[8] = float[8](d0.x, d0.y, d0.z, d0.w, d1.x, d1.y, d1.z, d1.w);
    for (int t = 0; t < 4; ++t) {
        int c = t == 0 ? a : a ^ (1 << (t - 1));  // the tets of corners a, a^1, a^2, a^4 hold the node
        if (d[c] != 0.0) {
            mat3 dj;
            corner_gradients(p, q, c, dj);
            dx += (wi * d[c]) * tet_gradient(dj, c, a);
        }
    }
#endif
    return dx;
}

// The corrections of the constraints of the node's full incident cells (bit q of `cells`) on the
// node, at neighbourhood slot 13; `barriers` receives its active barriers after this sweep. The
// 27 positions are fetched only when a multiplier of one of the cells changed in this sweep
// (state A), and each cell's gather is written out with a constant q (CELL_GATHER), so that every
// position index is a constant.
vec3 cell_corrections(ivec2 texel, uint cells, float wi, out float barriers) {
    ivec2 owner[8];
    cell_owners(texel, owner);
    barriers = 0.0;
    bool changed = false;
    for (int q = 0; q < 8; ++q) {
        if (((cells >> uint(q)) & 1u) != 0u) {
            vec4 state = texelFetch(u_cell_state, owner[q], 0);
            changed = changed || state.a != 0.0;
            int mask = int(state.b);
            int a = 7 - q;  // the node's corner: in the tets of corners a, a^1, a^2, a^4
            barriers += float(((mask >> a) & 1) + ((mask >> (a ^ 1)) & 1) + ((mask >> (a ^ 2)) & 1)
                              + ((mask >> (a ^ 4)) & 1));
        }
    }
    vec3 dx = vec3(0.0);
    if (!changed) {
        return dx;
    }
    vec3 p[27];
    for (int layer = 0; layer < 7; ++layer) {
        ivec4 nb = texelFetch(u_cell_nodes, ivec3(texel, layer), 0);
        for (int c = 0; c < 4; ++c) {
            if (4 * layer + c < 27) {
                p[4 * layer + c] = texelFetch(u_p, node_texel(nb[c]), 0).xyz;
            }
        }
    }
#define CELL_GATHER(Q) if (((cells >> uint(Q)) & 1u) != 0u) { dx += cell_correction(p, Q, owner[Q], wi); }
    CELL_GATHER(0)
    CELL_GATHER(1)
    CELL_GATHER(2)
    CELL_GATHER(3)
    CELL_GATHER(4)
    CELL_GATHER(5)
    CELL_GATHER(6)
    CELL_GATHER(7)
#undef CELL_GATHER
    return dx;
}

// The node's corrections from its cells' constraints and its active barriers (added to counts).
void cell_xpbd(inout vec3 dx, inout float counts, ivec2 texel, int flags, float wi) {
    uint cells = term_bits(flags);
    if (cells != 0u) {
        float barriers;
        dx += cell_corrections(texel, cells, wi, barriers);
        counts += barriers;
    }
}
