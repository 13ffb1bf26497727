// Normals through a trilinear transform, at the vertex's own Jacobian J (section 4.2).
// direct (NORMALS_TANGENT 0): J n, smooth across cells, not always orthogonal to the surface.
// tangent frame (NORMALS_TANGENT 1): sign(det J) (J t) x (J b) with t x b = n: orthogonal to the
// deformed surface, with seams at cell borders. Default: direct.
#ifndef NORMALS_TANGENT
#define NORMALS_TANGENT 0
#endif
vec3 transform_normal(mat3 J, vec3 n) {
#if NORMALS_TANGENT
    vec3 helper = abs(n.x) < 0.9 ? vec3(1.0, 0.0, 0.0) : vec3(0.0, 1.0, 0.0);
    vec3 t = normalize(cross(helper, n));
    vec3 b = cross(n, t);
    vec3 m = cross(J * t, J * b);
    return normalize(determinant(J) < 0.0 ? -m : m);
#else
    return normalize(J * n);
#endif
}
