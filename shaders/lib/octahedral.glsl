// Packed normals (Mosegaard & Sorensen 2005, eq. 3, section 3.2).
// A normal travels in the alpha channel of an RGBA32F position texel as an integer below 2^24
// (exact in float32: no NaN, Inf or denormal bit pattern): two 12-bit octahedral coordinates,
// packed = qx * 4096 + qy. A node without a defined normal stores NO_NORMAL (-1.0).
// NumPy twin: deformgl/normals.py.

const float OCT_LEVELS = 4095.0;
const float NO_NORMAL = -1.0;
const float MIN_SUM_LENGTH = 0.5;  // shorter sums have no reliable direction (normals.py)

vec2 oct_sign_not_zero(vec2 v) {
    return vec2(v.x >= 0.0 ? 1.0 : -1.0, v.y >= 0.0 ? 1.0 : -1.0);
}

// Pack a direction of any length; shorter than MIN_SUM_LENGTH packs NO_NORMAL.
float pack_normal(vec3 v) {
    if (length(v) < MIN_SUM_LENGTH) {
        return NO_NORMAL;
    }
    vec3 p = v / (abs(v.x) + abs(v.y) + abs(v.z));
    vec2 e = p.z >= 0.0 ? p.xy : (1.0 - abs(p.yx)) * oct_sign_not_zero(p.xy);
    vec2 q = floor(clamp(e * 0.5 + 0.5, 0.0, 1.0) * OCT_LEVELS + 0.5);
    return q.x * (OCT_LEVELS + 1.0) + q.y;
}

// Unpack; NO_NORMAL (or any negative value) gives the zero vector.
vec3 unpack_normal(float code) {
    if (code < 0.0) {
        return vec3(0.0);
    }
    float qx = floor(code / (OCT_LEVELS + 1.0));
    float qy = code - qx * (OCT_LEVELS + 1.0);
    vec2 e = vec2(qx, qy) / OCT_LEVELS * 2.0 - 1.0;
    float z = 1.0 - abs(e.x) - abs(e.y);
    float t = max(-z, 0.0);
    vec2 xy = e - t * oct_sign_not_zero(e);
    return normalize(vec3(xy, z));
}
