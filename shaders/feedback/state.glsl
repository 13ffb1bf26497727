// Node state of the transform-feedback backend (Movania & Feng 2012, section 4: the positions
// and velocities that transform feedback writes, read back by the next pass on the GPU).
// Transform feedback writes a pass's outputs interleaved (K vec4 per node, in varying order);
// the same bytes are then copied, GPU to GPU, into an RGBA32F texture of K * NODE_ROW x rows
// texels, so slot s of node n lies at lib/node_texel.glsl's node_slot_texel(n, K, s) and every
// node can fetch its neighbours' state.
// Positions: xyz, w = mass (kg). Velocities: xyz, w unused.
// NODE_ROW: nodes per texture row (deformgl: a power of two; default 1024, the largest it uses).
#ifndef NODE_ROW
#define NODE_ROW 1024
#endif
#include "lib/node_texel.glsl"

vec4 slot(sampler2D tex, int k, int node, int s) {
    return texelFetch(tex, node_slot_texel(node, k, s), 0);
}
