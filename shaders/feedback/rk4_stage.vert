#version 330 core
// Classical RK4 on the first-order system y = (x, v), y' = (v, a(x, v, t)) (docs/EQUATIONS.md,
// Movania & Feng 2012 section 3), stage RK4_STAGE (1, 2 or 3) of 4, h = dt/2:
//   k_s = (v_s, a(x_s, v_s)) with (x_1, v_1) = (x, v) and (x_s, v_s) the previous stage state;
//   next stage state (x, v) + c k_s, c = h for stages 1-2, dt for stage 3;
//   running sum k_1 + 2 k_2 + 2 k_3 (read by feedback/rk4_final.vert).
// Output per node: stage x (w mass), stage v, sum_x, sum_v (transform feedback, interleaved).
#ifndef RK4_STAGE
#define RK4_STAGE 1
#endif
#include "feedback/state.glsl"
uniform sampler2D u_state;  // 2 slots per node: x (w mass), v
#if RK4_STAGE > 1
uniform sampler2D u_stage;  // 4 slots per node: x_s (w mass), v_s, sum_x, sum_v
vec4 eval_x(int j) { return slot(u_stage, 4, j, 0); }
vec3 eval_v(int j) { return slot(u_stage, 4, j, 1).xyz; }
#else
vec4 eval_x(int j) { return slot(u_state, 2, j, 0); }
vec3 eval_v(int j) { return slot(u_state, 2, j, 1).xyz; }
#endif
uniform float u_dt;
#include "feedback/forces.glsl"
out vec4 out_x;
out vec4 out_v;
out vec4 out_sum_x;
out vec4 out_sum_v;
void main() {
    int i = gl_VertexID;
    ivec4 info = node_info(i);
    vec4 x = slot(u_state, 2, i, 0);
    vec3 v = slot(u_state, 2, i, 1).xyz;
    vec4 xs = eval_x(i);
    vec3 kx = eval_v(i);
    vec3 kv = list_acceleration(i, info, xs, kx);
#if RK4_STAGE == 3
    float c = u_dt;
#else
    float c = 0.5 * u_dt;
#endif
    out_x = vec4(x.xyz + c * kx, x.w);
    out_v = vec4(v + c * kv, 0.0);
#if RK4_STAGE == 1
    out_sum_x = vec4(kx, 0.0);
    out_sum_v = vec4(kv, 0.0);
#else
    out_sum_x = vec4(slot(u_stage, 4, i, 2).xyz + 2.0 * kx, 0.0);
    out_sum_v = vec4(slot(u_stage, 4, i, 3).xyz + 2.0 * kv, 0.0);
#endif
}
