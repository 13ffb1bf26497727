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
// TERMS: the system's further physics terms (deformgl/sim/terms; terms/active.glsl, composed by the
// host): each node's terms_force after the cells'; with TERMS_NEIGHBOURS, terms_begin before the
// neighbours and terms_neighbour(f, n, j, d) after each neighbour's spring, d = x_i - x_j.
// TERMS_HOOD (with HOOD_DIAGONALS): a term reads the node's 3x3x3 neighbourhood at the same
// evaluation state (lib/node_hood.glsl: the 18 neighbours the springs fetch are kept in node_hood);
// the terms' node bits are u_node's G bits 6-13 (lib/node_flags.glsl term_bits).

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
#ifdef TERMS_HOOD
// the positions of the 18 grid neighbours the springs fetch are kept, relative to the node, in
// their slots of its 3x3x3 neighbourhood node_hood (slot (dx + 1) + 3 (dy + 1) + 9 (dz + 1) of
// NEIGHBOUR_OFFSETS[j]); node_hood.glsl adds the body diagonals (HOOD_DIAGONALS)
vec3 node_hood[27];
#define HOOD_POSITION(T) EVAL_X(T)
#include "lib/node_hood.glsl"
#endif
#ifdef TERMS
// the system's further physics terms (deformgl/sim/terms: each a chunk; terms/active.glsl, composed
// by the host, calls them): their forces at the evaluation state
#define TERM_POSITION(T) EVAL_X(T)
#define TERM_VELOCITY(T) EVAL_V(T)
#include "terms/active.glsl"
#endif

// The spring of class cls to the neighbour at texel tj, d = x_i - x_j (lib/spring_force.glsl).
vec3 class_spring_force(vec3 d, ivec2 tj, vec3 vi, int cls) {
#ifdef SPRING_DAMPING
    return spring_force(d, u_rest[cls], u_k[cls], u_c[cls], vi - EVAL_V(tj));
#else
    return spring_force(d, u_rest[cls], u_k[cls], 0.0, vec3(0.0));
#endif
}

// Neighbour J (a literal) and its spring; unrolled with literal indices (llvmpipe keeps a
// dynamically indexed local array in memory). GRID_SPRING: the 18 grid neighbours (SLOT: their
// slot of node_hood, kept with TERMS_HOOD); GRID_FLEXION: the 6 flexion neighbours (with NB_COUNT 24).
// (each macro on one line: a backslash line continuation is GLSL 4.20, not 3.30 nor ES 3.00)
#ifdef DENSE
#define NB_OTHER(J) (((mask >> (J)) & 1) != 0 ? self_node + u_offsets[J] : self_node)
#else
#define NB_OTHER(J) nbl[(J) / 4][(J) % 4]
#endif
#ifdef SPRING_WEIGHTS
#define NB_SPRING(J, D, TJ) wl[(J) / 4][(J) % 4] * class_spring_force(D, TJ, vi, (J) < 6 ? 0 : ((J) < 18 ? 1 : 2))
#else
#define NB_SPRING(J, D, TJ) class_spring_force(D, TJ, vi, (J) < 6 ? 0 : ((J) < 18 ? 1 : 2))
#endif
#ifdef TERMS_HOOD
#define HOOD_KEEP(SLOT, D) node_hood[SLOT] = -(D);
#else
#define HOOD_KEEP(SLOT, D)
#endif
#ifdef TERMS_NEIGHBOURS
#define TERMS_NB(J, D) terms_neighbour(f, term_node, J, D);
#else
#define TERMS_NB(J, D)
#endif
#define GRID_SPRING(J, SLOT) { ivec2 tj = node_texel(NB_OTHER(J)); vec3 d = xi - EVAL_X(tj); HOOD_KEEP(SLOT, d) f += NB_SPRING(J, d, tj); TERMS_NB(J, d) }
#define GRID_FLEXION(J) { ivec2 tj = node_texel(NB_OTHER(J)); vec3 d = xi - EVAL_X(tj); f += NB_SPRING(J, d, tj); TERMS_NB(J, d) }

vec3 grid_acceleration(ivec2 texel, vec3 xi, vec3 vi, float m, int groups) {
    vec3 f = vec3(0.0);
#ifdef DENSE
    int self_node = texel_node(texel);
    int mask = int(texelFetch(u_node, texel, 0).a);
#else
    ivec4 nbl[NB_LAYERS];
    nbl[0] = texelFetch(u_neighbours, ivec3(texel, 0), 0);
    nbl[1] = texelFetch(u_neighbours, ivec3(texel, 1), 0);
    nbl[2] = texelFetch(u_neighbours, ivec3(texel, 2), 0);
    nbl[3] = texelFetch(u_neighbours, ivec3(texel, 3), 0);
    nbl[4] = texelFetch(u_neighbours, ivec3(texel, 4), 0);
#if NB_LAYERS > 5
    nbl[5] = texelFetch(u_neighbours, ivec3(texel, 5), 0);
#endif
#endif
#ifdef SPRING_WEIGHTS
    vec4 wl[NB_LAYERS];
    wl[0] = texelFetch(u_weights, ivec3(texel, 0), 0);
    wl[1] = texelFetch(u_weights, ivec3(texel, 1), 0);
    wl[2] = texelFetch(u_weights, ivec3(texel, 2), 0);
    wl[3] = texelFetch(u_weights, ivec3(texel, 3), 0);
    wl[4] = texelFetch(u_weights, ivec3(texel, 4), 0);
#if NB_LAYERS > 5
    wl[5] = texelFetch(u_weights, ivec3(texel, 5), 0);
#endif
#endif
#ifdef TERMS
    TermNode term_node = TermNode(ivec3(texel, 0), xi, vi, m, term_bits(int(texelFetch(u_node, texel, 0).g)), 1.0);
#ifdef TERMS_NEIGHBOURS
    terms_begin(term_node);
#endif
#endif
    // the 18 of deformgl/grid/nodes.py NEIGHBOUR_OFFSETS; slot (dx + 1) + 3 (dy + 1) + 9 (dz + 1)
    GRID_SPRING(0, 14)
    GRID_SPRING(1, 12)
    GRID_SPRING(2, 16)
    GRID_SPRING(3, 10)
    GRID_SPRING(4, 22)
    GRID_SPRING(5, 4)
    GRID_SPRING(6, 17)
    GRID_SPRING(7, 11)
    GRID_SPRING(8, 15)
    GRID_SPRING(9, 9)
    GRID_SPRING(10, 23)
    GRID_SPRING(11, 5)
    GRID_SPRING(12, 21)
    GRID_SPRING(13, 3)
    GRID_SPRING(14, 25)
    GRID_SPRING(15, 7)
    GRID_SPRING(16, 19)
    GRID_SPRING(17, 1)
#if NB_COUNT > 18
    GRID_FLEXION(18)
    GRID_FLEXION(19)
    GRID_FLEXION(20)
    GRID_FLEXION(21)
    GRID_FLEXION(22)
    GRID_FLEXION(23)
#endif
#ifdef TERMS_HOOD
    hood_diagonals(texel, xi);
#endif
#ifdef TERMS
    terms_force(f, term_node);
#endif
    add_node_forces(f, texel_node(texel), groups, xi, vi, m);
    return f / m;
}
