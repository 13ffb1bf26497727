// Constraints after the step (Movania & Feng 2012 section 4: the "positivity" ground constraint
// y' = max(y', y_ground) and the sphere collision x' = s + r (x' - s)/|x' - s| when |x' - s| < r;
// docs/EQUATIONS.md), as deformgl/sim/integrators.py apply_constraints(): spheres in order, then the
// ground. Shared by both GPU backends (shaders/feedback/*.vert, shaders/sim/integrators/step.frag).
// With VELOCITY (every integrator but Verlet) a contact is inelastic and frictionless: the
// velocity along the contact normal n becomes max(v . n, u . n), u the obstacle's velocity over
// the step (0 for the ground). Verlet needs no velocity rule: its next backward difference
// contains the projection. Compiled only with CONSTRAINTS (GROUND and/or SPHERES > 0).
#ifndef SPHERES
#define SPHERES 0
#endif

#ifdef CONSTRAINTS
#ifdef GROUND
uniform float u_ground;
#endif
#if SPHERES > 0
uniform vec4 u_spheres[SPHERES];          // xyz centre at t + dt, w radius
#ifdef VELOCITY
uniform vec3 u_sphere_velocity[SPHERES];  // (centre(t + dt) - centre(t)) / dt
#endif
#endif

#ifdef VELOCITY
void constrain(inout vec3 x, inout vec3 v) {
#else
void constrain(inout vec3 x) {
#endif
#if SPHERES > 0
    for (int k = 0; k < SPHERES; ++k) {
        vec3 centre = u_spheres[k].xyz;
        vec3 rel = x - centre;
        float dist = length(rel);
        vec3 n = dist > 0.0 ? rel / dist : vec3(0.0, 1.0, 0.0);
        if (dist < u_spheres[k].w) {
            x = centre + u_spheres[k].w * n;
#ifdef VELOCITY
            float vn = dot(v, n);
            v += (max(vn, dot(n, u_sphere_velocity[k])) - vn) * n;
#endif
        }
    }
#endif
#ifdef GROUND
    if (x.y < u_ground) {
        x.y = u_ground;
#ifdef VELOCITY
        v.y = max(v.y, 0.0);
#endif
    }
#endif
}
#endif  // CONSTRAINTS
