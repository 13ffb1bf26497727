// Node grid atlas: padded z-slices laid out as tiles in a 2D texture (deformgl/grid/nodes.py AtlasLayout).
// Padded slice pz sits at tile (pz % u_tiles_x, pz / u_tiles_x); in a tile, texel (x, y) is padded
// grid position (x, y). The one-node padding keeps every neighbour fetch inside the texture.

#ifndef COMPACT
uniform ivec3 u_grid;    // (nx, ny, nz) unpadded grid dimensions
uniform int u_tiles_x;   // tiles per texture row

ivec2 atlas_tile_origin(int pz) {
    return ivec2((pz % u_tiles_x) * (u_grid.x + 2), (pz / u_tiles_x) * (u_grid.y + 2));
}

// Padded slice index of a texel.
int atlas_slice(ivec2 texel) {
    ivec2 tile = texel / ivec2(u_grid.x + 2, u_grid.y + 2);
    return tile.y * u_tiles_x + tile.x;
}
#endif
