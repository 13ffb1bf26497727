#version 330 core
// Midpoint (RK2) method, first pass (docs/EQUATIONS.md, Movania & Feng 2012 section 3):
//   x_m = x + dt/2 v,  v_m = v + dt/2 a(x, v, t)
// into the stage buffer (transform feedback), read by feedback/midpoint_full.vert.
#include "feedback/state.glsl"
uniform sampler2D u_state;  // 2 slots per node: x (w mass), v
uniform float u_dt;
vec4 eval_x(int j) { return slot(u_state, 2, j, 0); }
vec3 eval_v(int j) { return slot(u_state, 2, j, 1).xyz; }
#include "feedback/forces.glsl"
out vec4 out_x;
out vec4 out_v;
void main() {
    int i = gl_VertexID;
    ivec4 info = node_info(i);
    vec4 x = eval_x(i);
    vec3 v = eval_v(i);
    vec3 a = list_acceleration(i, info, x, v);
    float h = 0.5 * u_dt;
    out_x = vec4(x.xyz + h * v, x.w);
    out_v = vec4(v + h * a, 0.0);
}
