// Static node data texture (RGBA32F): R mass (kg), G flag bits, B neighbour mask (18 bits), A the spring-weight
// levels code of SPRING_WEIGHT_LEVELS (lib/springs.glsl; 24 bits, exact in a float), else 0.
// Flag bits: 1 exists, 2 fixed, 4 << g member of scripted pull g (deformgl/sim/backends/foundation.py).
const int FLAG_EXISTS = 1;
const int FLAG_FIXED = 2;
const int PULL_SHIFT = 2;
