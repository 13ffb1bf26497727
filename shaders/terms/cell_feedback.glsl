// The cells' volumetric term and inversion barrier on one node in the transform-feedback stages
// (the term's feedback form, deformgl/sim/terms/volume/chunks.py volume_feedback(); compiled with
// TERM_CELL through terms/feedback.glsl): the node's 3x3x3 neighbourhood and the mask of its full
// incident cells come from one RGBA32I texture, the forces from terms/cell_forces.glsl (the
// float32 twin of deformgl/sim/terms/volume/energy.py volume_forces()). Included through
// terms/feedback.glsl by feedback/forces.glsl, after the stage's eval_x hook.
//
//   u_cell_nodes (7 NODE_ROW x rows)  node n: texels node_slot_texel(n, 7, s) (lib/node_texel.glsl),
//                                     s = 0..6; integer m = 4 s + channel (m < 27) is the node at
//                                     neighbourhood slot m = (dx + 1) + 3 (dy + 1) + 9 (dz + 1)
//                                     (absent: the node itself), integer 27 (texel 6, w) the bit
//                                     mask of its full incident cells
//                                     (deformgl/sim/terms/volume/chunks.py).
//
// The positions handed to cell_forces() are relative to the node's own: both terms depend on
// differences of positions only (the centre gradients G_c sum to zero), and differences of nearby
// float32 positions are exact, so the cell's shape is not lost to the rounding of large
// coordinates.
#include "terms/cell_forces.glsl"

uniform isampler2D u_cell_nodes;

void cell_feedback(inout vec3 f, int i, vec3 xi) {
    ivec4 t[7];
    for (int s = 0; s < 7; ++s) {
        t[s] = texelFetch(u_cell_nodes, node_slot_texel(i, 7, s), 0);
    }
    uint mask = uint(t[6].w);
    if (mask == 0u) {
        return;
    }
    vec3 p[27];
    for (int m = 0; m < 27; ++m) {
        p[m] = eval_x(t[m >> 2][m & 3]).xyz - xi;
    }
    f += cell_forces(p, mask);
}
