// The cells' volumetric term and corner barrier (deformgl/sim/terms/volume/energy.py CellVolumes; docs/EQUATIONS.md
// "Any Poisson's ratio"): the float32 twin of volume_forces (terms/cell_forces.glsl) on the node, from
// its 3x3x3 neighbourhood, which the pass keeps for it (TERMS_HOOD: node_hood in the explicit
// gathers, lib/node_hood.glsl), and its full incident cells, the term's node bits (n.bits: bit q the
// cell whose lower corner is at offset (qx - 1, qy - 1, qz - 1)). CELL_CENTRE: the centre term
// (kappa > 0; its cells' body diagonals, HOOD_DIAGONALS); CELL_BARRIER: the corner barrier.
// Implicit Euler (TERMS_IMPLICIT): the Gauss-Newton product and the node's block
// (terms/cell_implicit.glsl), `held` whether a barrier term holds the node at the step's start.
#include "terms/cell_forces.glsl"

void cell_force(inout vec3 f, TermNode n) {
    f += cell_forces(node_hood, n.bits);
}

#ifdef TERMS_IMPLICIT
#include "terms/cell_implicit.glsl"
#endif
