// The backward-Euler system of one grid node, matrix-free (docs/EQUATIONS.md "Implicit Euler";
// the float64 reference is deformgl/sim/implicit.py):
//   A = M + dt C + dt^2 H,  H = -df/dx (projected geometric term; IMPLICIT_CELLS: + the
//   cells' Gauss-Newton block),  C = -df/dv.
// Per spring (i, j) at the step's start positions, d = x_i - x_j, u = d/|d|, weight w_j (the
// calibrated lattice's SPRING_WEIGHTS), class stiffness k, rest L, spring damping c:
//   H_s = w k (u u^T + max(0, 1 - L/|d|) (I - u u^T)),  C_s = w c u u^T.
// The neighbours come from u_neighbours (NB_LAYERS RGBA32I layers, an absent one is the node
// itself: d = 0 gives u = 0, g = 0 and no term), as sim/integrators/forces.glsl.
// Every CG vector is 0 at fixed nodes and padding texels, so the rows and columns of the fixed
// nodes drop out (the solve is over the free nodes).
// NB_LAYERS and NB_COUNT as sim/integrators/forces.glsl (default 5 and 18).
// IMPLICIT_CELLS: the full cells' volumetric term and corner barriers add their (Gauss-Newton)
// block, dt^2 H_cells (sim/implicit/cells.glsl). TERMS (with TERMS_IMPLICIT): the system's further
// physics terms add dt^2 K y (terms_product, terms/active.glsl, which forces.glsl includes), those
// that read the grid neighbours (TERMS_NEIGHBOURS) with the springs' sums.
#include "lib/neighbour_count.glsl"
uniform sampler2D u_vec;    // the vector y multiplied (xyz), sampled at the neighbours
#ifdef TERMS
vec3 term_vector(int node) {  // (lib/term_node.glsl: y at another node, for the terms' products)
    return texelFetch(u_vec, node_texel(node), 0).xyz;
}
#endif
#ifdef IMPLICIT_CELLS
#include "sim/implicit/cells.glsl"
#endif

// Sums over the node's springs: sk = sum H_s (y_i - y_j), sc = sum C_s (y_i - y_j), the
// diagonals dk = sum diag(H_s), dc = sum diag(C_s) and the off-diagonals (xy, xz, yz) of the
// node's 3x3 block, ok of sum H_s and oc of sum C_s (the block-Jacobi preconditioner's; the
// passes that do not use them leave them to the compiler to drop).
void spring_sums(ivec2 texel, vec3 xi, vec3 yi, float m, out vec3 sk, out vec3 sc, out vec3 dk, out vec3 dc,
                 out vec3 ok, out vec3 oc) {
    sk = vec3(0.0); sc = vec3(0.0); dk = vec3(0.0); dc = vec3(0.0); ok = vec3(0.0); oc = vec3(0.0);
#ifdef TERMS_NEIGHBOURS
    TermNode term_node = TermNode(ivec3(texel, 0), xi, vec3(0.0), m);
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
#ifdef IMPLICIT_CELLS
    q += (dt * dt) * cells_times(texel, xi, u_vec);
#endif
#ifdef TERMS
    vec3 kq = vec3(0.0);  // the physics terms' K y at this node (terms/active.glsl)
    terms_product(kq, TermNode(ivec3(texel, 0), xi, vec3(0.0), m), yi);
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
