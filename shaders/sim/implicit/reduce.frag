#version 330 core
// One level of the GPU sum of per-texel values (RGBA, each channel its own sum; the solver's
// dot products are R, the scaled warm start's two are R and G) for the implicit solver
// (deformgl/sim/backends/implicit_gpu.py): each output texel sums a 4x4 block of u_src within
// its u_size texels; the last level is 1x1. Pairwise-style partial sums keep float32 rounding
// at O(log N) instead of O(N).
uniform sampler2D u_src;
uniform ivec2 u_size;     // texels of u_src that hold values
out vec4 o_sum;

void main() {
    ivec2 base = 4 * ivec2(gl_FragCoord.xy);
    vec4 total = vec4(0.0);
    for (int dy = 0; dy < 4; ++dy) {
        vec4 row = vec4(0.0);
        for (int dx = 0; dx < 4; ++dx) {
            ivec2 t = base + ivec2(dx, dy);
            if (t.x < u_size.x && t.y < u_size.y) {
                row += texelFetch(u_src, t, 0);
            }
        }
        total += row;
    }
    o_sum = total;
}
