// The spline cells (deformgl/sim/terms/spline; docs/EQUATIONS.md "Spline cells"): a node's elastic
// force, gathered from the span pass's outputs (terms/spline_span.frag, run before each force
// evaluation) of the up to 27 knot spans whose node it is.
// Table u_spline_spans: 7 RGBA32F layers per node, channel c of layer l the span whose node
// a = 4 l + c this node is (a = 9 (dx + 1) + 3 (dy + 1) + (dz + 1), dx.. its offset from the span's
// centre node), -1 where none (deformgl/sim/terms/spline/tables.py SpanTables.node_spans).
// u_spline_f0..3: the span pass's forces, node a = 4 l + c of span s in u_spline_f<c> at texel
// slot_texel(row_texel(s, u_spline_row), 7, l), xyz in N.
uniform sampler2DArray u_spline_spans;
uniform sampler2D u_spline_f0;
uniform sampler2D u_spline_f1;
uniform sampler2D u_spline_f2;
uniform sampler2D u_spline_f3;
uniform int u_spline_row;  // spans per row of the span pass's textures

ivec2 spline_texel(float span, int l) {
    return slot_texel(row_texel(int(span), u_spline_row), 7, l);
}

void spline_force(inout vec3 f, TermNode n) {
    for (int l = 0; l < 7; ++l) {
        vec4 spans = term_table(u_spline_spans, 7, l, n);
        if (spans.x >= 0.0) {
            f += texelFetch(u_spline_f0, spline_texel(spans.x, l), 0).xyz;
        }
        if (spans.y >= 0.0) {
            f += texelFetch(u_spline_f1, spline_texel(spans.y, l), 0).xyz;
        }
        if (spans.z >= 0.0) {
            f += texelFetch(u_spline_f2, spline_texel(spans.z, l), 0).xyz;
        }
        if (spans.w >= 0.0) {
            f += texelFetch(u_spline_f3, spline_texel(spans.w, l), 0).xyz;
        }
    }
}
