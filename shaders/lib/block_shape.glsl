// The block shape of the BLOCKED layouts (deformgl/grid/blocks.py BlockedLayout): BLOCK_X x
// BLOCK_Y x BLOCK_Z nodes per fragment, 1x1x1 where the application defines none. Shared by
// lib/node_texel.glsl and lib/block_state.glsl.
#ifndef BLOCK_X
#define BLOCK_X 1
#endif
#ifndef BLOCK_Y
#define BLOCK_Y 1
#endif
#ifndef BLOCK_Z
#define BLOCK_Z 1
#endif
