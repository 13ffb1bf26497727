// Packed normals (Mosegaard & Sorensen 2005, eq. 3, section 3.2). NumPy twin: deformgl/sim/normals.py.
// A normal travels in the alpha channel of an RGBA32F position texel as a positive *normal*
// float (never NaN, Inf or denormal, so any float32 render target carries it exactly): the
// octahedral coordinates quantised to 46,159 steps each give c = qx * 46159 + qy < 2^31 - 2^24,
// stored as the float with bit pattern c + 2^23. Round trip error at most 0.006 degrees.
// A node without a defined normal stores NO_NORMAL = 0.0.

const float OCT_LEVELS = 46158.0;
const uint OCT_STEPS = 46159u;
const uint OCT_BIAS = 8388608u;  // 2^23
const float NO_NORMAL = 0.0;
const float MIN_SUM_LENGTH = 0.5;  // shorter sums have no reliable direction (sim/normals.py)

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
    uvec2 q = uvec2(floor(clamp(e * 0.5 + 0.5, 0.0, 1.0) * OCT_LEVELS + 0.5));
    return uintBitsToFloat(q.x * OCT_STEPS + q.y + OCT_BIAS);
}

// Whether a packed value holds a normal (false for NO_NORMAL).
bool has_normal(float code) {
    return floatBitsToUint(code) >= OCT_BIAS;
}

// Unpack; NO_NORMAL gives the zero vector.
vec3 unpack_normal(float code) {
    uint bits = floatBitsToUint(code);
    if (bits < OCT_BIAS) {
        return vec3(0.0);
    }
    uint c = bits - OCT_BIAS;
    uint qx = c / OCT_STEPS;
    vec2 e = vec2(float(qx), float(c - qx * OCT_STEPS)) / OCT_LEVELS * 2.0 - 1.0;
    float z = 1.0 - abs(e.x) - abs(e.y);
    float t = max(-z, 0.0);
    vec2 xy = e - t * oct_sign_not_zero(e);
    return normalize(vec3(xy, z));
}
