// What the spline terms' span passes share (terms/spline_span.frag, terms/spline_anchor.frag): the
// span tables' layout, span s's slot k of a table of `slots` texels a span at
// slot_texel(row_texel(s, u_span_row), slots, k) (lib/node_texel.glsl).
uniform int u_span_row;  // spans per row of the span tables

ivec2 span_texel(int s, int slots, int slot) {
    return slot_texel(row_texel(s, u_span_row), slots, slot);
}
