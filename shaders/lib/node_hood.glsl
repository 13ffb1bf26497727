// The node's 3x3x3 neighbourhood for the physics terms that read it (TERMS_HOOD; deformgl/sim/terms
// GlslTerm.hood: the volumetric cell term), kept by the pass that computes the node's springs:
// sim/verlet.frag and sim/verlet_block.frag (the foundation's Verlet pass) and
// sim/integrators/step.frag (every stage of the five integrators). node_hood[27] holds positions
// relative to the node, slot (dx + 1) + 3 (dy + 1) + 9 (dz + 1): the 18 neighbour positions the
// springs fetched (lib/springs.glsl, sim/integrators/forces.glsl: HOOD_KEEP) and, with
// HOOD_DIAGONALS, the 8 body diagonals (±1, ±1, ±1) fetched here by hood_diagonals; slot 13 (the
// node) 0. Without HOOD_DIAGONALS nothing is fetched besides the springs. The diagonal
// (2 qx - 1, 2 qy - 1, 2 qz - 1) has slot 2 qx + 6 qy + 18 qz. Its node number: on dense grids
// (COMPACT_DENSE: u_strides of lib/springs.glsl; DENSE: u_offsets of sim/integrators/forces.glsl,
// +x +y +z at 0, 2, 4) from the node-number strides, clamped into the texture (outside the box no
// cell is full and the value is unused); with HOOD_NODES (implicit Euler's passes) from the node's
// 27-neighbourhood table u_hood_nodes (7 RGBA32I layers, slot s in channel s % 4 of layer s / 4;
// the host's neighbourhood table); else from u_hood_diagonals (the node itself
// where absent).
// BLOCKED layouts (sim/verlet_block.frag) read the diagonals from the block's neighbourhood,
// hood_position at g_local, the member's block-local position, + (±1, ±1, ±1).
// The including pass defines HOOD_POSITION(T): the position (xyz) of the node at texel T at which
// forces are evaluated; it has declared u_node and node_hood and filled node_hood with its springs.

#ifdef HOOD_NODES
uniform isampler2DArray u_hood_nodes;      // 7 layers RGBA32I: the 27 node numbers of the neighbourhood
#elif defined(HOOD_DIAGONALS) && !defined(COMPACT_DENSE) && !defined(DENSE) && !defined(BLOCKED)
uniform isampler2DArray u_hood_diagonals;  // 2 layers RGBA32I: the node at diagonal q in channel q % 4 of layer q / 4
#endif

// (each macro on one line: a backslash line continuation is GLSL 4.20, not 3.30 nor ES 3.00)
#define HOOD_DIAGONAL(Q, NODE) node_hood[2 * ((Q) & 1) + 6 * (((Q) >> 1) & 1) + 18 * (((Q) >> 2) & 1)] = HOOD_POSITION(node_texel(HOOD_VALID(NODE))) - p;
#if defined(COMPACT_DENSE) || defined(DENSE)
#define HOOD_VALID(NODE) clamp(NODE, 0, last)
#else
#define HOOD_VALID(NODE) (NODE)
#endif

// Completes node_hood for the terms (p: the node's position): the body diagonals with
// HOOD_DIAGONALS, and the node's own slot.
void hood_diagonals(ivec2 texel, vec3 p) {
#if defined(HOOD_DIAGONALS) && defined(BLOCKED)
    for (int q = 0; q < 8; ++q) {
        ivec3 c = ivec3(2 * (q & 1) - 1, 2 * ((q >> 1) & 1) - 1, 2 * ((q >> 2) & 1) - 1);
        node_hood[2 * (q & 1) + 6 * ((q >> 1) & 1) + 18 * ((q >> 2) & 1)] = hood_position(g_local + c) - p;
    }
#elif defined(HOOD_DIAGONALS)
#if defined(COMPACT_DENSE) || defined(DENSE)
    int n = texel_node(texel);
#ifdef COMPACT_DENSE
    ivec3 s = u_strides;
#else
    ivec3 s = ivec3(u_offsets[0], u_offsets[2], u_offsets[4]);
#endif
    ivec4 d0 = ivec4(n - s.x - s.y - s.z, n + s.x - s.y - s.z, n - s.x + s.y - s.z, n + s.x + s.y - s.z);
    ivec4 d1 = ivec4(n - s.x - s.y + s.z, n + s.x - s.y + s.z, n - s.x + s.y + s.z, n + s.x + s.y + s.z);
    ivec2 size = textureSize(u_node, 0);
    int last = size.x * size.y - 1;
#elif defined(HOOD_NODES)
    ivec4 l0 = texelFetch(u_hood_nodes, ivec3(texel, 0), 0), l1 = texelFetch(u_hood_nodes, ivec3(texel, 1), 0);
    ivec4 l2 = texelFetch(u_hood_nodes, ivec3(texel, 2), 0), l4 = texelFetch(u_hood_nodes, ivec3(texel, 4), 0);
    ivec4 l5 = texelFetch(u_hood_nodes, ivec3(texel, 5), 0), l6 = texelFetch(u_hood_nodes, ivec3(texel, 6), 0);
    ivec4 d0 = ivec4(l0.x, l0.z, l1.z, l2.x);   // slots 0, 2, 6, 8
    ivec4 d1 = ivec4(l4.z, l5.x, l6.x, l6.z);   // slots 18, 20, 24, 26
#else
    ivec4 d0 = texelFetch(u_hood_diagonals, ivec3(texel, 0), 0);
    ivec4 d1 = texelFetch(u_hood_diagonals, ivec3(texel, 1), 0);
#endif
    HOOD_DIAGONAL(0, d0.x)
    HOOD_DIAGONAL(1, d0.y)
    HOOD_DIAGONAL(2, d0.z)
    HOOD_DIAGONAL(3, d0.w)
    HOOD_DIAGONAL(4, d1.x)
    HOOD_DIAGONAL(5, d1.y)
    HOOD_DIAGONAL(6, d1.z)
    HOOD_DIAGONAL(7, d1.w)
#endif
    node_hood[13] = vec3(0.0);
}
