#version 330 core
// The compact view of a BLOCKED state (deformgl/sim/backends/blocked.py): texel n of the compact
// layout (deformgl/grid/nodes.py CompactLayout) gets node n's state texel, copied bit for bit, so
// the draw passes, the census and the mappings read the positions as from a one-node pass.
#include "lib/block_state.glsl"

uniform isampler2D u_place;  // RGBA32I per compact texel: node's block texel (x, y), member, 0; padding: member -1

layout(location = 0) out vec4 o_state;

void main() {
    ivec4 q = texelFetch(u_place, ivec2(gl_FragCoord.xy), 0);
    o_state = q.z < 0 ? vec4(0.0) : state_at(q.z, q.xy);  // (padding holds 0, as in the compact layout)
}
