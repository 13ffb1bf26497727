// The physics terms of a pass (deformgl/sim/terms). Composed by deformgl/sim/terms/glsl.py
// compose(); do not edit: `python -m deformgl.sim.terms.registry` writes the shipped one.
#include "lib/term_node.glsl"
#ifdef TERM_CELL
#include "terms/cell.glsl"
#endif
#ifdef TERM_BENDING
#include "terms/bending.glsl"
#endif
#ifdef TERM_SPLINE
#include "terms/spline.glsl"
#endif
#ifdef TERM_SPLINE_ANCHOR
#include "terms/spline_anchor.glsl"
#endif
void terms_force(inout vec3 f, TermNode n) {
#ifdef TERM_CELL
    cell_force(f, n);
#endif
#ifdef TERM_BENDING
    bending_force(f, n);
#endif
#ifdef TERM_SPLINE
    spline_force(f, n);
#endif
#ifdef TERM_SPLINE_ANCHOR
    spline_anchor_force(f, n);
#endif
}
#ifdef TERMS_NEIGHBOURS
void terms_begin(TermNode n) {
#ifdef TERM_BENDING
    bending_begin(n);
#endif
}
void terms_neighbour(inout vec3 f, TermNode n, int j, vec3 d) {
#ifdef TERM_BENDING
    bending_neighbour(f, n, j, d);
#endif
}
#endif
#ifdef TERMS_IMPLICIT
void terms_product(inout vec3 q, TermNode n, vec3 y) {
#ifdef TERM_CELL
    cell_product(q, n, y);
#endif
#ifdef TERM_BENDING
    bending_product(q, n, y);
#endif
}
void terms_diagonal(inout vec3 d, inout vec3 off, inout float held, TermNode n) {
#ifdef TERM_CELL
    cell_diagonal(d, off, held, n);
#endif
#ifdef TERM_BENDING
    bending_diagonal(d, off, held, n);
#endif
}
#ifdef TERMS_NEIGHBOURS
void terms_neighbour_product(inout vec3 sk, inout vec3 dk, TermNode n, int j, vec3 dy) {
#ifdef TERM_BENDING
    bending_neighbour_product(sk, dk, n, j, dy);
#endif
}
#endif
#endif
