#version 330 core
// One point per existing node, so only existing nodes cost fragment work.
in ivec2 in_texel;        // the node's texel in the atlas
uniform vec2 u_target_size;
void main() {
    gl_Position = vec4((vec2(in_texel) + 0.5) / u_target_size * 2.0 - 1.0, 0.0, 1.0);
    gl_PointSize = 1.0;
}
