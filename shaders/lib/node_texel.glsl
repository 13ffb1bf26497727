// The node layout: where node n's state lives in a node-numbered texture (deformgl/grid/nodes.py
// CompactLayout, the layout every pass reads and writes; docs/ARCHITECTURE.md "Textures: channel
// layouts"). Every pass goes from a node number to a texel, and back, through these functions
// only; none computes a texel itself (tests/test_node_layout.py).
//
// Node n sits at texel (n % w, n / w) of a texture w nodes wide, w a power of two: the uniform
// w = 2^u_width_log2 (set by deformgl/grid/nodes.py layout_uniforms), or, where a pass fixes it at
// compile time (the transform-feedback backend, deformgl/sim/backends/feedback.py), the define
// NODE_ROW. A texture of K texels per node (the transform-feedback state, K vec4 outputs per node
// interleaved; its cell table) holds slot s of node n at texel (K (n % w) + s, n / w):
// node_slot_texel. Tables of other items laid out row by row (the feedback backend's spring
// entries, a multigrid level read from a finer or coarser one) use row_texel / width_texel.
// Integer arithmetic only: the same texels whichever form computes them.
//
// BLOCKED layouts (deformgl/grid/blocks.py BlockedLayout) number blocks the same way: block b is
// texel node_texel(b) of every member's texture, and block_place gives the block and member
// (render target) of a node at a block-local grid position.

// Item i of a row-major table 2^width_log2 items wide.
ivec2 width_texel(int i, int width_log2) {
    return ivec2(i & ((1 << width_log2) - 1), i >> width_log2);
}

// Item i of a row-major table `row` items wide (a row fixed at compile time; i >= 0).
ivec2 row_texel(int i, int row) {
    return ivec2(i % row, i / row);
}

#ifndef NODE_ROW
uniform int u_width_log2;  // log2 of the texture width
#endif

ivec2 node_texel(int n) {
#ifdef NODE_ROW
    return row_texel(n, NODE_ROW);
#else
    return width_texel(n, u_width_log2);
#endif
}

// The node number of a texel (the inverse of node_texel).
int texel_node(ivec2 texel) {
#ifdef NODE_ROW
    return texel.y * NODE_ROW + texel.x;
#else
    return (texel.y << u_width_log2) | texel.x;
#endif
}

// Slot `slot` of the node whose one-texel-per-node texel is `node` (node_texel(n), or the
// fragment of a pass drawn over the node grid), in a texture of `slots` texels per node.
ivec2 slot_texel(ivec2 node, int slots, int slot) {
    return ivec2(slots * node.x + slot, node.y);
}

// Slot `slot` of node n in a texture of `slots` texels per node.
ivec2 node_slot_texel(int n, int slots, int slot) {
    return slot_texel(node_texel(n), slots, slot);
}

// The item and slot (x: item, y: slot) of a texel of a table of items `row` to a row, `slots`
// texels each: the inverse of slot_texel(row_texel(item, row), slots, slot).
ivec2 texel_item_slot(ivec2 texel, int slots, int row) {
    return ivec2(texel.y * row + texel.x / slots, texel.x % slots);
}

// A texel the host packed into one int as x | y << 16 (deformgl/render/premap.py).
ivec2 packed_texel(int code) {
    return ivec2(code & 0xffff, code >> 16);
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
