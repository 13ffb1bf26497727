// The uniform quadratic B-spline on the node grid (deformgl/sim/terms/spline/basis.py): the three
// functions of a knot span along one axis at span coordinate s in [-1/2, 1/2] (values
// ((1/2 - s)^2 / 2, 3/4 - s^2, (1/2 + s)^2 / 2) of the nodes at offsets -1, 0, +1, and their
// slopes d/ds), and the offset from the span's centre node of its node a = 9 (dx + 1) + 3 (dy + 1)
// + (dz + 1) (z fastest). Shared by the spline terms' span passes and the mapping through the field.
void bspline_axis(float s, out vec3 value, out vec3 slope) {
    value = vec3(0.5 * (0.5 - s) * (0.5 - s), 0.75 - s * s, 0.5 * (0.5 + s) * (0.5 + s));
    slope = vec3(s - 0.5, -2.0 * s, s + 0.5);
}

ivec3 bspline_offset(int a) {
    return ivec3(a / 9, (a / 3) % 3, a % 3) - ivec3(1);
}
