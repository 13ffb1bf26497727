#version 330 core
// A leaf drawn with its one composed transform (Knuth, Kohlhammer & Kuijper, section 4.1), one instance per leaf; the cost per
// vertex is the same whatever the depth of the hierarchy. TRANSFORM_PATH picks the transform:
//   0 affine: 3 rows of a 3x4 matrix on the local position (the cheap path for linear leaves)
//   1 one cuboid: Knuth, Kohlhammer & Kuijper, eq. 4 (CUBOID_FORM 4, rows of C) or eq. 1
//     (CUBOID_FORM 1, rows of the corners)
//   2 grid: hardware trilinear filtering of the leaf's block in the RGBA32F 3D atlas
// Defaults: TRANSFORM_PATH 0, CUBOID_FORM 4 (deformgl's own default).
#ifndef TRANSFORM_PATH
#define TRANSFORM_PATH 0
#endif
#ifndef CUBOID_FORM
#define CUBOID_FORM 4
#endif
#include "trilinear/cuboid.glsl"
#include "trilinear/grid.glsl"
#include "trilinear/normals.glsl"

in vec3 in_position;            // local vertex position (inside the leaf's box)
in vec3 in_normal;              // local unit normal
uniform mat4 u_view_projection;

#if TRANSFORM_PATH == 0
in vec4 i_row0;                 // per instance: rows of the 3x4 affine matrix
in vec4 i_row1;
in vec4 i_row2;
#elif TRANSFORM_PATH == 1
in vec4 i_box_lo;               // per instance: xyz box minimum, w 0
in vec4 i_box_scale;            // per instance: xyz 1 / box size, w 0
in vec4 i_xa;                   // per instance: the 3x8 rows (see cuboid.glsl)
in vec4 i_xb;
in vec4 i_ya;
in vec4 i_yb;
in vec4 i_za;
in vec4 i_zb;
#else
in vec4 i_grid_lo;              // per instance: xyz box minimum, w cells x
in vec4 i_grid_scale;           // per instance: xyz cells / box size, w cells y
in vec4 i_grid_origin;          // per instance: xyz block offset + 0.5 texel, w cells z
#endif

out vec3 v_world;
out vec3 v_normal;

void main() {
    vec3 world;
    mat3 J;
#if TRANSFORM_PATH == 0
    vec4 p = vec4(in_position, 1.0);
    world = vec3(dot(i_row0, p), dot(i_row1, p), dot(i_row2, p));
    J = transpose(mat3(i_row0.xyz, i_row1.xyz, i_row2.xyz));
#elif TRANSFORM_PATH == 1
    vec3 u = (in_position - i_box_lo.xyz) * i_box_scale.xyz;
    Rows3x8 m = Rows3x8(i_xa, i_xb, i_ya, i_yb, i_za, i_zb);
#if CUBOID_FORM == 4
    world = trilinear_poly(m, u);
    J = trilinear_poly_jacobian(m, u);
#else
    world = trilinear_corners(m, u);
    J = trilinear_corners_jacobian(m, u);
#endif
    J = mat3(J[0] * i_box_scale.x, J[1] * i_box_scale.y, J[2] * i_box_scale.z);
#else
    vec3 g = (in_position - i_grid_lo.xyz) * i_grid_scale.xyz;
    vec3 cells = vec3(i_grid_lo.w, i_grid_scale.w, i_grid_origin.w);
    world = grid_point(i_grid_origin.xyz, g);
    J = grid_jacobian(i_grid_origin.xyz, g, cells, world);
    J = mat3(J[0] * i_grid_scale.x, J[1] * i_grid_scale.y, J[2] * i_grid_scale.z);
#endif
    v_world = world;
    v_normal = transform_normal(J, in_normal);
    gl_Position = u_view_projection * vec4(world, 1.0);
}
