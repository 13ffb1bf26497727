// One trilinear cuboid (Knuth, Kohlhammer & Kuijper, section 3.2), both forms, with Jacobians.
// A 3x8 matrix is passed as six vec4: row x = (xa, xb), row y = (ya, yb), row z = (za, zb).
// Knuth, Kohlhammer & Kuijper, eq. 4: the rows of C (eq. 2) times v = (xyz, yz, xz, xy | z, y, x, 1) (eq. 3).
// Knuth, Kohlhammer & Kuijper, eq. 1: the rows of (p0 ... p7)^T times the corner weights (corner i = x + 2y + 4z).
struct Rows3x8 {
    vec4 xa, xb, ya, yb, za, zb;
};

vec3 rows_times(Rows3x8 m, vec4 a, vec4 b) {
    return vec3(dot(m.xa, a) + dot(m.xb, b), dot(m.ya, a) + dot(m.yb, b), dot(m.za, a) + dot(m.zb, b));
}

// Knuth, Kohlhammer & Kuijper, eq. 3, split in two halves: a = (xyz, yz, xz, xy), b = (z, y, x, 1)
void parameter_vector(vec3 u, out vec4 a, out vec4 b) {
    float yz = u.y * u.z;
    a = vec4(u.x * yz, yz, u.x * u.z, u.x * u.y);
    b = vec4(u.z, u.y, u.x, 1.0);
}

// Knuth, Kohlhammer & Kuijper, eq. 4: v' = C v
vec3 trilinear_poly(Rows3x8 c, vec3 u) {
    vec4 a, b;
    parameter_vector(u, a, b);
    return rows_times(c, a, b);
}

// d/du of Knuth, Kohlhammer & Kuijper, eq. 4: columns are the partial derivatives along x, y, z of the unit cube
mat3 trilinear_poly_jacobian(Rows3x8 c, vec3 u) {
    return mat3(rows_times(c, vec4(u.y * u.z, 0.0, u.z, u.y), vec4(0.0, 0.0, 1.0, 0.0)),
                rows_times(c, vec4(u.x * u.z, u.z, 0.0, u.x), vec4(0.0, 1.0, 0.0, 0.0)),
                rows_times(c, vec4(u.x * u.y, u.y, u.x, 0.0), vec4(1.0, 0.0, 0.0, 0.0)));
}

// Knuth, Kohlhammer & Kuijper, eq. 1: weights of corners 0-3 (a) and 4-7 (b)
void corner_weights(vec3 u, out vec4 a, out vec4 b) {
    vec4 xy = vec4((1.0 - u.x) * (1.0 - u.y), u.x * (1.0 - u.y), (1.0 - u.x) * u.y, u.x * u.y);
    a = xy * (1.0 - u.z);
    b = xy * u.z;
}

// Knuth, Kohlhammer & Kuijper, eq. 1: sum of w_i p_i; p holds the corner coordinates as rows (x of p0..p7, y..., z...)
vec3 trilinear_corners(Rows3x8 p, vec3 u) {
    vec4 a, b;
    corner_weights(u, a, b);
    return rows_times(p, a, b);
}

mat3 trilinear_corners_jacobian(Rows3x8 p, vec3 u) {
    vec4 dx = vec4(-(1.0 - u.y), 1.0 - u.y, -u.y, u.y);
    vec4 dy = vec4(-(1.0 - u.x), -u.x, 1.0 - u.x, u.x);
    vec4 xy = vec4((1.0 - u.x) * (1.0 - u.y), u.x * (1.0 - u.y), (1.0 - u.x) * u.y, u.x * u.y);
    return mat3(rows_times(p, dx * (1.0 - u.z), dx * u.z),
                rows_times(p, dy * (1.0 - u.z), dy * u.z),
                rows_times(p, -xy, xy));
}
