// The volumetric term of one node inside the pass that computes its springs (define CELLS):
// sim/verlet.frag (the foundation's Verlet pass) and sim/integrators/step.frag (every stage of
// the five integrators). The node's 3x3x3 neighbourhood relative to the node, cell_hood (slot
// (dx + 1) + 3 (dy + 1) + 9 (dz + 1), lib/cell_forces.glsl's layout), holds the 18 neighbour
// positions the springs fetched (lib/springs.glsl, sim/integrators/forces.glsl: CELL_KEEP) and,
// for the centre term (CELL_CENTRE), the 8 body diagonals (±1, ±1, ±1) fetched here; then
// lib/cell_forces.glsl cell_forces. The barrier alone never reads a body diagonal (the tets
// holding a corner reach its edge and face neighbours only), so without CELL_CENTRE nothing is
// fetched besides the springs. The diagonal (2 qx - 1, 2 qy - 1, 2 qz - 1) belongs to incident
// cell q = qx + 2 qy + 4 qz only. Its node number: on dense grids (COMPACT_DENSE: u_strides of
// lib/springs.glsl; DENSE: u_offsets of sim/integrators/forces.glsl, +x +y +z at 0, 2, 4) from
// the node-number strides, clamped into the texture (outside the box the cell is not full and
// the value is unused); else from u_cell_diagonals (the node itself where absent). BLOCKED layouts
// (sim/verlet_block.frag) read the diagonals from the block's neighbourhood, hood_position at
// g_local, the member's block-local position, + (±1, ±1, ±1).
// The including pass defines CELL_POSITION(T): the position (xyz) of the node at texel T at
// which forces are evaluated; it has declared u_node and cell_hood and filled cell_hood with its
// springs.

#include "lib/cell_forces.glsl"

#if defined(CELL_CENTRE) && !defined(COMPACT_DENSE) && !defined(DENSE) && !defined(BLOCKED)
uniform isampler2DArray u_cell_diagonals;  // 2 layers RGBA32I: the node at the diagonal of cell q in channel q % 4 of layer q / 4
#endif

// (each macro on one line: a backslash line continuation is GLSL 4.20, not 3.30 nor ES 3.00)
#define CELL_DIAGONAL(Q, NODE) cell_hood[2 * ((Q) & 1) + 6 * (((Q) >> 1) & 1) + 18 * (((Q) >> 2) & 1)] = CELL_POSITION(node_texel(CELL_VALID(NODE))) - p;
#if defined(COMPACT_DENSE) || defined(DENSE)
#define CELL_VALID(NODE) clamp(NODE, 0, last)
#else
#define CELL_VALID(NODE) (NODE)
#endif

// The force in N of the node's full incident cells (bit q of `cells`); p: the node's position.
vec3 hood_cell_force(ivec2 texel, vec3 p, uint cells) {
#if defined(CELL_CENTRE) && defined(BLOCKED)
    for (int q = 0; q < 8; ++q) {
        ivec3 c = ivec3(2 * (q & 1) - 1, 2 * ((q >> 1) & 1) - 1, 2 * ((q >> 2) & 1) - 1);
        cell_hood[2 * (q & 1) + 6 * ((q >> 1) & 1) + 18 * ((q >> 2) & 1)] = hood_position(g_local + c) - p;
    }
#elif defined(CELL_CENTRE)
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
#else
    ivec4 d0 = texelFetch(u_cell_diagonals, ivec3(texel, 0), 0);
    ivec4 d1 = texelFetch(u_cell_diagonals, ivec3(texel, 1), 0);
#endif
    CELL_DIAGONAL(0, d0.x)
    CELL_DIAGONAL(1, d0.y)
    CELL_DIAGONAL(2, d0.z)
    CELL_DIAGONAL(3, d0.w)
    CELL_DIAGONAL(4, d1.x)
    CELL_DIAGONAL(5, d1.y)
    CELL_DIAGONAL(6, d1.z)
    CELL_DIAGONAL(7, d1.w)
#endif
    cell_hood[13] = vec3(0.0);
    return cell_forces(cell_hood, cells);
}
