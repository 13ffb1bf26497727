"""A spline term's span pass on the GPU (the cells': ``shaders/terms/spline_span.frag``, a penalty
anchor's: ``shaders/terms/spline_anchor.frag``): every knot span's forces on its 27 nodes from the
node positions, into four force textures that the term's chunk gathers. The explicit gathers run
it before each force evaluation (:attr:`deformgl.sim.terms.base.GlslTerm.prepass`);
:meth:`SplineSpanPass.forces` reads the node forces back (the check against float64)."""

from __future__ import annotations

import moderngl
import numpy as np

from deformgl.errors import GLError
from deformgl.gl.es_context import read_texture
from deformgl.gl.programs import Program
from deformgl.gl.resources import GLOwner, restore_framebuffer
from deformgl.sim.backends.compact_textures import float_texture
from deformgl.sim.terms.spline.tables import SPAN_GROUPS, SPAN_NODE_TEXELS, SpanTables

__all__ = ["SplineSpanPass"]

_UNITS = {"u_x": 0, "u_span_nodes": 1, "u_span_data": 2}


def _span_image(values: np.ndarray, row: int, texels: int) -> np.ndarray:
    """(rows, row * texels, 4): span s's ``texels`` texels at ``(texels * (s % row) + k, s / row)``."""
    spans = len(values)
    rows = -(-spans // row)
    out = np.zeros((rows * row, texels, 4), values.dtype)
    out[:spans] = values.reshape(spans, texels, 4)
    return out.reshape(rows, row * texels, 4)


class SplineSpanPass(GLOwner):
    """The span pass of a spline term (see the module docstring).

    Args:
        ctx: the GL context.
        layout: the node layout's uniforms (:func:`deformgl.grid.nodes.layout_uniforms`) of the
            position textures it reads.
        tables: the body's :class:`~deformgl.sim.terms.spline.tables.SpanTables`.
    """

    def __init__(self, ctx: moderngl.Context, layout: dict[str, int], *, tables: SpanTables) -> None:
        super().__init__(ctx)
        self.tables = tables
        row, spans = tables.row, tables.spans
        rows = -(-spans // row)
        widest = row * tables.data_texels
        limit = int(ctx.info["GL_MAX_TEXTURE_SIZE"])
        if widest > limit or rows > limit:
            raise GLError(f"spline cells: {spans} spans need a {widest} x {rows} texture; this GL allows {limit}")
        with self.building():
            nodes = _span_image(tables.nodes, row, SPAN_NODE_TEXELS)
            self.nodes = self.own(ctx.texture((row * SPAN_NODE_TEXELS, rows), 4, nodes.tobytes(), dtype="i4"))
            self.nodes.filter = (moderngl.NEAREST, moderngl.NEAREST)
            self.data = float_texture(self, ctx, (widest, rows), _span_image(tables.data, row, tables.data_texels))
            size = (row * SPAN_GROUPS, rows)
            self.outputs = tuple(float_texture(self, ctx, size) for _ in range(4))
            self.fbo = self.own(ctx.framebuffer(color_attachments=list(self.outputs)))
            self.program = self.own(Program(ctx, "sim/fullscreen.vert", tables.fragment))
            self.program.set(**_UNITS, **layout, u_span_row=row, u_spans=spans, **tables.uniforms)
            self.vao = self.own(ctx.vertex_array(self.program.gl, []))
        self.bytes_allocated = 16 * rows * row * (SPAN_NODE_TEXELS + tables.data_texels + 4 * SPAN_GROUPS)

    def run(self, positions: moderngl.Texture) -> None:
        """The spans' forces on their nodes at ``positions`` (RGBA32F, xyz in m, node layout)."""
        positions.use(_UNITS["u_x"])
        self.nodes.use(_UNITS["u_span_nodes"])
        self.data.use(_UNITS["u_span_data"])
        self.fbo.use()
        self.vao.render(moderngl.TRIANGLES, vertices=3)

    def textures(self) -> tuple[moderngl.Texture, ...]:
        """The four force textures (``shaders/terms/spline.glsl`` u_spline_f0..3)."""
        return self.outputs

    def forces(self, positions: moderngl.Texture) -> np.ndarray:
        """(N, 3) float64 every node's force at ``positions``, N: the pass run and its outputs
        summed on the host as the chunk sums them (node order of the body)."""
        previous = self.ctx.fbo
        try:
            self.run(positions)
        finally:
            restore_framebuffer(self.ctx, previous)
        t = self.tables
        rows = -(-t.spans // t.row)
        images = [np.frombuffer(read_texture(tex), np.float32).reshape(rows, t.row, SPAN_GROUPS, 4)
                  .reshape(rows * t.row, SPAN_GROUPS, 4)[: t.spans, :, :3] for tex in self.outputs]
        per_slot = np.stack(images, axis=2).reshape(t.spans, 4 * SPAN_GROUPS, 3)[:, :27]  # (S, a, 3)
        out = np.zeros((len(t.node_spans), 3))
        nodes = t.nodes[:, :27]
        np.add.at(out, nodes, per_slot.astype(np.float64))
        return out
