#version 330 core
// The coarse levels of the multigrid V-cycle that preconditions the implicit step's CG
// (docs/EQUATIONS.md "Multigrid"; float64 reference deformgl/sim/multigrid.py; host
// deformgl/sim/backends/multigrid_gpu.py). Each coarse level is its own compact node texture
// (lib/node_texel.glsl: node n at node_texel(n), w = 2^u_width_log2) holding the Galerkin operator
// A_l = P^T A_{l-1} P of the step's start state as its row's 3x3 blocks (STENCIL_COUNT at most:
// 27 on a body of the 18-neighbour lattice, 25 on a sheet); the finest level's
// smoothing and residual are implicit.frag's MG_SMOOTH and MG_RESIDUAL (its matrix-free A).
// One define selects the pass:
//   LEVEL_SMOOTH    x' = x + W (b - A x), W = w D^-1 (the damped inverse of the node's diagonal
//                   block); with FROM_ZERO x' = W b
//   LEVEL_RESIDUAL  res = b - A x
//   RESTRICT        b_c = sum_k P_kc res_k over the (at most 27) finer nodes k that take a share
//                   of the coarse node c (R = P^T)
//   PROLONG         x' = x + sum_c P_kc e_c over the (at most 8) coarser nodes c of node k
//   COARSEST        x = A^-1 b on the coarsest level, a dense inverse (at most 64 nodes)
//   RZ              per texel R: r . z, G: r . r (CG's z = M^-1 r); with RZ_INIT also p = z
// Texels beyond u_count nodes write 0 (and PROLONG's and RZ's fixed or absent nodes keep 0:
// their tables are empty and their r is 0).
#if !defined(LEVEL_SMOOTH) && !defined(LEVEL_RESIDUAL) && !defined(RESTRICT) && !defined(PROLONG) && !defined(COARSEST) && !defined(RZ)
#define LEVEL_SMOOTH
#endif
#include "lib/node_texel.glsl"

uniform int u_count;            // nodes of this pass's level
#if defined(LEVEL_SMOOTH) || defined(LEVEL_RESIDUAL)
#define STENCIL_COUNT 27  // the most blocks of a row (deformgl/sim/backends/multigrid_gpu.py MAX_STENCIL)
uniform isampler2DArray u_stencil_nb;  // ceil(STENCIL_COUNT / 4) RGBA32I layers: the node's row's
                                       // block columns (-1 past the row's end)
uniform sampler2DArray u_stencil;      // 3 STENCIL_COUNT RGBA32F layers: row r of block j is
                                       // layer 3 j + r (xyz)
uniform sampler2D u_rhs;        // xyz b of the level
#if defined(LEVEL_RESIDUAL) || !defined(FROM_ZERO)
uniform sampler2D u_vec;        // xyz x of the level
#endif
#endif
#ifdef LEVEL_SMOOTH
uniform sampler2DArray u_smoother;     // 3 RGBA32F layers: the rows of W (xyz)
#endif
#if defined(RESTRICT) || defined(PROLONG)
uniform int u_src_width_log2;   // log2 of the width of the level read from
uniform sampler2D u_src;        // xyz the vector transferred (RESTRICT: the finer residual;
                                // PROLONG: the coarser correction)
uniform isampler2DArray u_transfer_nb;  // the source nodes (-1 absent): 7 layers (RESTRICT) or 2
uniform sampler2DArray u_transfer_w;    // their weights, as many layers
#endif
#ifdef PROLONG
uniform sampler2D u_vec;        // xyz x of this level, corrected
#define TRANSFER_COUNT 8
#endif
#ifdef RESTRICT
#define TRANSFER_COUNT 27
#endif
#ifdef COARSEST
uniform sampler2D u_rhs;        // xyz b of the coarsest level
uniform sampler2D u_inverse;    // (u_count, 3 u_count) RGBA32F: texel (j, 3 i + r) is row 3 i + r
                                // of A^-1 at columns 3 j .. 3 j + 2 (xyz)
#endif
#ifdef RZ
uniform sampler2D u_r;          // xyz CG's r (fine level)
uniform sampler2D u_z;          // xyz M^-1 r (the cycle's result)
#endif

layout(location = 0) out vec4 o_0;
#ifdef RZ_INIT
layout(location = 1) out vec4 o_1;
#endif

#if defined(LEVEL_RESIDUAL) || (defined(LEVEL_SMOOTH) && !defined(FROM_ZERO))
// (A x) at this node: its row's blocks times the neighbours' x
vec3 stencil_product(ivec2 texel) {
    vec3 q = vec3(0.0);
    for (int layer = 0; layer < (STENCIL_COUNT + 3) / 4; ++layer) {
        ivec4 nb = texelFetch(u_stencil_nb, ivec3(texel, layer), 0);
        for (int c = 0; c < 4; ++c) {
            int j = 4 * layer + c;
            if (j >= STENCIL_COUNT) {
                break;
            }
            if (nb[c] < 0) {
                continue;
            }
            vec3 y = texelFetch(u_vec, node_texel(nb[c]), 0).xyz;
            q += vec3(dot(texelFetch(u_stencil, ivec3(texel, 3 * j), 0).xyz, y),
                      dot(texelFetch(u_stencil, ivec3(texel, 3 * j + 1), 0).xyz, y),
                      dot(texelFetch(u_stencil, ivec3(texel, 3 * j + 2), 0).xyz, y));
        }
    }
    return q;
}
#endif

#if defined(RESTRICT) || defined(PROLONG)
ivec2 source_texel(int n) {
    return width_texel(n, u_src_width_log2);
}

vec3 transfer(ivec2 texel) {
    vec3 sum = vec3(0.0);
    for (int layer = 0; layer < (TRANSFER_COUNT + 3) / 4; ++layer) {
        ivec4 nb = texelFetch(u_transfer_nb, ivec3(texel, layer), 0);
        vec4 w = texelFetch(u_transfer_w, ivec3(texel, layer), 0);
        for (int c = 0; c < 4; ++c) {
            if (nb[c] >= 0) {
                sum += w[c] * texelFetch(u_src, source_texel(nb[c]), 0).xyz;
            }
        }
    }
    return sum;
}
#endif

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    if (texel_node(texel) >= u_count) {
        o_0 = vec4(0.0);
#ifdef RZ_INIT
        o_1 = vec4(0.0);
#endif
        return;
    }
#if defined(LEVEL_SMOOTH)
    vec3 res = texelFetch(u_rhs, texel, 0).xyz;
#ifdef FROM_ZERO
    vec3 x = vec3(0.0);
#else
    vec3 x = texelFetch(u_vec, texel, 0).xyz;
    res -= stencil_product(texel);
#endif
    o_0 = vec4(x + vec3(dot(texelFetch(u_smoother, ivec3(texel, 0), 0).xyz, res),
                        dot(texelFetch(u_smoother, ivec3(texel, 1), 0).xyz, res),
                        dot(texelFetch(u_smoother, ivec3(texel, 2), 0).xyz, res)), 0.0);
#elif defined(LEVEL_RESIDUAL)
    o_0 = vec4(texelFetch(u_rhs, texel, 0).xyz - stencil_product(texel), 0.0);
#elif defined(RESTRICT)
    o_0 = vec4(transfer(texel), 0.0);
#elif defined(PROLONG)
    o_0 = vec4(texelFetch(u_vec, texel, 0).xyz + transfer(texel), 0.0);
#elif defined(COARSEST)
    int i = texel_node(texel);
    vec3 x = vec3(0.0);
    for (int j = 0; j < u_count; ++j) {
        vec3 b = texelFetch(u_rhs, node_texel(j), 0).xyz;
        x += vec3(dot(texelFetch(u_inverse, ivec2(j, 3 * i), 0).xyz, b),
                  dot(texelFetch(u_inverse, ivec2(j, 3 * i + 1), 0).xyz, b),
                  dot(texelFetch(u_inverse, ivec2(j, 3 * i + 2), 0).xyz, b));
    }
    o_0 = vec4(x, 0.0);
#elif defined(RZ)
    vec3 r = texelFetch(u_r, texel, 0).xyz;
    vec3 z = texelFetch(u_z, texel, 0).xyz;
    o_0 = vec4(dot(r, z), dot(r, r), 0.0, 0.0);
#ifdef RZ_INIT
    o_1 = vec4(z, 0.0);
#endif
#endif
}
