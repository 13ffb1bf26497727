// The per-node forces of both integrator backends (Movania & Feng 2012, eq. 1, and the
// user-intervention force of section 3), the same as deformgl/sim/springs.py forces() after the
// springs, in the same order:
//   m g - (c + alpha m) v (gravity, global and Rayleigh mass damping), wind_drag (wind - v) (WIND), then
//   loads: force(t) per node on every node of load group g (bit g of the node's groups; a
//          scene's [[physics.pull]]), at most 4 groups; per kilogram (times m) where bit
//          LOADS_PER_KG_BIT of the groups is set (deformgl/sim/springs.py load_groups);
//   drags: a zero-rest-length spring k_d (target(t) - x) pulling one node toward a moving target.
// LOADS and DRAGS are the counts; 0 compiles none of it. Times are the stage's: the host sets
// u_load and u_drag_target before each pass.
#ifndef LOADS
#define LOADS 0
#endif
#ifndef DRAGS
#define DRAGS 0
#endif
uniform vec3 u_gravity;
uniform float u_velocity_damping;
uniform float u_mass_damping;      // Rayleigh alpha, 1/s: -alpha m v
#ifdef WIND
uniform vec3 u_wind;
uniform float u_wind_drag;
#endif
#if LOADS > 0
uniform vec3 u_load[LOADS];         // N per node (N/kg: LOADS_PER_KG_BIT) of each load group at this stage's time
const int LOADS_PER_KG_BIT = 4;
#endif
#if DRAGS > 0
uniform int u_drag_node[DRAGS];
uniform float u_drag_k[DRAGS];      // N/m
uniform vec3 u_drag_target[DRAGS];  // target(t) at this stage's time
#endif

// Adds them to f (the node's spring force so far), term by term as the reference does.
void add_node_forces(inout vec3 f, int node, int groups, vec3 x, vec3 v, float m) {
    f += m * u_gravity - (u_velocity_damping + u_mass_damping * m) * v;
#ifdef WIND
    f += u_wind_drag * (u_wind - v);
#endif
    vec3 f_ext = vec3(0.0);
#if LOADS > 0
    float per = ((groups >> LOADS_PER_KG_BIT) & 1) != 0 ? m : 1.0;
    for (int g = 0; g < LOADS; ++g) {
        if (((groups >> g) & 1) != 0) {
            f_ext += per * u_load[g];
        }
    }
#endif
#if DRAGS > 0
    for (int k = 0; k < DRAGS; ++k) {
        if (u_drag_node[k] == node) {
            f_ext += u_drag_k[k] * (u_drag_target[k] - x);
        }
    }
#endif
    f += f_ext;
}
