// A spline body's penalty anchor (deformgl/sim/terms/spline/term.py SplineAnchor): a node's force,
// gathered (lib/term_node.glsl span_gather) from the anchor's span pass (terms/spline_anchor.frag, run
// before each force evaluation) of the up to 27 knot spans holding the anchor's points whose node
// it is. u_spline_anchor_spans: the node table (deformgl/sim/terms/spline/tables.py anchor_tables);
// u_spline_anchor_f0..3: the span pass's forces; u_spline_anchor_row: spans per row of those.
uniform sampler2DArray u_spline_anchor_spans;
uniform sampler2D u_spline_anchor_f0;
uniform sampler2D u_spline_anchor_f1;
uniform sampler2D u_spline_anchor_f2;
uniform sampler2D u_spline_anchor_f3;
uniform int u_spline_anchor_row;

void spline_anchor_force(inout vec3 f, TermNode n) {
    f += span_gather(u_spline_anchor_spans, u_spline_anchor_f0, u_spline_anchor_f1, u_spline_anchor_f2,
                     u_spline_anchor_f3, u_spline_anchor_row, n);
}
