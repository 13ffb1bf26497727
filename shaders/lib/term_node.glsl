// What a physics term's chunk gets of the node it evaluates (deformgl/sim/terms/base.py GlslTerm):
// x and v at the pass's evaluation state (m, m/s), the mass m (kg), and at: where the node's row of
// every term table is, in the pass's node layout (xy the texel, z the member of a block: 0 in the
// compact layout). A term's table has `layers` RGBA32F layers per node; term_table reads layer l.
struct TermNode {
    ivec3 at;
    vec3 x;
    vec3 v;
    float m;
};

vec4 term_table(sampler2DArray table, int layers, int l, TermNode n) {
    return texelFetch(table, ivec3(n.at.xy, n.at.z * layers + l), 0);
}

// Another node's state by node number, for a term that couples nodes (GlslTerm.others): its
// position and velocity at the evaluation state (the explicit gathers) and, in the implicit
// product's functions, the multiplied vector y at that node. Each pass that runs such terms
// defines them (the compact layouts' passes; the blocked layout does not run them).
vec3 term_position(int node);
vec3 term_velocity(int node);
vec3 term_vector(int node);
