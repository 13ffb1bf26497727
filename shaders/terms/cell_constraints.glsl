// The cells' XPBD constraints (Macklin, Muller & Chentanez 2016, eq. 17-18; docs/EQUATIONS.md,
// "XPBD"), the float32 twin of deformgl/sim/terms/volume/xpbd_form.py, on the 3x3x3 neighbourhood of
// terms/cell_forces.glsl (its layout, corner numbering and uniforms):
//   volume constraint per full cell  C = J - 1 (J = det F at the centre), compliance 1 / (kappa V),
//                                    grad_a C = cof(F) G_a, G_a = s_a / (4h)
//   barrier per cell corner c        C = J_c - J_b >= 0 on the tet (c, c^1, c^2, c^4), compliance
//                                    1 / (kappa_b V / 8), gradients from corner_gradients()
// Shared by the cell pass (terms/cell_xpbd.frag: the multipliers) and the node sweep
// (terms/cell_xpbd.glsl in sim/xpbd/iterate.frag: each node gathers its corrections).
#ifndef XPBD_CELL_CONSTRAINTS_GLSL
#define XPBD_CELL_CONSTRAINTS_GLSL
#include "terms/cell_forces.glsl"

// Incident cell q's J = det F at its centre; cof receives cof(F) (columns F1 x F2, F2 x F0,
// F0 x F1), so grad_a J = cof * G_a. F is summed from positions relative to corner 0 (the G_c sum
// to 0), which keeps float32 rounding of the world coordinates out of J - 1.
float centre_jacobian(vec3 p[27], int q, out mat3 cof) {
    float g = 0.25 / u_cell_h;
    vec3 origin = CELL_CORNER(p, q, 0);
    vec3 f0 = vec3(0.0), f1 = vec3(0.0), f2 = vec3(0.0);
    for (int c = 1; c < 8; ++c) {
        vec3 xc = (CELL_CORNER(p, q, c) - origin) * g;
        vec3 s = cell_sign(c);
        f0 += s.x * xc;
        f1 += s.y * xc;
        f2 += s.z * xc;
    }
    cof = mat3(cross(f1, f2), cross(f2, f0), cross(f0, f1));
    return dot(f0, cof[0]);
}

// grad_a C of the volume constraint for the node at corner a, from centre_jacobian's cof.
vec3 centre_gradient(mat3 cof, int a) {
    return cof * (cell_sign(a) * (0.25 / u_cell_h));
}

// grad_a J_c of corner c's tet for the node at corner a (a == c, or a = c ^ 2^k), from the
// neighbour gradients dj of corner_gradients().
vec3 tet_gradient(mat3 dj, int c, int a) {
    int k = a ^ c;
    if (k == 0) {
        return -(dj[0] + dj[1] + dj[2]);
    }
    return k == 1 ? dj[0] : (k == 2 ? dj[1] : dj[2]);
}

#endif
