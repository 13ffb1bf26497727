#version 330 core
// The spline body's mapping (deformgl/render/bspline_premap.py; docs/EQUATIONS.md "Spline cells"):
// one fragment per detailed-mesh vertex, vertex v at texel node_texel(v) of the outputs, drawn
// through the B-spline field the body was solved with: x(X) = sum_a N_a(X) x_a over the 27 control
// points of the vertex's knot span, its normal the rest normal turned by the field's cofactor
// cof F = det(F) F^-T, F = sum_a x_a grad N_a(X)^T (what was solved is what is drawn). The outputs
// are those of render/mapped_premap.frag, so render/mapped_premapped.vert draws them.
//
// u_vertex_nodes RGBA32I array, 7 layers: the span's 27 node numbers, node a in channel a % 4 of
//   layer a / 4 (a = 9 (dx + 1) + 3 (dy + 1) + (dz + 1), the offset from the span's centre node,
//   a = 13);
// u_vertex_data RGBA32F array, 2 layers: 0 xyz the vertex's span coordinates (in [-1/2, 1/2]:
//   (X - X_centre) / h), 1 xyz its rest normal.
#include "lib/node_texel.glsl"
#include "lib/bspline.glsl"

uniform sampler2D u_position;           // RGBA32F node positions (xyz, m), node layout
uniform isampler2DArray u_vertex_nodes;
uniform sampler2DArray u_vertex_data;
uniform float u_h;                      // grid spacing h, m

layout(location = 0) out vec4 o_world;   // xyz mapped position, m
layout(location = 1) out vec4 o_normal;  // xyz mapped normal (not normalised)

void main() {
    ivec2 t = ivec2(gl_FragCoord.xy);
    vec3 s = texelFetch(u_vertex_data, ivec3(t, 0), 0).xyz;
    vec3 rest_normal = texelFetch(u_vertex_data, ivec3(t, 1), 0).xyz;
    vec3 vx, dx, vy, dy, vz, dz;
    bspline_axis(s.x, vx, dx);
    bspline_axis(s.y, vy, dy);
    bspline_axis(s.z, vz, dz);
    // about the centre node (the basis sums to 1, its gradients to 0): float32 at the scale of h
    int centre = texelFetch(u_vertex_nodes, ivec3(t, 3), 0)[1];
    vec3 xc = texelFetch(u_position, node_texel(centre), 0).xyz;
    vec3 x = vec3(0.0);
    mat3 F = mat3(0.0);
    for (int l = 0; l < 7; ++l) {
        ivec4 nodes = texelFetch(u_vertex_nodes, ivec3(t, l), 0);
        for (int c = 0; c < 4; ++c) {
            int a = 4 * l + c;
            if (a < 27) {
                int i = a / 9;
                int j = (a / 3) % 3;
                int k = a % 3;
                vec3 d = texelFetch(u_position, node_texel(nodes[c]), 0).xyz - xc;
                x += (vx[i] * vy[j] * vz[k]) * d;
                F += outerProduct(d, vec3(dx[i] * vy[j] * vz[k], vx[i] * dy[j] * vz[k], vx[i] * vy[j] * dz[k]));
            }
        }
    }
    F /= u_h;
    mat3 cofactor = mat3(cross(F[1], F[2]), cross(F[2], F[0]), cross(F[0], F[1]));
    o_world = vec4(xc + x, 1.0);
    o_normal = vec4(cofactor * rest_normal, 0.0);
}
