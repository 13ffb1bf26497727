// Node number <-> texel of the node-numbered layouts (deformgl/grid/nodes.py CompactLayout; the
// fragment-pass integrators' textures): node n sits at texel (n % w, n / w) of a texture whose
// width w = 2^u_width_log2 is a power of two. Shared by lib/springs.glsl (COMPACT layouts),
// sim/integrators/forces.glsl and profile/step_ablation.frag.
// BLOCKED layouts (deformgl/grid/blocks.py BlockedLayout) number blocks the same way: block b is
// texel node_texel(b) of every member's texture, and block_place gives the block and member
// (render target) of a node at a block-local grid position.

uniform int u_width_log2;  // log2 of the texture width

ivec2 node_texel(int n) {
    return ivec2(n & ((1 << u_width_log2) - 1), n >> u_width_log2);
}

// The node number of a texel (the inverse of node_texel).
int texel_node(ivec2 texel) {
    return (texel.y << u_width_log2) | texel.x;
}

#ifdef BLOCKED
#include "lib/block_shape.glsl"
const ivec3 BLOCK = ivec3(BLOCK_X, BLOCK_Y, BLOCK_Z);
const int BLOCK_MEMBERS = BLOCK_X * BLOCK_Y * BLOCK_Z;

// The member (render target) of block-local grid position c (0 <= c < BLOCK): C order, as node numbers.
int block_member(ivec3 c) {
    return (c.x * BLOCK_Y + c.y) * BLOCK_Z + c.z;
}

// The neighbour block (each component -1, 0 or 1) holding block-local position c (-1 <= c <= BLOCK)
// and c's member there: ivec4(block offset, member).
ivec4 block_place(ivec3 c) {
    ivec3 o = ivec3(c.x < 0 ? -1 : (c.x >= BLOCK_X ? 1 : 0), c.y < 0 ? -1 : (c.y >= BLOCK_Y ? 1 : 0),
                    c.z < 0 ? -1 : (c.z >= BLOCK_Z ? 1 : 0));
    return ivec4(o, block_member(c - o * BLOCK));
}
#endif
