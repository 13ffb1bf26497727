// The force of one spring on node i (Movania & Feng 2012, eq. 2, with the damping term of
// docs/EQUATIONS.md, "Spring force and damping"), the same as deformgl/sim/springs.py forces():
//   d = x_i - x_j, u = d/|d| (0 for |d| = 0),
//   f = k (L - |d|) u - c_s ((v_i - v_j) . u) u   (the damping term only with SPRING_DAMPING).
// Shared by both integrator backends: sim/integrators/forces.glsl (grid neighbours) and
// feedback/forces.glsl (explicit spring lists). Without SPRING_DAMPING, c and dv are unused.

vec3 spring_force(vec3 d, float rest, float k, float c, vec3 dv) {
    float len = length(d);
    vec3 u = len > 0.0 ? d / len : vec3(0.0);
    float scale = k * (rest - len);
#ifdef SPRING_DAMPING
    scale -= c * dot(dv, u);
#endif
    return scale * u;
}
