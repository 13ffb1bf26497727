// The spline cells (deformgl/sim/terms/spline; docs/EQUATIONS.md "Spline cells"): a node's elastic
// force, gathered (lib/term_node.glsl span_gather) from the span pass's outputs (terms/spline_span.frag,
// run before each force evaluation) of the up to 27 knot spans whose node it is.
// u_spline_spans: the node table; u_spline_f0..3: the span pass's forces; u_spline_row: spans per
// row of those textures (the layouts: lib/term_node.glsl span_gather).
uniform sampler2DArray u_spline_spans;
uniform sampler2D u_spline_f0;
uniform sampler2D u_spline_f1;
uniform sampler2D u_spline_f2;
uniform sampler2D u_spline_f3;
uniform int u_spline_row;

void spline_force(inout vec3 f, TermNode n) {
    f += span_gather(u_spline_spans, u_spline_f0, u_spline_f1, u_spline_f2, u_spline_f3, u_spline_row, n);
}
