// The physics terms of the XPBD node sweep (deformgl/sim/terms). Composed by
// deformgl/sim/terms/glsl.py compose_xpbd(); do not edit: `python -m deformgl.sim.terms.registry`
// writes the shipped one. Included by sim/xpbd/iterate.frag under XPBD_TERMS.
#ifdef TERM_CELL
#include "terms/cell_xpbd.glsl"
#endif
void xpbd_terms(inout vec3 dx, inout float counts, ivec2 texel, int flags, float wi) {
#ifdef TERM_CELL
    cell_xpbd(dx, counts, texel, flags, wi);
#endif
}
