// The state textures of a BLOCKED layout (deformgl/grid/blocks.py BlockedLayout): member m of
// every block is texture u_position<m> (RGBA32F, xyz position, w packed normal), one render
// target per member. GLSL 3.30 and ES 3.00 index sampler arrays by constant expressions only, so
// the members are named; state_at folds to one fetch where m is a constant (the block passes).
#include "lib/block_shape.glsl"
#define MEMBERS (BLOCK_X * BLOCK_Y * BLOCK_Z)

uniform sampler2D u_position0;
#if MEMBERS > 1
uniform sampler2D u_position1;
#endif
#if MEMBERS > 2
uniform sampler2D u_position2;
uniform sampler2D u_position3;
#endif
#if MEMBERS > 4
uniform sampler2D u_position4;
uniform sampler2D u_position5;
uniform sampler2D u_position6;
uniform sampler2D u_position7;
#endif

// The state texel of member m at block texel t.
vec4 state_at(int m, ivec2 t) {
#if MEMBERS > 4
    if (m == 7) return texelFetch(u_position7, t, 0);
    if (m == 6) return texelFetch(u_position6, t, 0);
    if (m == 5) return texelFetch(u_position5, t, 0);
    if (m == 4) return texelFetch(u_position4, t, 0);
#endif
#if MEMBERS > 2
    if (m == 3) return texelFetch(u_position3, t, 0);
    if (m == 2) return texelFetch(u_position2, t, 0);
#endif
#if MEMBERS > 1
    if (m == 1) return texelFetch(u_position1, t, 0);
#endif
    return texelFetch(u_position0, t, 0);
}
