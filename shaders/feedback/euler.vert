#version 330 core
// One explicit Euler step per node (Movania & Feng 2012, eq. 4-5; docs/EQUATIONS.md):
//   x' = x + dt v,  v' = v + dt a(x, v);
// with SEMI_IMPLICIT the paper's "implicit Euler" (Movania & Feng 2012, eq. 7; symplectic):
//   v' = v + dt a(x, v),  x' = x + dt v'.
// A vertex shader run over POINTS, one vertex per node, its outputs captured with transform
// feedback (the paper's section 4 pipeline); then the constraints, then fixed nodes keep x.
#include "feedback/state.glsl"
uniform sampler2D u_state;  // 2 slots per node: x (w mass), v
uniform float u_dt;
vec4 eval_x(int j) { return slot(u_state, 2, j, 0); }
vec3 eval_v(int j) { return slot(u_state, 2, j, 1).xyz; }
#include "feedback/forces.glsl"
#include "lib/constraints.glsl"
out vec4 out_x;
out vec4 out_v;
void main() {
    int i = gl_VertexID;
    ivec4 info = node_info(i);
    vec4 x = eval_x(i);
    vec3 v = eval_v(i);
    vec3 a = list_acceleration(i, info, x, v);
#ifdef SEMI_IMPLICIT
    vec3 v1 = v + u_dt * a;
    vec3 x1 = x.xyz + u_dt * v1;
#else
    vec3 x1 = x.xyz + u_dt * v;
    vec3 v1 = v + u_dt * a;
#endif
#ifdef CONSTRAINTS
    constrain(x1, v1);
#endif
    out_x = info.z != 0 ? x : vec4(x1, x.w);
    out_v = vec4(info.z != 0 ? vec3(0.0) : v1, 0.0);
}
