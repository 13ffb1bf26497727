#version 330 core
// A spline body's penalty anchor's span pass (deformgl/sim/terms/spline/term.py SplineAnchor;
// docs/EQUATIONS.md "Spline cells"): the forces f_a = -sum_q k w_q N_a(x_q) u(x_q) of the penalty
// k/2 int |u|^2 over a held region's quadrature points, u(x_q) = sum_b N_b(x_q) (x_b - X_b) the
// body's displacement field there, on the 27 nodes of every knot span holding a point. The float32
// twin of SplineAnchor.add_forces; run before each force evaluation of the explicit gathers,
// terms/spline_anchor.glsl gathers a node's share.
//
// One fragment per (span s, group g), 7 a span, at slot_texel(row_texel(s, u_span_row), 7, g);
// output o holds the force on the span's node a = 4 g + o (a < 27), N (xyz; w 0).
// Per span (deformgl/sim/terms/spline/tables.py anchor_tables):
//   u_span_nodes RGBA32I, 7 texels: its 27 node numbers, node a in channel a % 4 of texel a / 4
//     (a = 9 (dx + 1) + 3 (dy + 1) + (dz + 1), the offset from the span's centre node, a = 13);
//   u_span_data RGBA32F, u_span_texels texels: 0 xyz the centre node's rest position (m), w the
//     span's point count P; 1..P xyz a point's span coordinates (in [-1/2, 1/2]), w its weight
//     times the penalty's stiffness (N/m).
#include "lib/node_texel.glsl"
#include "lib/bspline.glsl"
#include "terms/spline_spans.glsl"

uniform sampler2D u_x;             // RGBA32F positions at the evaluation state (node_texel), m
uniform isampler2D u_span_nodes;
uniform sampler2D u_span_data;
uniform int u_spans;               // spans
uniform int u_span_texels;         // data texels a span
uniform float u_h;                 // grid spacing h, m

layout(location = 0) out vec4 o_f0;
layout(location = 1) out vec4 o_f1;
layout(location = 2) out vec4 o_f2;
layout(location = 3) out vec4 o_f3;

const int SPAN_GROUPS = 7;

void main() {
    ivec2 item = texel_item_slot(ivec2(gl_FragCoord.xy), SPAN_GROUPS, u_span_row);
    int s = item.x;
    int g = item.y;
    vec3 f[4] = vec3[4](vec3(0.0), vec3(0.0), vec3(0.0), vec3(0.0));
    if (s < u_spans) {
        // the nodes' displacements, about the centre node's (float32 at the scale of the motion)
        vec3 u[27];
        int centre = texelFetch(u_span_nodes, span_texel(s, 7, 3), 0)[1];
        vec4 head = texelFetch(u_span_data, span_texel(s, u_span_texels, 0), 0);
        vec3 xc = texelFetch(u_x, node_texel(centre), 0).xyz;
        vec3 uc = xc - head.xyz;
        for (int t = 0; t < 7; ++t) {
            ivec4 nodes = texelFetch(u_span_nodes, span_texel(s, 7, t), 0);
            for (int c = 0; c < 4; ++c) {
                int a = 4 * t + c;
                if (a < 27) {
                    u[a] = (texelFetch(u_x, node_texel(nodes[c]), 0).xyz - xc) - u_h * vec3(bspline_offset(a)) + uc;
                }
            }
        }
        int points = int(head.w + 0.5);
        for (int q = 0; q < points; ++q) {
            vec4 point = texelFetch(u_span_data, span_texel(s, u_span_texels, 1 + q), 0);
            vec3 vx, vy, vz, slope;
            bspline_axis(point.x, vx, slope);
            bspline_axis(point.y, vy, slope);
            bspline_axis(point.z, vz, slope);
            vec3 uq = vec3(0.0);
            for (int a = 0; a < 27; ++a) {
                ivec3 k = bspline_offset(a) + ivec3(1);
                uq += (vx[k.x] * vy[k.y] * vz[k.z]) * u[a];
            }
            for (int o = 0; o < 4; ++o) {
                int a = 4 * g + o;
                if (a < 27) {
                    ivec3 k = bspline_offset(a) + ivec3(1);
                    f[o] -= (point.w * vx[k.x] * vy[k.y] * vz[k.z]) * uq;
                }
            }
        }
    }
    o_f0 = vec4(f[0], 0.0);
    o_f1 = vec4(f[1], 0.0);
    o_f2 = vec4(f[2], 0.0);
    o_f3 = vec4(f[3], 0.0);
}
