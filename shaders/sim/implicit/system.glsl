// The backward-Euler system of one grid node, matrix-free (docs/EQUATIONS.md "Implicit Euler";
// the float64 reference is deformgl/sim/implicit.py):
//   A = M + dt C + dt^2 H,  H = -df/dx (projected geometric term; TERMS: + the physics
//   terms' share, the cells' Gauss-Newton block among them),  C = -df/dv.
// Per spring (i, j) at the step's start positions, d = x_i - x_j, u = d/|d|, weight w_j (the
// calibrated lattice's SPRING_WEIGHTS), class stiffness k, rest L, spring damping c:
//   H_s = w k (u u^T + max(0, 1 - L/|d|) (I - u u^T)),  C_s = w c u u^T.
// The neighbours come from u_neighbours (NB_LAYERS RGBA32I layers, an absent one is the node
// itself: d = 0 gives u = 0, g = 0 and no term), as sim/integrators/forces.glsl.
// Every CG vector is 0 at fixed nodes and padding texels, so the rows and columns of the fixed
// nodes drop out (the solve is over the free nodes).
// NB_LAYERS and NB_COUNT as sim/integrators/forces.glsl (default 5 and 18).
// TERMS (with TERMS_IMPLICIT): the system's physics terms add dt^2 K y (terms_product, terms/active.glsl, which forces.glsl includes), those
// that read the grid neighbours (TERMS_NEIGHBOURS) with the springs' sums.
#include "lib/neighbour_count.glsl"
uniform sampler2D u_vec;    // the vector y multiplied (xyz), sampled at the neighbours
#ifdef TERMS
vec3 term_vector(int node) {  // (lib/term_node.glsl: y at another node, for the terms' products)
    return texelFetch(u_vec, node_texel(node), 0).xyz;
}
#endif
#ifdef TERMS_HOOD
// The node's 3x3x3 neighbourhood for the terms that read it (lib/term_node.glsl): s at the 27 nodes
// of u_hood_nodes (lib/node_hood.glsl) minus `origin`, each slot a literal (llvmpipe keeps a
// dynamically indexed local array in memory).
#define HOOD_FETCH(V, S, O, K) V[K] = texelFetch(S, node_texel(hood[(K) / 4][(K) % 4]), 0).xyz - O;
void hood_gather(ivec2 texel, sampler2D s, vec3 origin, out vec3 v[27]) {
    ivec4 hood[7];
    for (int layer = 0; layer < 7; ++layer) {
        hood[layer] = texelFetch(u_hood_nodes, ivec3(texel, layer), 0);
    }
    HOOD_FETCH(v, s, origin, 0) HOOD_FETCH(v, s, origin, 1) HOOD_FETCH(v, s, origin, 2)
    HOOD_FETCH(v, s, origin, 3) HOOD_FETCH(v, s, origin, 4) HOOD_FETCH(v, s, origin, 5)
    HOOD_FETCH(v, s, origin, 6) HOOD_FETCH(v, s, origin, 7) HOOD_FETCH(v, s, origin, 8)
    HOOD_FETCH(v, s, origin, 9) HOOD_FETCH(v, s, origin, 10) HOOD_FETCH(v, s, origin, 11)
    HOOD_FETCH(v, s, origin, 12) HOOD_FETCH(v, s, origin, 13) HOOD_FETCH(v, s, origin, 14)
    HOOD_FETCH(v, s, origin, 15) HOOD_FETCH(v, s, origin, 16) HOOD_FETCH(v, s, origin, 17)
    HOOD_FETCH(v, s, origin, 18) HOOD_FETCH(v, s, origin, 19) HOOD_FETCH(v, s, origin, 20)
    HOOD_FETCH(v, s, origin, 21) HOOD_FETCH(v, s, origin, 22) HOOD_FETCH(v, s, origin, 23)
    HOOD_FETCH(v, s, origin, 24) HOOD_FETCH(v, s, origin, 25) HOOD_FETCH(v, s, origin, 26)
}
void hood_positions(TermNode n, out vec3 p[27]) {
    hood_gather(n.at.xy, u_x, n.x, p);
}
void hood_vector(TermNode n, out vec3 y[27]) {
    hood_gather(n.at.xy, u_vec, vec3(0.0), y);
}
#endif

// Sums over the node's springs: sk = sum H_s (y_i - y_j), sc = sum C_s (y_i - y_j), the
// diagonals dk = sum diag(H_s), dc = sum diag(C_s) and the off-diagonals (xy, xz, yz) of the
// node's 3x3 block, ok of sum H_s and oc of sum C_s (the block-Jacobi preconditioner's; the
// passes that do not use them leave them to the compiler to drop).
void spring_sums(ivec2 texel, vec3 xi, vec3 yi, float m, out vec3 sk, out vec3 sc, out vec3 dk, out vec3 dc,
                 out vec3 ok, out vec3 oc) {
    sk = vec3(0.0); sc = vec3(0.0); dk = vec3(0.0); dc = vec3(0.0); ok = vec3(0.0); oc = vec3(0.0);
#ifdef TERMS_NEIGHBOURS
    TermNode term_node = TermNode(ivec3(texel, 0), xi, vec3(0.0), m, 0u, 1.0);
    terms_begin(term_node);
#endif
    for (int layer = 0; layer < NB_LAYERS; ++layer) {
        ivec4 nb = texelFetch(u_neighbours, ivec3(texel, layer), 0);
#ifdef SPRING_WEIGHTS
        vec4 w = texelFetch(u_weights, ivec3(texel, layer), 0);
#else
        vec4 w = vec4(1.0);
#endif
        for (int c = 0; c < 4; ++c) {
            int j = 4 * layer + c;
            if (j >= NB_COUNT) {
                break;
            }
            int cls = j < 6 ? 0 : (j < 18 ? 1 : 2);
            ivec2 tj = node_texel(nb[c]);
            vec3 d = xi - texelFetch(u_x, tj, 0).xyz;
            float len = length(d);
            vec3 u = len > 0.0 ? d / len : vec3(0.0);
            float g = len > 0.0 ? max(0.0, 1.0 - u_rest[cls] / len) : 0.0;
            float k = w[c] * u_k[cls];
            vec3 dy = yi - texelFetch(u_vec, tj, 0).xyz;
            float along = dot(u, dy);
            sk += k * (along * u + g * (dy - along * u));
            dk += k * (u * u + g * (vec3(1.0) - u * u));
            vec3 uu = u.xxy * u.yzz;   // u_x u_y, u_x u_z, u_y u_z
            ok += k * (1.0 - g) * uu;
#ifdef TERMS_NEIGHBOURS
            terms_neighbour_product(sk, dk, term_node, j, dy);
#endif
#ifdef SPRING_DAMPING
            float cs = w[c] * u_c[cls];
            sc += cs * along * u;
            dc += cs * u * u;
            oc += cs * uu;
#endif
        }
    }
}

// Per-node terms: damping c + alpha m (+ wind drag) and the drags' stiffness at this node.
float node_damping(float m) {
    float c = u_velocity_damping + u_mass_damping * m;
#ifdef WIND
    c += u_wind_drag;
#endif
    return c;
}

float node_drag_stiffness(int node) {
    float k = 0.0;
#if DRAGS > 0
    for (int i = 0; i < DRAGS; ++i) {
        if (u_drag_node[i] == node) {
            k += u_drag_k[i];
        }
    }
#endif
    return k;
}

// A y at this node (y_i = yi).
vec3 apply_system(ivec2 texel, vec3 xi, vec3 yi, float m) {
    vec3 sk, sc, dk, dc, ok, oc;
    spring_sums(texel, xi, yi, m, sk, sc, dk, dc, ok, oc);
    float dt = u_dt;
    float own = m + dt * node_damping(m) + dt * dt * node_drag_stiffness(texel_node(texel));
    vec3 q = own * yi + (dt * dt) * sk + dt * sc;
#ifdef TERMS
    vec3 kq = vec3(0.0);  // the physics terms' K y at this node (terms/active.glsl)
#if defined(TERMS_HELD) && !defined(SETUP)
    float held = texelFetch(u_b, texel, 0).w;   // (SETUP's flag)
#else
    float held = 1.0;
#endif
    terms_product(kq, TermNode(ivec3(texel, 0), xi, vec3(0.0), m, term_bits(int(texelFetch(u_node, texel, 0).g)), held), yi);
    q += (dt * dt) * kq;
#endif
    return q;
}

// P^-1 r at this node: the Jacobi inverse diagonal (inv.xyz), or with PRECOND_BLOCK the
// symmetric inverse of the node's 3x3 block, diagonal inv.xyz and off-diagonal off.xyz (xy, xz, yz).
#ifdef PRECOND_BLOCK
vec3 apply_preconditioner(vec3 inv, vec3 off, vec3 r) {
    return vec3(inv.x * r.x + off.x * r.y + off.y * r.z,
                off.x * r.x + inv.y * r.y + off.z * r.z,
                off.y * r.x + off.z * r.y + inv.z * r.z);
}
#endif
