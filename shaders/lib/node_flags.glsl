// Static node data texture (RGBA32F): R mass (kg), G flag bits, B neighbour mask (18 bits), A the spring-weight
// levels code of SPRING_WEIGHT_LEVELS (lib/springs.glsl; 24 bits, exact in a float), else 0.
// Flag bits: 1 exists, 2 fixed, 4 << g member of scripted pull g (deformgl/sim/backends/foundation.py),
// 64 << q: full incident cell q of the volumetric term (lib/cell_forces.glsl; q = qx + 2 qy + 4 qz,
// the cell whose lower corner is at offset (qx - 1, qy - 1, qz - 1); deformgl/sim/backends/cell_tables.py),
// 16384: the node's pulls are per kilogram (u_pull_force times its mass; a material scene's pull).
// The fragment-pass integrators' node data (sim/integrators/step.frag) uses the same G bits
// (its load groups are in B instead).
const int FLAG_EXISTS = 1;
const int FLAG_FIXED = 2;
const int PULL_SHIFT = 2;
const int CELL_SHIFT = 6;
const int FLAG_PULLS_PER_KG = 16384;

// The incident-cell mask of a node's flag bits (8 bits).
uint cell_bits(int flags) {
    return uint(flags >> CELL_SHIFT) & 255u;
}
