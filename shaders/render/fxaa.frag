#version 330 core
// Post-process anti-aliasing of a rendered image: FXAA 3.11, its PC "quality" algorithm at
// preset 12 (Lottes 2011, NVIDIA FXAA 3.11 white paper and reference source). Per pixel:
// a local luma contrast below the edge threshold leaves the pixel as it is; otherwise the edge
// is horizontal or vertical by the 3x3 second differences, its two ends are searched along it
// (up to 5 steps of 1 to 12 pixels each way, bilinear taps straddling the edge), and the pixel is
// re-sampled shifted across the edge by its distance to the nearer end (coverage of a stair
// step), or at least by the sub-pixel term of the 3x3 low-pass (lone pixels, thin lines).
// u_colour must be sampled with LINEAR filtering and clamp-to-edge; one fragment per output
// pixel (sim/fullscreen.vert). Luma of the stored (gamma-encoded) colour.
uniform sampler2D u_colour;
uniform vec2 u_texel;  // 1 / (width, height)
out vec4 o_colour;

const float SUBPIX = 0.75;             // amount of sub-pixel smoothing (1: softest)
const float EDGE_THRESHOLD = 0.166;    // least local contrast, a fraction of the local max luma
const float EDGE_THRESHOLD_MIN = 0.0833;  // least local contrast (dark areas)
const int SEARCH_STEPS = 5;
const float STEP[5] = float[5](1.0, 1.5, 2.0, 4.0, 12.0);  // preset 12, pixels per search step

float luma(vec3 c) {
    return dot(c, vec3(0.299, 0.587, 0.114));
}

float luma_at(vec2 uv) {
    return luma(texture(u_colour, uv).rgb);
}

// the 3x3 neighbourhood by texelFetch (no filtering: cheaper than a bilinear tap on llvmpipe),
// clamped to the image as the clamp-to-edge sampler does
float luma_off(ivec2 p, int dx, int dy) {
    ivec2 q = clamp(p + ivec2(dx, dy), ivec2(0), textureSize(u_colour, 0) - 1);
    return luma(texelFetch(u_colour, q, 0).rgb);
}

void main() {
    vec2 pos = gl_FragCoord.xy * u_texel;
    ivec2 pixel = ivec2(gl_FragCoord.xy);
    vec4 centre = texelFetch(u_colour, pixel, 0);
    float m = luma(centre.rgb);
    float s = luma_off(pixel, 0, 1);
    float e = luma_off(pixel, 1, 0);
    float n = luma_off(pixel, 0, -1);
    float w = luma_off(pixel, -1, 0);
    float range_max = max(max(max(n, w), max(e, s)), m);
    float range_min = min(min(min(n, w), min(e, s)), m);
    float range = range_max - range_min;
    if (range < max(EDGE_THRESHOLD_MIN, range_max * EDGE_THRESHOLD)) {
        o_colour = vec4(centre.rgb, 1.0);
        return;
    }
    float nw = luma_off(pixel, -1, -1);
    float se = luma_off(pixel, 1, 1);
    float ne = luma_off(pixel, 1, -1);
    float sw = luma_off(pixel, -1, 1);
    // edge orientation from the second differences of the 3x3 neighbourhood
    float edge_horz = abs(-2.0 * w + nw + sw) + 2.0 * abs(-2.0 * m + n + s) + abs(-2.0 * e + ne + se);
    float edge_vert = abs(-2.0 * s + sw + se) + 2.0 * abs(-2.0 * m + w + e) + abs(-2.0 * n + nw + ne);
    bool horz = edge_horz >= edge_vert;
    // sub-pixel term: the centre against the 3x3 low-pass, in units of the local range
    float lowpass = (2.0 * (n + s + w + e) + (nw + sw + ne + se)) / 12.0;
    float subpix_c = clamp(abs(lowpass - m) / range, 0.0, 1.0);
    float subpix = (-2.0 * subpix_c + 3.0) * subpix_c * subpix_c;
    subpix = subpix * subpix * SUBPIX;
    // the neighbour pair across the edge; step towards the side of the steeper gradient
    float across = horz ? u_texel.y : u_texel.x;
    float l_n = horz ? n : w;
    float l_s = horz ? s : e;
    float grad_n = l_n - m;
    float grad_s = l_s - m;
    bool pair_n = abs(grad_n) >= abs(grad_s);
    float gradient = max(abs(grad_n), abs(grad_s));
    if (pair_n) {
        across = -across;
    }
    float edge_luma = 0.5 * (m + (pair_n ? l_n : l_s));  // mean luma of the two sides
    vec2 along = horz ? vec2(u_texel.x, 0.0) : vec2(0.0, u_texel.y);
    vec2 start = pos + (horz ? vec2(0.0, 0.5 * across) : vec2(0.5 * across, 0.0));
    // search both ends of the edge
    float threshold = 0.25 * gradient;
    vec2 pos_n = start - along * STEP[0];
    vec2 pos_p = start + along * STEP[0];
    float end_n = luma_at(pos_n) - edge_luma;
    float end_p = luma_at(pos_p) - edge_luma;
    bool done_n = abs(end_n) >= threshold;
    bool done_p = abs(end_p) >= threshold;
    for (int i = 1; i < SEARCH_STEPS; i++) {
        if (done_n && done_p) {
            break;
        }
        if (!done_n) {
            pos_n -= along * STEP[i];
            end_n = luma_at(pos_n) - edge_luma;
            done_n = abs(end_n) >= threshold;
        }
        if (!done_p) {
            pos_p += along * STEP[i];
            end_p = luma_at(pos_p) - edge_luma;
            done_p = abs(end_p) >= threshold;
        }
    }
    float dst_n = horz ? pos.x - pos_n.x : pos.y - pos_n.y;
    float dst_p = horz ? pos_p.x - pos.x : pos_p.y - pos.y;
    bool m_below = m - edge_luma < 0.0;
    bool nearer_n = dst_n < dst_p;
    // the nearer end must turn the other way than this pixel's side, else no shift
    bool good = nearer_n ? ((end_n < 0.0) != m_below) : ((end_p < 0.0) != m_below);
    float offset = good ? 0.5 - min(dst_n, dst_p) / (dst_n + dst_p) : 0.0;
    offset = max(offset, subpix);
    vec2 shifted = pos + (horz ? vec2(0.0, offset * across) : vec2(offset * across, 0.0));
    o_colour = vec4(texture(u_colour, shifted).rgb, 1.0);
}
