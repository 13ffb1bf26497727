// A node's share of the forces a spline term's span pass computed (terms/spline.glsl,
// terms/spline_anchor.glsl): `spans` the term's node table (7 RGBA32F layers per node, channel c of
// layer l the span whose node a = 4 l + c this node is, -1 where none; deformgl/sim/terms/spline/
// tables.py node_spans), f0..f3 the span pass's outputs (node a = 4 l + c of span s in f<c> at texel
// slot_texel(row_texel(s, row), 7, l), xyz in N), `row` the spans per row of those textures.
vec3 span_gather(sampler2DArray spans, sampler2D f0, sampler2D f1, sampler2D f2, sampler2D f3, int row,
                 TermNode n) {
    vec3 f = vec3(0.0);
    for (int l = 0; l < 7; ++l) {
        vec4 s = term_table(spans, 7, l, n);
        if (s.x >= 0.0) {
            f += texelFetch(f0, slot_texel(row_texel(int(s.x), row), 7, l), 0).xyz;
        }
        if (s.y >= 0.0) {
            f += texelFetch(f1, slot_texel(row_texel(int(s.y), row), 7, l), 0).xyz;
        }
        if (s.z >= 0.0) {
            f += texelFetch(f2, slot_texel(row_texel(int(s.z), row), 7, l), 0).xyz;
        }
        if (s.w >= 0.0) {
            f += texelFetch(f3, slot_texel(row_texel(int(s.w), row), 7, l), 0).xyz;
        }
    }
    return f;
}
