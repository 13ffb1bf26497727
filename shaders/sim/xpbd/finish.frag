#version 330 core
// XPBD velocity update (Macklin, Muller & Chentanez 2016, Algorithm 1, line 15):
//   v = (x - x^n) / h, x' = x (the last iterate); fixed nodes and padding texels: x^n, v = 0.
#include "lib/node_flags.glsl"

uniform sampler2D u_node;  // as predict.frag
uniform sampler2D u_p;     // the last iterate
uniform sampler2D u_x;     // x^n, the position at the substep's start
uniform float u_h;

layout(location = 0) out vec4 o_x;
layout(location = 1) out vec4 o_v;

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    int flags = int(texelFetch(u_node, texel, 0).g);
    vec4 xn = texelFetch(u_x, texel, 0);
    if ((flags & FLAG_EXISTS) == 0 || (flags & FLAG_FIXED) != 0) {
        o_x = xn;
        o_v = vec4(0.0);
        return;
    }
    vec3 p = texelFetch(u_p, texel, 0).xyz;
    o_x = vec4(p, 0.0);
    o_v = vec4((p - xn.xyz) / u_h, 0.0);
}
