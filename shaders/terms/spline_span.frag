#version 330 core
// The spline cells' span pass (deformgl/sim/terms/spline/span_pass.py; docs/EQUATIONS.md "Spline
// cells"): the corotational elastic forces of every knot span on its 27 nodes, the float32 twin of
// deformgl/sim/terms/spline/term.py SplineCells.add_forces (with body.py span_forces at the Gauss
// points). Run before each force evaluation of the explicit gathers; terms/spline.glsl gathers a
// node's share from the (up to) 27 spans it belongs to.
//
// One fragment per (span s, group g), SPAN_GROUPS = 7 fragments per span: fragment texel
// slot_texel(row_texel(s, u_span_row), 7, g). Each computes its span's stresses at the 27 Gauss
// points and writes the forces on the span's nodes a = 4 g + o (o = 0..3, a < 27) to output o,
// N (xyz; w 0), in the world frame.
//
// Per span (deformgl/sim/terms/spline/tables.py SpanTables):
//   u_span_nodes RGBA32I, 7 texels: its 27 node numbers, node a in channel a % 4 of texel a / 4
//     (a = 9 (dx + 1) + 3 (dy + 1) + (dz + 1), the offset from the span's centre node, a = 13);
//   u_span_data RGBA32F, 15 texels: 0-2 the Gauss points' span coordinates along x, y, z (rgb:
//     the three of that axis; point q = 9 l + 3 m + n at (x_l, y_m, z_n)); 3-9 the weights w_q,
//     m^3, channel q % 4 of texel 3 + q / 4; 10 rgb the material's centroid (span coordinates,
//     where the rotation is taken), a the projection's function count P (0: the volumetric strain
//     itself, 1: its mean, 4: its linear L2 projection); 11-14 the inverse Gram matrix of those
//     functions, m^-3, row k in texel 11 + k; 15-17 the Gauss points' coordinates along x, y, z
//     minus the centroid's (rgb; the projection's linear functions, rounded once from float64).
//
// Quadratic B-spline per axis at span coordinate s in [-1/2, 1/2] (body.py, basis.py): the values
// ((1/2 - s)^2 / 2, 3/4 - s^2, (1/2 + s)^2 / 2) of the nodes at -1, 0, +1, slopes d/ds
// (s - 1/2, -2 s, s + 1/2). Rotation: the polar decomposition of F at the centroid, proper also
// where det F <= 0 (the smallest singular direction flipped: Irving, Teran & Fedkiw 2004, sec. 5),
// by a Jacobi eigen-decomposition of F^T F. Local displacements u~_a = R^T (x_a - x_c) - h d_a;
// strain, B-bar projected volumetric strain, stress 2 mu dev(eps) + kappa theta~ I; forces
// f_a = -R sum_q w_q sigma_q grad N_a(x_q).
#include "lib/node_texel.glsl"
#include "lib/bspline.glsl"
#include "terms/spline_spans.glsl"

uniform sampler2D u_x;             // RGBA32F positions at the evaluation state (node_texel), m
uniform isampler2D u_span_nodes;   // RGBA32I span nodes (above)
uniform sampler2D u_span_data;     // RGBA32F span data (above)
uniform int u_spans;               // spans
uniform float u_h;                 // grid spacing h, m
uniform float u_mu;                // shear modulus, Pa
uniform float u_kappa;             // bulk modulus, Pa

layout(location = 0) out vec4 o_f0;
layout(location = 1) out vec4 o_f1;
layout(location = 2) out vec4 o_f2;
layout(location = 3) out vec4 o_f3;

const int SPAN_GROUPS = 7;
const int SPAN_DATA = 18;

// One Jacobi rotation of the symmetric A zeroing A[p][q], accumulated into V (Numerical Recipes, 11.1).
void jacobi(inout mat3 A, inout mat3 V, int p, int q) {
    float apq = A[q][p];
    if (abs(apq) <= 1e-30 * (abs(A[p][p]) + abs(A[q][q]))) {
        return;
    }
    float theta = (A[q][q] - A[p][p]) / (2.0 * apq);
    // (theta^2 would overflow: t ~ 1 / (2 theta), Numerical Recipes 11.1.8's guard)
    float t = abs(theta) > 1e18 ? 0.5 / theta : (theta >= 0.0 ? 1.0 : -1.0) / (abs(theta) + sqrt(theta * theta + 1.0));
    float c = inversesqrt(t * t + 1.0);
    float s = t * c;
    mat3 J = mat3(1.0);
    J[p][p] = c;
    J[q][q] = c;
    J[q][p] = s;   // (row p, column q)
    J[p][q] = -s;  // (row q, column p)
    A = transpose(J) * A * J;
    V = V * J;
}

// The rotation of the polar decomposition F = R S, det R = +1.
mat3 polar_rotation(mat3 F) {
    mat3 A = transpose(F) * F;
    mat3 V = mat3(1.0);
    for (int sweep = 0; sweep < 6; ++sweep) {
        jacobi(A, V, 0, 1);
        jacobi(A, V, 0, 2);
        jacobi(A, V, 1, 2);
    }
    vec3 l = vec3(A[0][0], A[1][1], A[2][2]);
    // sort descending (columns of V with them)
    if (l.x < l.y) { l.xy = l.yx; V = mat3(V[1], V[0], V[2]); }
    if (l.y < l.z) { l.yz = l.zy; V = mat3(V[0], V[2], V[1]); }
    if (l.x < l.y) { l.xy = l.yx; V = mat3(V[1], V[0], V[2]); }
    if (determinant(V) < 0.0) {
        V[2] = -V[2];
    }
    vec3 a = F * V[0];
    float la = length(a);
    if (!(la > 0.0)) {
        return mat3(1.0);
    }
    vec3 u1 = a / la;
    vec3 b = F * V[1];
    b -= dot(u1, b) * u1;
    float lb = length(b);
    vec3 u2;
    if (lb > 1e-6 * la) {
        u2 = b / lb;
    } else {  // rank 1: any direction normal to u1
        vec3 axis = abs(u1.x) < 0.577 ? vec3(1.0, 0.0, 0.0) : vec3(0.0, 1.0, 0.0);
        u2 = normalize(cross(u1, axis));
    }
    mat3 U = mat3(u1, u2, cross(u1, u2));
    return U * transpose(V);
}

float span_weight(int s, int q) {
    return texelFetch(u_span_data, span_texel(s, SPAN_DATA, 3 + q / 4), 0)[q % 4];
}

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    ivec2 item = texel_item_slot(texel, SPAN_GROUPS, u_span_row);
    int s = item.x;
    int g = item.y;
    o_f0 = vec4(0.0);
    o_f1 = vec4(0.0);
    o_f2 = vec4(0.0);
    o_f3 = vec4(0.0);
    if (s >= u_spans) {
        return;
    }
    // the span's node positions relative to its centre node
    vec3 p[27];
    int centre = texelFetch(u_span_nodes, span_texel(s, 7, 3), 0)[1];
    vec3 xc = texelFetch(u_x, node_texel(centre), 0).xyz;
    for (int t = 0; t < 7; ++t) {
        ivec4 nodes = texelFetch(u_span_nodes, span_texel(s, 7, t), 0);
        for (int c = 0; c < 4; ++c) {
            int a = 4 * t + c;
            if (a < 27) {
                p[a] = texelFetch(u_x, node_texel(nodes[c]), 0).xyz - xc;
            }
        }
    }
    vec3 axes[3];
    for (int d = 0; d < 3; ++d) {
        axes[d] = texelFetch(u_span_data, span_texel(s, SPAN_DATA, d), 0).xyz;
    }
    vec4 mid = texelFetch(u_span_data, span_texel(s, SPAN_DATA, 10), 0);
    vec3 rel[3];  // the points' coordinates about the centroid, per axis
    for (int d = 0; d < 3; ++d) {
        rel[d] = texelFetch(u_span_data, span_texel(s, SPAN_DATA, 15 + d), 0).xyz;
    }

    // the rotation at the centroid (mid)
    vec3 cv[3];
    vec3 cd[3];
    bspline_axis(mid.x, cv[0], cd[0]);
    bspline_axis(mid.y, cv[1], cd[1]);
    bspline_axis(mid.z, cv[2], cd[2]);
    mat3 F = mat3(1.0);
    for (int a = 0; a < 27; ++a) {
        ivec3 o = bspline_offset(a) + ivec3(1);
        vec3 grad = vec3(cd[0][o.x] * cv[1][o.y] * cv[2][o.z], cv[0][o.x] * cd[1][o.y] * cv[2][o.z],
                         cv[0][o.x] * cv[1][o.y] * cd[2][o.z]) / u_h;
        F += outerProduct(p[a] - u_h * vec3(bspline_offset(a)), grad);
    }
    mat3 R = polar_rotation(F);
    mat3 Rt = transpose(R);
    for (int a = 0; a < 27; ++a) {
        p[a] = Rt * p[a] - u_h * vec3(bspline_offset(a));  // local displacements u~_a
    }

    // the basis along each axis at the Gauss points: component i of V*[l] / D*[l] the value / slope
    // of the function of offset i - 1 at the axis's point l
    vec3 VX[3], DX[3], VY[3], DY[3], VZ[3], DZ[3];
    for (int l = 0; l < 3; ++l) {
        bspline_axis(axes[0][l], VX[l], DX[l]);
        bspline_axis(axes[1][l], VY[l], DY[l]);
        bspline_axis(axes[2][l], VZ[l], DZ[l]);
    }
    // strains at the Gauss points, by sum factorisation (one axis at a time): H_q = sum_a u~_a
    // grad N_a(x_q)^T, its columns sum_ijk u~_ijk (D_i V_j V_k, V_i D_j V_k, V_i V_j D_k) / h
    vec3 A[27];   // [(3 i + j) 3 + n]: sum_k V_k(z_n) u~_ijk
    vec3 B[27];   //                    sum_k D_k(z_n) u~_ijk
    for (int ij = 0; ij < 9; ++ij) {
        for (int n = 0; n < 3; ++n) {
            A[3 * ij + n] = VZ[n].x * p[3 * ij] + VZ[n].y * p[3 * ij + 1] + VZ[n].z * p[3 * ij + 2];
            B[3 * ij + n] = DZ[n].x * p[3 * ij] + DZ[n].y * p[3 * ij + 1] + DZ[n].z * p[3 * ij + 2];
        }
    }
    vec3 AV[27];  // [(3 i + m) 3 + n]: sum_j V_j(y_m) A_ij(n)
    vec3 AD[27];  //                    sum_j D_j(y_m) A_ij(n)
    vec3 BV[27];  //                    sum_j V_j(y_m) B_ij(n)
    for (int i = 0; i < 3; ++i) {
        for (int m = 0; m < 3; ++m) {
            for (int n = 0; n < 3; ++n) {
                int k0 = 9 * i + n;
                AV[9 * i + 3 * m + n] = VY[m].x * A[k0] + VY[m].y * A[k0 + 3] + VY[m].z * A[k0 + 6];
                AD[9 * i + 3 * m + n] = DY[m].x * A[k0] + DY[m].y * A[k0 + 3] + DY[m].z * A[k0 + 6];
                BV[9 * i + 3 * m + n] = VY[m].x * B[k0] + VY[m].y * B[k0 + 3] + VY[m].z * B[k0 + 6];
            }
        }
    }
    mat3 eps[27];
    float theta[27];
    for (int q = 0; q < 27; ++q) {
        int l = q / 9;
        int mn = q % 9;
        vec3 c0 = DX[l].x * AV[mn] + DX[l].y * AV[9 + mn] + DX[l].z * AV[18 + mn];
        vec3 c1 = VX[l].x * AD[mn] + VX[l].y * AD[9 + mn] + VX[l].z * AD[18 + mn];
        vec3 c2 = VX[l].x * BV[mn] + VX[l].y * BV[9 + mn] + VX[l].z * BV[18 + mn];
        mat3 H = mat3(c0, c1, c2) / u_h;  // (column j: sum_a u~_a dN_a/dx_j)
        eps[q] = 0.5 * (H + transpose(H));
        theta[q] = H[0][0] + H[1][1] + H[2][2];
    }

    // the volumetric strain's projection (B-bar): c = G^-1 sum_q w_q phi(q) theta_q
    int functions = int(mid.w + 0.5);
    vec4 rhs = vec4(0.0);
    float w[27];
    for (int q = 0; q < 27; ++q) {
        w[q] = span_weight(s, q);
        vec4 phi = vec4(1.0, rel[0][q / 9], rel[1][(q / 3) % 3], rel[2][q % 3]);
        rhs += w[q] * theta[q] * phi;
    }
    vec4 coefficients = vec4(0.0);
    if (functions == 1) {
        coefficients.x = texelFetch(u_span_data, span_texel(s, SPAN_DATA, 11), 0).x * rhs.x;
    } else if (functions == 4) {
        for (int k = 0; k < 4; ++k) {
            coefficients[k] = dot(texelFetch(u_span_data, span_texel(s, SPAN_DATA, 11 + k), 0), rhs);
        }
    }

    // weighted stresses w_q sigma_q
    mat3 sigma[27];
    for (int q = 0; q < 27; ++q) {
        vec4 phi = vec4(1.0, rel[0][q / 9], rel[1][(q / 3) % 3], rel[2][q % 3]);
        float volumetric = functions == 0 ? theta[q] : dot(phi, coefficients);
        mat3 dev = eps[q] - (theta[q] / 3.0) * mat3(1.0);
        sigma[q] = w[q] * (2.0 * u_mu * dev + (u_kappa * volumetric) * mat3(1.0));
    }

    // the forces on this fragment's nodes
    vec4 out_f[4];
    for (int o = 0; o < 4; ++o) {
        int a = 4 * g + o;
        vec3 f = vec3(0.0);
        if (a < 27) {
            ivec3 k = bspline_offset(a) + ivec3(1);
            for (int q = 0; q < 27; ++q) {
                int l = q / 9;
                int m = (q / 3) % 3;
                int n = q % 3;
                vec3 grad = vec3(DX[l][k.x] * VY[m][k.y] * VZ[n][k.z], VX[l][k.x] * DY[m][k.y] * VZ[n][k.z],
                                 VX[l][k.x] * VY[m][k.y] * DZ[n][k.z]);
                f -= sigma[q] * grad;
            }
            f /= u_h;
        }
        out_f[o] = vec4(R * f, 0.0);
    }
    o_f0 = out_f[0];
    o_f1 = out_f[1];
    o_f2 = out_f[2];
    o_f3 = out_f[3];
}
