#version 330 core
// Classical RK4, last stage (docs/EQUATIONS.md, Movania & Feng 2012 section 3):
//   k_4 = (v_3, a(x_3, v_3, t + dt)),  (x', v') = (x, v) + dt/6 (k_1 + 2 k_2 + 2 k_3 + k_4),
// then constraints and fixed nodes.
#include "feedback/state.glsl"
uniform sampler2D u_state;  // 2 slots per node: x (w mass), v
uniform sampler2D u_stage;  // 4 slots per node: x_3 (w mass), v_3, sum_x, sum_v
uniform float u_dt;
vec4 eval_x(int j) { return slot(u_stage, 4, j, 0); }
vec3 eval_v(int j) { return slot(u_stage, 4, j, 1).xyz; }
#include "feedback/forces.glsl"
#include "lib/constraints.glsl"
out vec4 out_x;
out vec4 out_v;
void main() {
    int i = gl_VertexID;
    ivec4 info = node_info(i);
    vec4 x = slot(u_state, 2, i, 0);
    vec3 v = slot(u_state, 2, i, 1).xyz;
    vec4 xs = eval_x(i);
    vec3 kx = eval_v(i);
    vec3 kv = list_acceleration(i, info, xs, kx);
    float c = u_dt / 6.0;
    vec3 x1 = x.xyz + c * (slot(u_stage, 4, i, 2).xyz + kx);
    vec3 v1 = v + c * (slot(u_stage, 4, i, 3).xyz + kv);
#ifdef CONSTRAINTS
    constrain(x1, v1);
#endif
    out_x = info.z != 0 ? x : vec4(x1, x.w);
    out_v = vec4(info.z != 0 ? vec3(0.0) : v1, 0.0);
}
