// A grid of trilinear cells (section 3.3) in a 3D texture, interpolated by the texture unit.
// The atlas holds one block of (nx+1) x (ny+1) x (nz+1) texels per instance; texel (i, j, k) of a
// block is the image of lattice point (i, j, k). Grid coordinate g in [0, n] (g = u * n) lies at
// texel centre origin + g, origin = block offset + 0.5: for a lone block that is the
// (u * n + 0.5) / (n + 1) of the texture coordinates.
uniform sampler3D u_grid_atlas;  // RGBA32F, LINEAR, CLAMP_TO_EDGE: xyz lattice point image, w 1
uniform vec3 u_atlas_texel;      // 1 / (atlas width, height, depth) in texels

vec3 grid_point(vec3 origin, vec3 g) {
    return texture(u_grid_atlas, (origin + g) * u_atlas_texel).xyz;
}

// d T / d g (per grid unit) of the cell containing g, from samples on that cell's faces:
// inside a cell T is linear along each axis, so one difference per axis is exact. The face
// farther from g is used (distance >= 0.5), keeping float32 cancellation small.
mat3 grid_jacobian(vec3 origin, vec3 g, vec3 cells, vec3 at_g) {
    vec3 cell = clamp(floor(g), vec3(0.0), cells - 1.0);
    vec3 other = cell + 1.0 - step(vec3(0.5), g - cell);
    vec3 dg = other - g;
    return mat3((grid_point(origin, vec3(other.x, g.y, g.z)) - at_g) / dg.x,
                (grid_point(origin, vec3(g.x, other.y, g.z)) - at_g) / dg.y,
                (grid_point(origin, vec3(g.x, g.y, other.z)) - at_g) / dg.z);
}
