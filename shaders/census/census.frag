#version 330 core
// Node census: one fragment per node over a row x rows viewport, fragment (i, j) is the node at
// texel (i, j) of the node layout (lib/node_texel.glsl: texel_node, row = 2^u_width_log2). Slot s
// of that node lives at texel slot_texel((i, j), slots, s); only xyz is looked at. COPY writes the slot out (a snapshot); MOVED and BAD keep a fragment only where
// the predicate holds, so an occlusion query over the pass counts the nodes. Without any of the
// three the pass is BAD.

#include "lib/node_texel.glsl"

uniform sampler2D u_state;   // RGBA32F, NEAREST, read with texelFetch
uniform int u_count;         // nodes; texels past the last one are never counted
uniform int u_slots;         // texels per node in u_state
uniform int u_slot;          // which of them

#if defined(MOVED)
uniform sampler2D u_before;
uniform int u_before_slots;
uniform int u_before_slot;
uniform float u_threshold;
#elif !defined(COPY)  // BAD, also the mode without a mode define
uniform float u_limit;
#endif

#ifdef COPY
layout(location = 0) out vec4 o_value;
#else
layout(location = 0) out float o_mark;  // R8 target: only whether the fragment survives counts
#endif

// NaN or +-Inf in any component: exponent bits all ones. A bit test and not isnan/isinf, which
// an optimiser may fold away under the assumption that floats are finite.
bool non_finite(vec3 p) {
    uvec3 exponent = floatBitsToUint(p) & uvec3(0x7f800000u);
    return any(equal(exponent, uvec3(0x7f800000u)));
}

void main() {
    ivec2 node = ivec2(gl_FragCoord.xy);
    if (texel_node(node) >= u_count) discard;
    vec4 x = texelFetch(u_state, slot_texel(node, u_slots, u_slot), 0);
#if defined(COPY)
    o_value = x;
#else
#if defined(MOVED)
    vec3 b = texelFetch(u_before, slot_texel(node, u_before_slots, u_before_slot), 0).xyz;
    // a non-finite position on either side counts as moved (it is not at rest)
    bool keep = non_finite(x.xyz) || non_finite(b) || length(x.xyz - b) > u_threshold;
#else
    bool keep = non_finite(x.xyz) || any(greaterThan(abs(x.xyz), vec3(u_limit)));
#endif
    if (!keep) discard;
    o_mark = 1.0;
#endif
}
