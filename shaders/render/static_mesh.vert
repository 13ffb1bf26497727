#version 330 core
// A mesh drawn as stored (no mapping): the baseline of `deformgl bench render`.
in vec3 in_position;
in vec3 in_normal;
uniform mat4 u_view_projection;
out vec3 v_world;
out vec3 v_normal;
void main() {
    v_world = in_position;
    v_normal = in_normal;
    gl_Position = u_view_projection * vec4(in_position, 1.0);
}
