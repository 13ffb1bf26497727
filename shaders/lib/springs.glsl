// Spring forces and approximate normals over the 18 implicit neighbours
// (Mosegaard & Sorensen 2005, section 3.1).
//
// Mosegaard & Sorensen 2005, eq. 1: g_i = sum_j 1/2 k_ij (l_ij - |p_i - p_j|) (p_i - p_j)/|p_i - p_j|, with deformgl's
// k = k_ij / 2 in N/m. Grouping the 6 springs of rest length h (D1) and the 12 of h*sqrt(2) (D2),
// each group with one stiffness, gives Mosegaard & Sorensen 2005, eq. 2:
//   g_i = k1 (h S1 - P1) + k2 (sqrt(2) h S2 - P2),
//   S = sum of unit vectors (p_i - p_j)/|p_i - p_j|, P = sum of (p_i - p_j).
// S1 + S2 is the unnormalised approximate normal of Mosegaard & Sorensen 2005, eq. 3.
// Neighbour j exists when bit j of the node's mask is set; offsets in the order of
// deformgl/grid/nodes.py NEIGHBOUR_OFFSETS. The sum is branchless: an absent neighbour (the node
// itself in COMPACT layouts, its own position in BLOCKED ones: a finite position) is weighted by 0.

#include "lib/node_texel.glsl"

uniform float u_spacing;        // h
uniform float u_k_structural;   // k1, N/m
uniform float u_k_shear;        // k2, N/m

struct SpringSum {
    vec3 force;     // g_i (Mosegaard & Sorensen 2005, eq. 1/2)
    vec3 unit_sum;  // S1 + S2 (Mosegaard & Sorensen 2005, eq. 3 before normalisation)
};

// Where neighbour J lies: COMPACT layouts look its node number up in the neighbour-index
// texture (deformgl/grid/nodes.py CompactLayout); COMPACT_DENSE ones (every node of the box exists) compute it,
// n + DX sx + DY sy + DZ sz, or take the node itself where mask bit J says the neighbour is
// absent (as the index texture does: d = 0, so not even a NaN elsewhere can leak in).
// BLOCKED layouts read the block's fetched neighbourhood instead (below); there is no other layout.
#if !defined(COMPACT) && !defined(BLOCKED)
#error "lib/springs.glsl needs a node layout: COMPACT (deformgl/grid/nodes.py CompactLayout) or BLOCKED"
#endif
#ifdef COMPACT
#ifdef COMPACT_DENSE
uniform ivec3 u_strides;               // node-number step of +1 along x, y, z
// (each macro on one line: a backslash line continuation is GLSL 4.20, not 3.30 nor ES 3.00)
#define NB_TEXEL(J, DX, DY, DZ) node_texel(((mask >> J) & 1u) != 0u ? self_node + DX * u_strides.x + DY * u_strides.y + DZ * u_strides.z : self_node)
#else
uniform isampler2DArray u_neighbours;  // 5 layers RGBA32I: node numbers of neighbours 0..17
#define NB_TEXEL(J, DX, DY, DZ) node_texel(nb[J])
#endif
#endif

// The position of neighbour J. BLOCKED layouts (deformgl/grid/blocks.py BlockedLayout: one
// fragment owns a block of nodes): hood_position(c), defined by the pass, returns the node at
// block-local grid position c from the state texture of its member; where mask bit J says the
// neighbour is absent the node's own position p stands in (d = 0, as the compact layouts' self
// index), so the sums are bit for bit those of the one-node layouts. The pass fetched the block's
// neighbourhood once, before the members' sums (sim/verlet_block.frag fill_hood).
#ifdef BLOCKED
#define NB_POSITION(J, DX, DY, DZ) (((mask >> J) & 1u) != 0u ? hood_position(local + ivec3(DX, DY, DZ)) : p)
#else
#define NB_POSITION(J, DX, DY, DZ) texelFetch(positions, NB_TEXEL(J, DX, DY, DZ), 0).xyz
#endif

// SPRING_WEIGHTS (the calibrated lattice of deformgl/sim/materials.py): spring J's stiffness is
// its class's times wt[J] (u_weights: 5 layers RGBA32F, 4 neighbours per layer in neighbour
// order, 0 where absent), so S and P are weighted sums; the Mosegaard & Sorensen 2005, eq. 3 normal stays the unweighted
// sum of unit vectors over the existing neighbours (U). SPRING_WEIGHT_LEVELS (with SPRING_WEIGHTS):
// the weights are the lattice's cell shares, decoded from the levels code in the node texture's
// alpha (node_flags.glsl) instead of fetched: edge J < 6 weighs (bits 2J..2J+1 + 1) / 4, face
// diagonal J >= 6 weighs (bit 12 + J - 6, + 1) / 2, both times mask bit J.
// Unit vectors are d * inversesqrt(d.d): one reciprocal square root instead of a square root and a
// division (it differs from d / |d| in the last bits, within GLSL's 2 ulp).
// TERMS_HOOD (a physics term reads the node's 3x3x3 neighbourhood, lib/node_hood.glsl): every neighbour position
// fetched is also kept, relative to the node, in its slot of the node's 3x3x3 neighbourhood
// node_hood (lib/node_hood.glsl's layout), so the term fetches no neighbour twice.
#ifdef TERMS_HOOD
vec3 node_hood[27];
#define HOOD_KEEP(DX, DY, DZ, D) node_hood[((DX) + 1) + 3 * ((DY) + 1) + 9 * ((DZ) + 1)] = -(D);
#else
#define HOOD_KEEP(DX, DY, DZ, D)
#endif
#if defined(SPRING_WEIGHTS)
#ifndef SPRING_WEIGHT_LEVELS
uniform sampler2DArray u_weights;
#endif
#define NB_ACCUM(S, P, J, DX, DY, DZ) { float m = float((mask >> J) & 1u); float w = wt[J]; vec3 d = p - NB_POSITION(J, DX, DY, DZ); HOOD_KEEP(DX, DY, DZ, d) float inv = inversesqrt(max(dot(d, d), 1e-37)); U += (m * inv) * d; S += (w * inv) * d; P += w * d; }
#else
#define NB_ACCUM(S, P, J, DX, DY, DZ) { float w = float((mask >> J) & 1u); vec3 d = p - NB_POSITION(J, DX, DY, DZ); HOOD_KEEP(DX, DY, DZ, d) S += (w * inversesqrt(max(dot(d, d), 1e-37))) * d; P += w * d; }
#endif

#ifdef BLOCKED
// (texel: the block's; the weight texture holds member m's 5 layers at layers 5 m .. 5 m + 4)
#define WEIGHT_LAYER(L) ivec3(texel, 5 * block_member(local) + (L))
SpringSum spring_sum(ivec2 texel, ivec3 local, vec3 p, uint mask, uint levels) {
#else
#define WEIGHT_LAYER(L) ivec3(texel, L)
SpringSum spring_sum(sampler2D positions, ivec2 texel, vec3 p, uint mask, uint levels) {
#endif
#if defined(BLOCKED)
#elif defined(COMPACT_DENSE)
    int self_node = texel_node(texel);
#elif defined(COMPACT)
    ivec4 n0 = texelFetch(u_neighbours, ivec3(texel, 0), 0);
    ivec4 n1 = texelFetch(u_neighbours, ivec3(texel, 1), 0);
    ivec4 n2 = texelFetch(u_neighbours, ivec3(texel, 2), 0);
    ivec4 n3 = texelFetch(u_neighbours, ivec3(texel, 3), 0);
    ivec4 n4 = texelFetch(u_neighbours, ivec3(texel, 4), 0);
    int nb[18] = int[18](n0.x, n0.y, n0.z, n0.w, n1.x, n1.y, n1.z, n1.w, n2.x, n2.y, n2.z, n2.w,
                         n3.x, n3.y, n3.z, n3.w, n4.x, n4.y);
#endif
    vec3 s1 = vec3(0.0), p1 = vec3(0.0), s2 = vec3(0.0), p2 = vec3(0.0);
#ifdef TERMS_HOOD
    for (int slot = 0; slot < 27; ++slot) {
        node_hood[slot] = vec3(0.0);  // (slots of absent neighbours: read by no full cell)
    }
#endif
#ifdef SPRING_WEIGHTS
    vec3 U = vec3(0.0);
#ifdef SPRING_WEIGHT_LEVELS
    float wt[18];
    for (int j = 0; j < 6; ++j) wt[j] = 0.25 * float(((levels >> (2 * j)) & 3u) + 1u) * float((mask >> j) & 1u);
    for (int j = 6; j < 18; ++j) wt[j] = 0.5 * float(((levels >> (6 + j)) & 1u) + 1u) * float((mask >> j) & 1u);
#else
    vec4 w0 = texelFetch(u_weights, WEIGHT_LAYER(0), 0), w1 = texelFetch(u_weights, WEIGHT_LAYER(1), 0);
    vec4 w2 = texelFetch(u_weights, WEIGHT_LAYER(2), 0), w3 = texelFetch(u_weights, WEIGHT_LAYER(3), 0);
    vec4 w4 = texelFetch(u_weights, WEIGHT_LAYER(4), 0);
    float wt[18] = float[18](w0.x, w0.y, w0.z, w0.w, w1.x, w1.y, w1.z, w1.w, w2.x, w2.y, w2.z, w2.w,
                             w3.x, w3.y, w3.z, w3.w, w4.x, w4.y);
#endif
#endif
    NB_ACCUM(s1, p1, 0, 1, 0, 0)
    NB_ACCUM(s1, p1, 1, -1, 0, 0)
    NB_ACCUM(s1, p1, 2, 0, 1, 0)
    NB_ACCUM(s1, p1, 3, 0, -1, 0)
    NB_ACCUM(s1, p1, 4, 0, 0, 1)
    NB_ACCUM(s1, p1, 5, 0, 0, -1)
    NB_ACCUM(s2, p2, 6, 1, 1, 0)
    NB_ACCUM(s2, p2, 7, 1, -1, 0)
    NB_ACCUM(s2, p2, 8, -1, 1, 0)
    NB_ACCUM(s2, p2, 9, -1, -1, 0)
    NB_ACCUM(s2, p2, 10, 1, 0, 1)
    NB_ACCUM(s2, p2, 11, 1, 0, -1)
    NB_ACCUM(s2, p2, 12, -1, 0, 1)
    NB_ACCUM(s2, p2, 13, -1, 0, -1)
    NB_ACCUM(s2, p2, 14, 0, 1, 1)
    NB_ACCUM(s2, p2, 15, 0, 1, -1)
    NB_ACCUM(s2, p2, 16, 0, -1, 1)
    NB_ACCUM(s2, p2, 17, 0, -1, -1)
    SpringSum r;
    r.force = u_k_structural * (u_spacing * s1 - p1) + u_k_shear * (1.41421356 * u_spacing * s2 - p2);
#ifdef SPRING_WEIGHTS
    r.unit_sum = U;
#else
    r.unit_sum = s1 + s2;
#endif
    return r;
}
