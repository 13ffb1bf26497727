#version 330 core
// Overlay of nodes (points) and springs (lines) fetched from the state texture (figure 2b).
in ivec2 in_texel;
uniform sampler2D u_position;   // RGBA32F: xyz position, w packed normal
uniform mat4 u_view_projection;
void main() {
    gl_Position = u_view_projection * vec4(texelFetch(u_position, in_texel, 0).xyz, 1.0);
    gl_Position.z -= 1e-4 * gl_Position.w;  // pull lines in front of the surface they lie on
    gl_PointSize = 4.0;
}
