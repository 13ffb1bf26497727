#version 330 core
// Midpoint (RK2) method, second pass: the full step with the midpoint slopes
//   x' = x + dt v_m,  v' = v + dt a(x_m, v_m, t + dt/2)
// (docs/EQUATIONS.md, Movania & Feng 2012 section 3), then constraints and fixed nodes.
#include "feedback/state.glsl"
uniform sampler2D u_state;  // 2 slots per node: x (w mass), v
uniform sampler2D u_stage;  // 2 slots per node: x_m (w mass), v_m
uniform float u_dt;
vec4 eval_x(int j) { return slot(u_stage, 2, j, 0); }
vec3 eval_v(int j) { return slot(u_stage, 2, j, 1).xyz; }
#include "feedback/forces.glsl"
#include "lib/constraints.glsl"
out vec4 out_x;
out vec4 out_v;
void main() {
    int i = gl_VertexID;
    ivec4 info = node_info(i);
    vec4 x = slot(u_state, 2, i, 0);
    vec3 v = slot(u_state, 2, i, 1).xyz;
    vec4 xm = eval_x(i);
    vec3 vm = eval_v(i);
    vec3 a = list_acceleration(i, info, xm, vm);
    vec3 x1 = x.xyz + u_dt * vm;
    vec3 v1 = v + u_dt * a;
#ifdef CONSTRAINTS
    constrain(x1, v1);
#endif
    out_x = info.z != 0 ? x : vec4(x1, x.w);
    out_v = vec4(info.z != 0 ? vec3(0.0) : v1, 0.0);
}
