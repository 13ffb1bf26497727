#version 330 core
// Second stage of the two-stage mapping: the mapped vertices were written to a buffer by
// render/mapped_mesh.vert under transform feedback (once per vertex, not once per index), and
// are drawn from it as a plain mesh. Outputs as mapped_mesh.vert, for render/mapped_mesh.frag.
in vec3 in_world;
in vec3 in_normal;
#ifdef NORMAL_MAP
in vec3 in_tangent;
in float in_handedness;
in vec2 in_uv;
out vec3 v_tangent;
out float v_handedness;
out vec2 v_uv;
#endif
uniform mat4 u_view_projection;
out vec3 v_world;
out vec3 v_normal;

void main() {
    v_world = in_world;
    v_normal = in_normal;
#ifdef NORMAL_MAP
    v_tangent = in_tangent;
    v_handedness = in_handedness;
    v_uv = in_uv;
#endif
    gl_Position = u_view_projection * vec4(in_world, 1.0);
}
