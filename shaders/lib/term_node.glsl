// What a physics term's chunk gets of the node it evaluates (deformgl/sim/terms/base.py GlslTerm):
// x and v at the pass's evaluation state (m, m/s), the mass m (kg), at: where the node's row of
// every term table is, in the pass's node layout (xy the texel, z the member of a block: 0 in the
// compact layout), bits: the terms' 8 node bits (lib/node_flags.glsl term_bits), held: in implicit
// Euler's product passes the flag the terms set at the step's start (TERMS_HELD), else 1. A term's
// table has `layers` RGBA32F layers per node; term_table reads layer l.
struct TermNode {
    ivec3 at;
    vec3 x;
    vec3 v;
    float m;
    uint bits;
    float held;
};

vec4 term_table(sampler2DArray table, int layers, int l, TermNode n) {
    return texelFetch(table, ivec3(n.at.xy, n.at.z * layers + l), 0);
}

// Another node's state by node number, for a term that couples nodes (GlslTerm.others): its
// position and velocity at the evaluation state (the explicit gathers) and, in the implicit
// product's functions, the multiplied vector y at that node. Each pass that runs such terms
// defines them (the compact layouts' passes; the blocked layout does not run them).
#ifdef TERM_POSITION
// (the pass defines TERM_POSITION(T) and TERM_VELOCITY(T): a node's state at texel T)
vec3 term_position(int node) {
    return TERM_POSITION(node_texel(node));
}
vec3 term_velocity(int node) {
    return TERM_VELOCITY(node_texel(node));
}
#else
vec3 term_position(int node);
vec3 term_velocity(int node);
#endif
vec3 term_vector(int node);

// A term that reads the node's 3x3x3 neighbourhood (GlslTerm.hood; TERMS_HOOD): in the explicit
// gathers the pass keeps it in node_hood[27] (lib/node_hood.glsl: positions relative to the node,
// slot (dx + 1) + 3 (dy + 1) + 9 (dz + 1)); implicit Euler's passes gather it on request, the
// positions relative to the node and the vector multiplied (sim/implicit/system.glsl).
void hood_positions(TermNode n, out vec3 p[27]);
void hood_vector(TermNode n, out vec3 y[27]);

// A term with a pass of its own per knot span (GlslTerm.prepass; the spline terms): a node's share
// of what that pass wrote. `spans` is the term's node table (7 RGBA32F layers per node, channel c
// of layer l the span whose node a = 4 l + c this node is, -1 where none); f0..f3 the pass's
// outputs (node a = 4 l + c of span s in f<c> at texel slot_texel(row_texel(s, row), 7, l), xyz in
// N); `row` the spans per row of those textures. (Here, not in a chunk's include: a file included
// once per program must not sit under one term's #ifdef in the shipped terms/active.glsl.)
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
