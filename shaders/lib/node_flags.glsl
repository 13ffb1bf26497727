// Static node data texture (RGBA32F): R mass (kg), G flag bits, B neighbour mask (18 bits), A the spring-weight
// levels code of SPRING_WEIGHT_LEVELS (lib/springs.glsl; 24 bits, exact in a float), else 0.
// Flag bits: 1 exists, 2 fixed, 4 << g member of scripted pull g (deformgl/sim/backends/verlet_data.py),
// 64 << b: bit b of the physics terms' node bits (deformgl/sim/terms GlslTerm.node_bits; one term's:
// the volumetric term's full incident cells, bit q = qx + 2 qy + 4 qz the cell whose lower corner
// is at offset (qx - 1, qy - 1, qz - 1), deformgl/sim/terms/volume/chunks.py),
// 16384: the node's pulls are per kilogram (u_pull_force times its mass; a material scene's pull).
// The fragment-pass integrators' node data (sim/integrators/step.frag) uses the same G bits
// (its load groups are in B instead).
const int FLAG_EXISTS = 1;
const int FLAG_FIXED = 2;
const int PULL_SHIFT = 2;
const int TERM_SHIFT = 6;
const int FLAG_PULLS_PER_KG = 16384;

// The terms' node bits of a node's flag bits (8 bits; TermNode.bits, lib/term_node.glsl).
uint term_bits(int flags) {
    return uint(flags >> TERM_SHIFT) & 255u;
}
