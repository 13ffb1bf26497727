#version 330 core
// Mosegaard & Sorensen 2005, eq. 3: normals for node positions that come from outside (a file, an analytic motion, another
// simulator): copies each position and packs the normalised sum of neighbour unit vectors into
// alpha, exactly as the simulation pass does (Mosegaard & Sorensen 2005, 3.2).
#ifndef COMPACT
#define COMPACT  // (the layout this pass reads; a standalone compile gets it too)
#endif
#include "lib/node_flags.glsl"
#include "lib/octahedral.glsl"
#include "lib/springs.glsl"

uniform sampler2D u_position;   // RGBA32F: xyz position (alpha ignored)
uniform sampler2D u_node;       // RGBA32F static node data (node_flags.glsl)
layout(location = 0) out vec4 o_position;

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    vec4 x = texelFetch(u_position, texel, 0);
    vec4 node = texelFetch(u_node, texel, 0);
    if ((int(node.g) & FLAG_EXISTS) == 0) {
        o_position = x;
        return;
    }
    o_position = vec4(x.xyz, pack_normal(spring_sum(u_position, texel, x.xyz, uint(node.b), uint(node.a)).unit_sum));
}
