// Triangle bases of the mappings (Mosegaard & Sorensen 2005, 3.3). NumPy twin: deformgl/mapping/bases.py.
// Each function returns false when the basis cannot be built (a collapsed triangle, normals that
// sum to zero or lie along T); the caller then uses its defined fallback instead of NaN.
// Basis matrices hold the vectors as columns, so basis * o = o.x T + o.y N + o.z B (Mosegaard & Sorensen 2005, eq. 9).

const float DEGENERATE = 1e-6;

vec3 safe_normalize(vec3 v, inout bool ok) {
    float len = length(v);
    ok = ok && len > DEGENERATE;
    return v / max(len, DEGENERATE);
}

// Mosegaard & Sorensen 2005, eq. 6: T = normalize(p2 - p1), Bt = normalize(p3 - p1), N = normalize(T x Bt), B = N x T.
bool constant_basis(vec3 p1, vec3 p2, vec3 p3, out mat3 basis) {
    bool ok = true;
    vec3 t = safe_normalize(p2 - p1, ok);
    vec3 bt = safe_normalize(p3 - p1, ok);
    vec3 n = safe_normalize(cross(t, bt), ok);
    basis = mat3(t, n, cross(n, t));
    return ok;
}

// Mosegaard & Sorensen 2005, eq. 8: Nc = normalize(sum w_i Na(i)), Bc = normalize(Nc x T), Tc = Bc x Nc.
bool curvature_basis(vec3 p1, vec3 p2, vec3 w, vec3 na1, vec3 na2, vec3 na3, out mat3 basis) {
    bool ok = true;
    vec3 t = safe_normalize(p2 - p1, ok);
    vec3 nc = safe_normalize(w.x * na1 + w.y * na2 + w.z * na3, ok);
    vec3 bc = safe_normalize(cross(nc, t), ok);
    basis = mat3(cross(bc, nc), nc, bc);
    return ok;
}
