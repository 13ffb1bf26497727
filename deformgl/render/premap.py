"""The mapping of a detailed mesh run as a fragment pass, one fragment per vertex
(``shaders/render/mapped_premap.frag``), ahead of a draw that only fetches the results
(``shaders/render/mapped_premapped.vert``): :class:`MappedMeshPass`'s ``mapping_pass="fragment"``.

The same function as the paper's mapping in the drawing vertex shader (Mosegaard & Sørensen 2005,
section 3.3.3; ``shaders/lib/map_vertex.glsl`` holds it for both), computed once per vertex
rather than once per index, and in the renderer's parallel fragment threads: llvmpipe shades
vertices on the thread that issues the draw.

Textures (vertex v at texel (v % W, v // W), W a power of two; also in docs/ARCHITECTURE.md):

* vertex texels, RGBA32I (H, W, 4): the state-texture texels of the vertex's three nodes, each as
  ``x | y << 16``; A 0.
* vertex data, RGBA32F array (H, W, 4) x 5 layers (8 with a normal map): 0 the weights of
  Mosegaard & Sørensen 2005, eq. 4 (w: 1 for the curvature-corrected basis, else 0); 1 the
  offset in the basis (Mosegaard & Sørensen 2005, eq. 7); 2 the rest offset in world space
  (Mosegaard & Sørensen 2005, eq. 5); 3 normal in the basis; 4 normal in world space;
  5 tangent in the basis (w handedness); 6 tangent in world space; 7 uv (xy).
* outputs, RGBA32F (H, W, 4) each, rewritten by every :meth:`FragmentPremap.run`: mapped
  position (xyz, w 1); mapped normal (xyz, not normalised); with a normal map the tangent (xyz,
  w handedness) and uv (xy).
"""

from __future__ import annotations

import moderngl
import numpy as np

from deformgl.gl.es_context import read_texture
from deformgl.gl.programs import Program
from deformgl.gl.resources import GLOwner, restore_framebuffer
from deformgl.grid.nodes import CompactLayout, NodeGrid, layout_uniforms
from deformgl.render.mapped_data import MappedVertices

#: Texture units the premapped draw reads its inputs from (after the mapped mesh's 0 and 1).
OUTPUT_UNITS = (2, 3, 4, 5)


class PremapPass(GLOwner):
    """What a mapping run as a fragment pass shares (one fragment per vertex into the output
    textures the premapped draw reads): the subclass builds ``outputs``, ``fbo``, ``vao``,
    ``size``, ``count`` and the ``inputs`` it binds on units 1, 2, ... after the positions on 0."""

    count: int
    size: tuple[int, int]
    outputs: list[moderngl.Texture]
    inputs: list[moderngl.Texture | moderngl.TextureArray]
    fbo: moderngl.Framebuffer
    vao: moderngl.VertexArray

    @property
    def layout_uniforms(self) -> dict[str, int]:
        """The node layout's uniforms of the outputs (vertex v at texel node_texel(v))."""
        return layout_uniforms(self.size[0])

    def run(self, positions: moderngl.Texture) -> None:
        """Map every vertex with node positions from ``positions`` (texture units 0 and the inputs'
        are left bound); the caller's framebuffer and depth test come back."""
        previous = self.ctx.fbo
        self.fbo.use()
        self.ctx.disable(moderngl.DEPTH_TEST)
        try:
            positions.use(0)
            for unit, tex in enumerate(self.inputs, start=1):
                tex.use(unit)
            self.vao.render(moderngl.TRIANGLES, vertices=3)
        finally:
            self.ctx.enable(moderngl.DEPTH_TEST)
            restore_framebuffer(self.ctx, previous)

    def bind(self) -> dict[str, int]:
        """Bind the outputs to :data:`OUTPUT_UNITS`; the premapped draw's sampler uniforms."""
        names = ["u_vertex_world", "u_vertex_normal", "u_vertex_tangent", "u_vertex_uv"]
        for out, unit in zip(self.outputs, OUTPUT_UNITS):
            out.use(unit)
        return {name: unit for name, unit, _ in zip(names, OUTPUT_UNITS, self.outputs)}

    def read(self) -> tuple[np.ndarray, np.ndarray]:
        """(V, 3) float32 positions and normals of the last :meth:`run` (one read-back each)."""
        w, h = self.size
        images = [np.frombuffer(read_texture(t), dtype="f4").reshape(h * w, 4)[: self.count, :3].copy()
                  for t in self.outputs[:2]]
        return images[0], images[1]


class FragmentPremap(PremapPass):
    """Maps every vertex of ``data`` from a state texture into the output textures in one
    fragment pass; :meth:`bind` gives them to the premapped draw.

    Args:
        ctx: GL context.
        grid: the node grid; layout: where each node lies in the state texture.
        data: the per-vertex mapping data (:class:`~deformgl.render.mapped.MappedVertices`).
        defines: the mapping variant (``CURVATURE``, ``NORMAL_MAP``), as the draw's.
    """

    def __init__(self, ctx: moderngl.Context, grid: NodeGrid, layout: CompactLayout,
                 data: MappedVertices, defines: dict[str, object]) -> None:
        super().__init__(ctx)
        count = len(data.weights)
        self.count = count
        self.normal_mapped = bool(defines.get("NORMAL_MAP"))
        max_size = int(ctx.info["GL_MAX_TEXTURE_SIZE"])
        width = 1 << max(4, int(np.ceil(np.log2(np.sqrt(max(count, 1))))))
        width = min(width, 1 << int(np.floor(np.log2(max_size))))
        height = max(1, -(-count // width))
        if height > max_size:
            raise ValueError(f"{count} vertices need more than {max_size}x{max_size} texels")
        self.size = (width, height)
        texels = np.zeros((width * height, 4), np.int64)
        for c in range(3):
            node_texels = layout.texel(grid.ijk[data.tri_nodes[:, c]]).astype(np.int64)
            texels[:count, c] = node_texels[:, 0] | (node_texels[:, 1] << 16)
        columns = [np.column_stack([data.weights, np.asarray(data.use_curvature, np.float64)]),
                   data.offset, data.offset_world, data.normal, data.normal_world]
        if self.normal_mapped:
            assert data.tangent is not None and data.tangent_world is not None and data.uv is not None
            columns += [data.tangent, data.tangent_world, data.uv]
        layers = np.zeros((len(columns), width * height, 4), np.float32)
        for i, column in enumerate(columns):
            column = np.asarray(column, np.float64)
            layers[i, :count, :column.shape[1]] = column
        self.outputs: list[moderngl.Texture] = []
        with self.building():
            self.texels = self.own(ctx.texture(self.size, 4, texels.astype("i4").tobytes(), dtype="i4"))
            self.data = self.own(ctx.texture_array((width, height, len(columns)), 4, layers.tobytes(), dtype="f4"))
            for t in (self.texels, self.data):
                t.filter = (moderngl.NEAREST, moderngl.NEAREST)
            for _ in range(4 if self.normal_mapped else 2):
                out = self.own(ctx.texture(self.size, 4, dtype="f4"))
                out.filter = (moderngl.NEAREST, moderngl.NEAREST)
                self.outputs.append(out)
            self.fbo = self.own(ctx.framebuffer(color_attachments=self.outputs))
            self.program = self.own(Program(ctx, "sim/fullscreen.vert", "render/mapped_premap.frag",
                                            defines=defines))
            self.program.set(u_position=0, u_vertex_texels=1, u_vertex_data=2)
            self.vao = self.own(ctx.vertex_array(self.program.gl, []))
        self.inputs = [self.texels, self.data]
