// External forces on one node (Movania & Feng 2012 eq. 1 and the user-intervention force of
// section 3), the same as the ``loads`` and ``drags`` of deformgl/springs.py forces():
//   loads: force(t) per node on every node of load group g (bit g of the node's groups; a
//          scene's [[physics.pull]]), at most 4 groups;
//   drags: a zero-rest-length spring k_d (target(t) - x) pulling one node toward a moving target.
// LOADS and DRAGS are the counts; 0 compiles none of it. Times are the stage's: the host sets
// u_load and u_drag_target before each pass.
#ifndef LOADS
#define LOADS 0
#endif
#ifndef DRAGS
#define DRAGS 0
#endif
#if LOADS > 0
uniform vec3 u_load[LOADS];         // N per node of each load group at this stage's time
#endif
#if DRAGS > 0
uniform int u_drag_node[DRAGS];
uniform float u_drag_k[DRAGS];      // N/m
uniform vec3 u_drag_target[DRAGS];  // target(t) at this stage's time
#endif

vec3 external_force(int node, int groups, vec3 x) {
    vec3 f = vec3(0.0);
#if LOADS > 0
    for (int g = 0; g < LOADS; ++g) {
        if (((groups >> g) & 1) != 0) {
            f += u_load[g];
        }
    }
#endif
#if DRAGS > 0
    for (int k = 0; k < DRAGS; ++k) {
        if (u_drag_node[k] == node) {
            f += u_drag_k[k] * (u_drag_target[k] - x);
        }
    }
#endif
    return f;
}
