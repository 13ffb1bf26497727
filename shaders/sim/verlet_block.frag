#version 330 core
// One position-Verlet step of a block of nodes per fragment (BLOCKED layouts,
// deformgl/grid/blocks.py BlockedLayout): the fragment owns the block at its texel, fetches the
// block's union neighbourhood once (hood_position below; the members' spring sums ask for the
// same constant positions and the compiler fetches each once) and writes member m's new state
// to render target m. Every node's update is sim/verlet_node.glsl, as in sim/verlet.frag, so the
// positions are bit for bit those of the one-node pass.
// Variants: SPRING_WEIGHTS (u_weights: 5 layers per member, member m's at 5 m ..
// 5 m + 4) or with SPRING_WEIGHT_LEVELS, PULLS, TERMS with TERMS_HOOD
// and HOOD_DIAGONALS (as sim/verlet.frag; the body diagonals come from the block's neighbourhood);
// BLOCKED_DENSE: every block of the box exists, neighbour blocks by block strides, else from the
// block-neighbour table. BLOCK_FLAT_X/Y/Z: the grid is one node thick along that axis (a sheet):
// the neighbourhood off its plane is not fetched (every mask bit there is 0, p stands in).
#ifndef BLOCKED
#define BLOCKED  // (the pass is always blocked; BLOCKED selects the libraries' block paths)
#endif
#include "lib/node_flags.glsl"
#include "lib/octahedral.glsl"
#include "lib/node_texel.glsl"
#include "lib/block_state.glsl"

uniform sampler2D u_previous0;  // RGBA32F: member m's position at t - dt in u_previous<m>
#if MEMBERS > 1
uniform sampler2D u_previous1;
#endif
#if MEMBERS > 2
uniform sampler2D u_previous2;
uniform sampler2D u_previous3;
#endif
#if MEMBERS > 4
uniform sampler2D u_previous4;
uniform sampler2D u_previous5;
uniform sampler2D u_previous6;
uniform sampler2D u_previous7;
#endif
uniform sampler2DArray u_node;  // static node data (node_flags.glsl), layer m: member m
#ifdef BLOCKED_DENSE
uniform ivec3 u_block_strides;  // block-number step of +1 block along x, y, z
#else
uniform isampler2DArray u_block_neighbours;  // 7 layers RGBA32I: blocks at NEIGHBOUR_OFFSETS 0..17, corners 18..25
#ifdef HOOD_DIAGONALS
#define TABLE_LAYERS 7
#else
#define TABLE_LAYERS 5  // (springs reach no corner block)
#endif
#endif

vec3 previous_at(int m, ivec2 t) {
#if MEMBERS > 4
    if (m == 7) return texelFetch(u_previous7, t, 0).xyz;
    if (m == 6) return texelFetch(u_previous6, t, 0).xyz;
    if (m == 5) return texelFetch(u_previous5, t, 0).xyz;
    if (m == 4) return texelFetch(u_previous4, t, 0).xyz;
#endif
#if MEMBERS > 2
    if (m == 3) return texelFetch(u_previous3, t, 0).xyz;
    if (m == 2) return texelFetch(u_previous2, t, 0).xyz;
#endif
#if MEMBERS > 1
    if (m == 1) return texelFetch(u_previous1, t, 0).xyz;
#endif
    return texelFetch(u_previous0, t, 0).xyz;
}

ivec2 g_texel;  // this fragment's block texel
int g_block;    // and block number
ivec3 g_local;  // the block-local position of the member being computed (the terms)
#ifndef BLOCKED_DENSE
int g_neighbours[4 * TABLE_LAYERS];
#endif

// The slot of a block offset o in the block-neighbour table: NEIGHBOUR_OFFSETS order, then the
// corners (2 qx - 1, 2 qy - 1, 2 qz - 1) at 18 + q (deformgl/grid/blocks.py CORNER_OFFSETS).
int offset_slot(ivec3 o) {
    ivec3 neg = ivec3(o.x < 0 ? 1 : 0, o.y < 0 ? 1 : 0, o.z < 0 ? 1 : 0);
    if (o.x != 0 && o.y != 0 && o.z != 0) return 18 + (1 - neg.x) + 2 * (1 - neg.y) + 4 * (1 - neg.z);
    if (o.z == 0 && o.y == 0) return neg.x;
    if (o.z == 0 && o.x == 0) return 2 + neg.y;
    if (o.x == 0 && o.y == 0) return 4 + neg.z;
    if (o.z == 0) return 6 + 2 * neg.x + neg.y;
    if (o.y == 0) return 10 + 2 * neg.x + neg.z;
    return 14 + 2 * neg.y + neg.z;
}

// The block texel at block offset o from this fragment's block.
ivec2 neighbour_block(ivec3 o) {
    if (o == ivec3(0)) return g_texel;
#ifdef BLOCKED_DENSE
    // (clamped into the blocks: outside the box the neighbour is absent and its value unused)
    ivec2 size = textureSize(u_node, 0).xy;
    int b = g_block + o.x * u_block_strides.x + o.y * u_block_strides.y + o.z * u_block_strides.z;
    return node_texel(clamp(b, 0, size.x * size.y - 1));
#else
    return node_texel(g_neighbours[offset_slot(o)]);
#endif
}

// The block's union neighbourhood: every grid position within one of a member, but the 8 corners
// of the box (no member's spring reaches them; HOOD_DIAGONALS: with the corners, body diagonals), fetched once into hood[] (fill_hood) and read by
// the members' spring sums (hood_position). Each position is written out below with a constant
// test the compiler folds, so the array is indexed by constants only and lives in registers;
// the largest box, 1x1x4 / 4x1x1 blocks, is 6 positions along its long side.
#define HOOD_X (BLOCK_X + 2)
#define HOOD_Y (BLOCK_Y + 2)
#define HOOD_Z (BLOCK_Z + 2)
vec3 g_hood[HOOD_X * HOOD_Y * HOOD_Z];

int hood_slot(ivec3 c) {
    return ((c.x + 1) * HOOD_Y + (c.y + 1)) * HOOD_Z + (c.z + 1);
}

void hood_fill(ivec3 c) {
    // (a grid one node thick along an axis: no neighbour off its plane exists; the slot gets 0,
    // defined, and the mask selects p there)
#ifdef BLOCK_FLAT_X
    if (c.x != 0) { g_hood[hood_slot(c)] = vec3(0.0); return; }
#endif
#ifdef BLOCK_FLAT_Y
    if (c.y != 0) { g_hood[hood_slot(c)] = vec3(0.0); return; }
#endif
#ifdef BLOCK_FLAT_Z
    if (c.z != 0) { g_hood[hood_slot(c)] = vec3(0.0); return; }
#endif
    ivec4 q = block_place(c);
#ifdef HOOD_DIAGONALS
    if (true) {  // (the corners are body diagonals of the corner members)
#else
    if (q.x == 0 || q.y == 0 || q.z == 0) {
#endif
        g_hood[hood_slot(c)] = state_at(q.w, neighbour_block(q.xyz)).xyz;
    }
}

// The position of the node at block-local grid position c (-1 <= c <= BLOCK; lib/springs.glsl).
vec3 hood_position(ivec3 c) {
    return g_hood[hood_slot(c)];
}

#define HOOD_AT(CX, CY, CZ) if (CX <= BLOCK_X && CY <= BLOCK_Y && CZ <= BLOCK_Z) hood_fill(ivec3(CX, CY, CZ));
#define HOOD_ROW(CX, CY) HOOD_AT(CX, CY, -1) HOOD_AT(CX, CY, 0) HOOD_AT(CX, CY, 1) HOOD_AT(CX, CY, 2) HOOD_AT(CX, CY, 3) HOOD_AT(CX, CY, 4)
#define HOOD_PLANE(CX) HOOD_ROW(CX, -1) HOOD_ROW(CX, 0) HOOD_ROW(CX, 1) HOOD_ROW(CX, 2) HOOD_ROW(CX, 3) HOOD_ROW(CX, 4)

void fill_hood() {
    HOOD_PLANE(-1)
    HOOD_PLANE(0)
    HOOD_PLANE(1)
    HOOD_PLANE(2)
    HOOD_PLANE(3)
    HOOD_PLANE(4)
}

#include "lib/springs.glsl"
#ifdef TERMS_HOOD
#include "lib/node_hood.glsl"
#endif
#include "sim/verlet_node.glsl"

// The new state texel of the member at block-local position local.
vec4 member_step(ivec3 local) {
    int m = block_member(local);
    g_local = local;
    vec4 x = state_at(m, g_texel);
    vec4 node = texelFetch(u_node, ivec3(g_texel, m), 0);
    if ((int(node.g) & FLAG_EXISTS) == 0) {
        return x;
    }
    SpringSum s = spring_sum(g_texel, local, x.xyz, uint(node.b), uint(node.a));
    return verlet_node(g_texel, x, previous_at(m, g_texel), node, s);
}

ivec3 member_local(int m) {
    return ivec3(m / (BLOCK_Y * BLOCK_Z), (m / BLOCK_Z) % BLOCK_Y, m % BLOCK_Z);
}

layout(location = 0) out vec4 o_state0;
#if MEMBERS > 1
layout(location = 1) out vec4 o_state1;
#endif
#if MEMBERS > 2
layout(location = 2) out vec4 o_state2;
layout(location = 3) out vec4 o_state3;
#endif
#if MEMBERS > 4
layout(location = 4) out vec4 o_state4;
layout(location = 5) out vec4 o_state5;
layout(location = 6) out vec4 o_state6;
layout(location = 7) out vec4 o_state7;
#endif

void main() {
    g_texel = ivec2(gl_FragCoord.xy);
    g_block = texel_node(g_texel);
#ifndef BLOCKED_DENSE
    for (int l = 0; l < TABLE_LAYERS; ++l) {
        ivec4 n = texelFetch(u_block_neighbours, ivec3(g_texel, l), 0);
        g_neighbours[4 * l] = n.x;
        g_neighbours[4 * l + 1] = n.y;
        g_neighbours[4 * l + 2] = n.z;
        g_neighbours[4 * l + 3] = n.w;
    }
#endif
    fill_hood();
    o_state0 = member_step(member_local(0));
#if MEMBERS > 1
    o_state1 = member_step(member_local(1));
#endif
#if MEMBERS > 2
    o_state2 = member_step(member_local(2));
    o_state3 = member_step(member_local(3));
#endif
#if MEMBERS > 4
    o_state4 = member_step(member_local(4));
    o_state5 = member_step(member_local(5));
    o_state6 = member_step(member_local(6));
    o_state7 = member_step(member_local(7));
#endif
}
