#version 330 core
// The volumetric term of every node, per node (terms/cell_forces.glsl cell_forces: the float32
// twin of deformgl/sim/terms/volume/energy.py volume_forces), into a force texture: one fragment per node of
// a compact layout (deformgl/grid/nodes.py CompactLayout: node n at texel node_texel(n)).
// The node's 3x3x3 neighbourhood comes from u_cell_hood (7 RGBA32I layers, slot 4 l + c =
// (dx + 1) + 3 (dy + 1) + 9 (dz + 1): deformgl/sim/terms/volume/tables.py neighbourhood), or
// with COMPACT_DENSE (every node of the box exists) from the node-number strides; the mask of
// its full incident cells is the node data's G >> TERM_SHIFT (lib/node_flags.glsl). Positions
// are taken relative to the node (the terms only use differences), so float32 rounding stays at
// the scale of h. Output: xyz the force in N, w 0; 0 at nodes in no full cell.
#include "lib/node_flags.glsl"
#include "lib/node_texel.glsl"
#include "terms/cell_forces.glsl"

uniform sampler2D u_x;       // RGBA32F: xyz position, m
uniform sampler2D u_node;    // RGBA32F node data: G flag bits with the incident-cell mask
#ifdef COMPACT_DENSE
uniform ivec3 u_strides;     // node-number step of +1 along x, y, z
#else
uniform isampler2DArray u_cell_hood;
#endif

layout(location = 0) out vec4 o_force;

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    uint cells = term_bits(int(texelFetch(u_node, texel, 0).g));
    if (cells == 0u) {
        o_force = vec4(0.0);
        return;
    }
    vec3 origin = texelFetch(u_x, texel, 0).xyz;
    vec3 p[27];
#ifdef COMPACT_DENSE
    int self_node = texel_node(texel);
    ivec2 size = textureSize(u_x, 0);
    int last = size.x * size.y - 1;
    for (int slot = 0; slot < 27; ++slot) {
        int n = self_node + (slot % 3 - 1) * u_strides.x + ((slot / 3) % 3 - 1) * u_strides.y + (slot / 9 - 1) * u_strides.z;
        p[slot] = texelFetch(u_x, node_texel(clamp(n, 0, last)), 0).xyz - origin;
    }
#else
    for (int layer = 0; layer < 7; ++layer) {
        ivec4 nb = texelFetch(u_cell_hood, ivec3(texel, layer), 0);
        for (int c = 0; c < 4; ++c) {
            int slot = 4 * layer + c;
            if (slot < 27) {
                p[slot] = texelFetch(u_x, node_texel(nb[c]), 0).xyz - origin;
            }
        }
    }
#endif
    o_force = vec4(cell_forces(p, cells), 0.0);
}
