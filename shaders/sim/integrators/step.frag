#version 330 core
// One pass of a fragment-pass integrator on the node grid (Mosegaard & Sorensen 2005, 3.1:
// one texel per node, state in RGBA32F textures; Movania & Feng 2012, section 3: the five
// integrators, their lost formulas as in docs/EQUATIONS.md; the float64 reference is
// deformgl/sim/integrators.py). Exactly one method define selects the pass:
//   EULER          x' = x + dt v,  v' = v + dt a(x, v)                      (Movania & Feng 2012, eq. 4-5)
//   SEMI_IMPLICIT  v' = v + dt a(x, v),  x' = x + dt v'                     (Movania & Feng 2012, eq. 7: "implicit")
//   MIDPOINT_HALF  stage (x_m, v_m) = (x + dt/2 v, v + dt/2 a(x, v))
//   MIDPOINT_FULL  x' = x + dt v_m,  v' = v + dt a(x_m, v_m)
//   RK4_STAGE k    (k = 1, 2, 3) k_k = (v_s, a(x_s, v_s)) at the previous stage state (stage 1:
//                  (x, v)); next stage state (x, v) + c k_k, c = dt/2, dt/2, dt; running sum
//                  k_1 + 2 k_2 + 2 k_3 in two more render targets
//   RK4_FINAL      k_4 at the stage-3 state; x' = x + dt/6 (sum_x + k4_x), v' likewise
//   VERLET         x' = 2x - x_prev + dt^2 a(x, v), v = (x - x_prev)/dt           (Movania & Feng 2012, eq. 6)
// Passes that write x and v write both at once (multiple render targets). The last pass of a
// step applies the constraints (CONSTRAINTS). Fixed nodes and padding texels copy x bit for bit
// (velocity 0). Without a method define the pass is VERLET (deformgl's default integrator).
#if !defined(EULER) && !defined(SEMI_IMPLICIT) && !defined(MIDPOINT_HALF) && !defined(MIDPOINT_FULL) && !defined(RK4_STAGE) && !defined(RK4_FINAL) && !defined(VERLET)
#define VERLET
#endif
#include "lib/node_flags.glsl"

uniform sampler2D u_node;   // RGBA32F static: R mass kg, G flags (1 exists, 2 fixed), B load groups
uniform sampler2D u_x;      // xyz position at t
uniform float u_dt;
#ifdef VERLET
uniform sampler2D u_x_prev; // xyz position at t - dt
#define EVAL_X(T) texelFetch(u_x, T, 0).xyz
#define EVAL_V(T) ((texelFetch(u_x, T, 0).xyz - texelFetch(u_x_prev, T, 0).xyz) / u_dt)
#else
uniform sampler2D u_v;      // xyz velocity at t
#ifdef EVAL_STAGE
uniform sampler2D u_xs;     // stage state at which forces are evaluated
uniform sampler2D u_vs;
#define EVAL_X(T) texelFetch(u_xs, T, 0).xyz
#define EVAL_V(T) texelFetch(u_vs, T, 0).xyz
#else
#define EVAL_X(T) texelFetch(u_x, T, 0).xyz
#define EVAL_V(T) texelFetch(u_v, T, 0).xyz
#endif
#ifdef READ_SUMS
uniform sampler2D u_sum_x;  // RK4 running sum of the stage slopes
uniform sampler2D u_sum_v;
#endif
#endif

#include "sim/integrators/forces.glsl"
#include "lib/constraints.glsl"

layout(location = 0) out vec4 o_x;
#ifndef VERLET
layout(location = 1) out vec4 o_v;
#endif
#ifdef WRITE_SUMS
layout(location = 2) out vec4 o_sum_x;
layout(location = 3) out vec4 o_sum_v;
#endif

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    vec4 node = texelFetch(u_node, texel, 0);
    int flags = int(node.g);
    vec4 x = texelFetch(u_x, texel, 0);
    if ((flags & FLAG_EXISTS) == 0 || (flags & FLAG_FIXED) != 0) {
        // padding texel or fixed node: position bit for bit, no velocity, no slope
        o_x = x;
#ifndef VERLET
        o_v = vec4(0.0);
#endif
#ifdef WRITE_SUMS
        o_sum_x = vec4(0.0);
        o_sum_v = vec4(0.0);
#endif
        return;
    }
    float m = node.r;
    int groups = int(node.b);
    float dt = u_dt;
#ifdef VERLET
    vec3 v = EVAL_V(texel);
    vec3 a = grid_acceleration(texel, x.xyz, v, m, groups);
    vec3 x1 = 2.0 * x.xyz - texelFetch(u_x_prev, texel, 0).xyz + (dt * dt) * a;
#else
    vec3 v = texelFetch(u_v, texel, 0).xyz;
    vec3 xs = EVAL_X(texel);
    vec3 vs = EVAL_V(texel);
    vec3 a = grid_acceleration(texel, xs, vs, m, groups);
#if defined(EULER)
    vec3 x1 = x.xyz + dt * v;
    vec3 v1 = v + dt * a;
#elif defined(SEMI_IMPLICIT)
    vec3 v1 = v + dt * a;
    vec3 x1 = x.xyz + dt * v1;
#elif defined(MIDPOINT_HALF)
    vec3 x1 = x.xyz + (0.5 * dt) * v;
    vec3 v1 = v + (0.5 * dt) * a;
#elif defined(MIDPOINT_FULL)
    vec3 x1 = x.xyz + dt * vs;
    vec3 v1 = v + dt * a;
#elif defined(RK4_STAGE)
    float c = RK4_STAGE == 3 ? dt : 0.5 * dt;
    vec3 x1 = x.xyz + c * vs;
    vec3 v1 = v + c * a;
#if RK4_STAGE == 1
    o_sum_x = vec4(vs, 0.0);
    o_sum_v = vec4(a, 0.0);
#else
    o_sum_x = vec4(texelFetch(u_sum_x, texel, 0).xyz + 2.0 * vs, 0.0);
    o_sum_v = vec4(texelFetch(u_sum_v, texel, 0).xyz + 2.0 * a, 0.0);
#endif
#elif defined(RK4_FINAL)
    vec3 x1 = x.xyz + (dt / 6.0) * (texelFetch(u_sum_x, texel, 0).xyz + vs);
    vec3 v1 = v + (dt / 6.0) * (texelFetch(u_sum_v, texel, 0).xyz + a);
#endif
#endif
#ifdef CONSTRAINTS
#ifdef VELOCITY
    constrain(x1, v1);
#else
    constrain(x1);
#endif
#endif
    o_x = vec4(x1, 0.0);
#ifndef VERLET
    o_v = vec4(v1, 0.0);
#endif
}
