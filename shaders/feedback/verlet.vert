#version 330 core
// Position Verlet (Movania & Feng 2012, eq. 6; docs/EQUATIONS.md): x' = 2x - x_prev + dt^2 a(x, v)
// with no stored velocity: damping, spring damping and wind see the backward difference
// v = (x - x_prev)/dt (deformgl/sim/integrators.py). Then the constraints (no velocity rule: the next
// backward difference contains the projection) and fixed nodes keep x bit for bit.
#include "feedback/state.glsl"
uniform sampler2D u_x;       // 1 slot per node: x (w mass)
uniform sampler2D u_x_prev;  // 1 slot per node: x one step earlier (w mass)
uniform float u_dt;
vec4 eval_x(int j) { return slot(u_x, 1, j, 0); }
vec3 eval_v(int j) { return (slot(u_x, 1, j, 0).xyz - slot(u_x_prev, 1, j, 0).xyz) / u_dt; }
#include "feedback/forces.glsl"
#include "lib/constraints.glsl"
out vec4 out_x;
void main() {
    int i = gl_VertexID;
    ivec4 info = node_info(i);
    vec4 x = eval_x(i);
    vec3 v = eval_v(i);
    vec3 a = list_acceleration(i, info, x, v);
    vec3 x1 = 2.0 * x.xyz - slot(u_x_prev, 1, i, 0).xyz + (u_dt * u_dt) * a;
#ifdef CONSTRAINTS
    constrain(x1);
#endif
    out_x = info.z != 0 ? x : vec4(x1, x.w);
}
