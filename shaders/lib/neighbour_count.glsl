// The grid neighbours a node's springs reach (Mosegaard & Sorensen 2005, section 3.1):
// NB_LAYERS RGBA32I layers of u_neighbours hold NB_COUNT neighbour node numbers, 5 and 18
// (the default: 6 structural and 12 shear springs) or 6 and 24 (with the 6 flexion springs).
// Defaults for an application that defines neither; deformgl defines both.
#ifndef NB_LAYERS
#define NB_LAYERS 5
#endif
#ifndef NB_COUNT
#if NB_LAYERS > 5
#define NB_COUNT 24
#else
#define NB_COUNT 18
#endif
#endif
