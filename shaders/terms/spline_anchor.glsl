// A spline body's penalty anchor (deformgl/sim/terms/spline/term.py SplineAnchor): a node's force,
// gathered from the anchor's span pass (terms/spline_anchor.frag, run before each force
// evaluation) of the up to 27 knot spans holding the anchor's points whose node it is.
// Table u_spline_anchor_spans: 7 RGBA32F layers per node, channel c of layer l the anchor span whose
// node a = 4 l + c this node is, -1 where none (deformgl/sim/terms/spline/tables.py anchor_tables).
// u_spline_anchor_f0..3: the span pass's forces, node a = 4 l + c of span s in u_spline_anchor_f<c>
// at texel slot_texel(row_texel(s, u_spline_anchor_row), 7, l), xyz in N.
uniform sampler2DArray u_spline_anchor_spans;
uniform sampler2D u_spline_anchor_f0;
uniform sampler2D u_spline_anchor_f1;
uniform sampler2D u_spline_anchor_f2;
uniform sampler2D u_spline_anchor_f3;
uniform int u_spline_anchor_row;  // spans per row of the span pass's textures

ivec2 spline_anchor_texel(float span, int l) {
    return slot_texel(row_texel(int(span), u_spline_anchor_row), 7, l);
}

void spline_anchor_force(inout vec3 f, TermNode n) {
    for (int l = 0; l < 7; ++l) {
        vec4 spans = term_table(u_spline_anchor_spans, 7, l, n);
        if (spans.x >= 0.0) {
            f += texelFetch(u_spline_anchor_f0, spline_anchor_texel(spans.x, l), 0).xyz;
        }
        if (spans.y >= 0.0) {
            f += texelFetch(u_spline_anchor_f1, spline_anchor_texel(spans.y, l), 0).xyz;
        }
        if (spans.z >= 0.0) {
            f += texelFetch(u_spline_anchor_f2, spline_anchor_texel(spans.z, l), 0).xyz;
        }
        if (spans.w >= 0.0) {
            f += texelFetch(u_spline_anchor_f3, spline_anchor_texel(spans.w, l), 0).xyz;
        }
    }
}
