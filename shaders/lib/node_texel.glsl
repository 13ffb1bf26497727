// Node number <-> texel of the node-numbered layouts (deformgl/grid/nodes.py CompactLayout; the
// fragment-pass integrators' textures): node n sits at texel (n % w, n / w) of a texture whose
// width w = 2^u_width_log2 is a power of two. Shared by lib/springs.glsl (COMPACT layouts),
// sim/integrators/forces.glsl and profile/step_ablation.frag.

uniform int u_width_log2;  // log2 of the texture width

ivec2 node_texel(int n) {
    return ivec2(n & ((1 << u_width_log2) - 1), n >> u_width_log2);
}

// The node number of a texel (the inverse of node_texel).
int texel_node(ivec2 texel) {
    return (texel.y << u_width_log2) | texel.x;
}
