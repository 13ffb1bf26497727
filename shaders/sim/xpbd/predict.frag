#version 330 core
// XPBD prediction (Macklin, Muller & Chentanez 2016, Algorithm 1, line 1; docs/EQUATIONS.md,
// "XPBD"), the same as deformgl/sim/xpbd.py XpbdSolver.substep, in float32:
//   v* = v / (1 + h g) + h a,  x~ = x + h v*,
//   g = mass_damping + (velocity_damping + wind_drag) w,  a = gravity + w (loads(t) + wind_drag wind),
// w the inverse mass. Fixed nodes and padding texels keep x.
#include "lib/node_flags.glsl"
#ifndef LOADS
#define LOADS 0
#endif

uniform sampler2D u_node;  // RGBA32F: R inverse mass 1/kg (0 fixed), G flags, B load groups, A constraints
uniform sampler2D u_x;     // xyz position at the substep's start
uniform sampler2D u_v;     // xyz velocity at the substep's start
uniform float u_h;         // substep, s
uniform vec3 u_gravity;
uniform float u_mass_damping;      // Rayleigh alpha, 1/s
uniform float u_velocity_damping;  // N s/m
#ifdef WIND
uniform vec3 u_wind;
uniform float u_wind_drag;
#endif
#if LOADS > 0
uniform vec3 u_load[LOADS];        // N per node of each load group at the substep's start (N/kg on nodes
                                   // whose groups have bit 4 set: a material scene's pull)
#endif

layout(location = 0) out vec4 o_p;

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    vec4 node = texelFetch(u_node, texel, 0);
    int flags = int(node.g);
    vec4 x = texelFetch(u_x, texel, 0);
    if ((flags & FLAG_EXISTS) == 0 || (flags & FLAG_FIXED) != 0) {
        o_p = x;
        return;
    }
    float w = node.r;
    int groups = int(node.b);
    float g = u_mass_damping + u_velocity_damping * w;
    vec3 f = vec3(0.0);
#ifdef WIND
    g += u_wind_drag * w;
#endif
#if LOADS > 0
    float per = ((groups >> 4) & 1) != 0 ? 1.0 / w : 1.0;  // (a per-kg load's f w is its N/kg)
    for (int k = 0; k < LOADS; ++k) {
        if (((groups >> k) & 1) != 0) {
            f += per * u_load[k];
        }
    }
#endif
#ifdef WIND
    f += u_wind_drag * u_wind;
#endif
    vec3 a = u_gravity + w * f;
    vec3 v = texelFetch(u_v, texel, 0).xyz / (1.0 + u_h * g) + u_h * a;
    o_p = vec4(x.xyz + u_h * v, 0.0);
}
