// The physics terms of the transform-feedback stages (deformgl/sim/terms). Composed by
// deformgl/sim/terms/glsl.py compose_feedback(); do not edit: `python -m deformgl.sim.terms.registry`
// writes the shipped one. Included by feedback/forces.glsl under FEEDBACK_TERMS.
#ifdef TERM_CELL
#include "terms/cell_feedback.glsl"
#endif
void feedback_terms(inout vec3 f, int i, vec3 xi) {
#ifdef TERM_CELL
    cell_feedback(f, i, xi);
#endif
}
