"""The physics terms' node tables (:class:`~deformgl.sim.terms.base.NodeTable`) as textures in a
pass's node layout: one RGBA32F texture array per table, ``layers`` layers per node; in the
compact layout layer l at the node's texel, in the blocked layout layer ``m * layers + l`` at its
block's texel for member m (what ``shaders/lib/term_node.glsl`` ``term_table`` reads)."""

from __future__ import annotations

from collections.abc import Sequence

import moderngl
import numpy as np

from deformgl.gl.programs import Program
from deformgl.gl.resources import GLOwner
from deformgl.grid.blocks import BlockedLayout
from deformgl.grid.nodes import CompactLayout, NodeGrid
from deformgl.sim.terms.glsl import PassTerms, blocked_table

__all__ = ["TermTables"]


class TermTables(GLOwner):
    """The textures of ``terms``' node tables in ``layout`` (compact or blocked), bound to
    ``units`` (one each, in table order).

    Raises:
        ValueError: more tables than units.
    """

    def __init__(self, ctx: moderngl.Context, terms: PassTerms, grid: NodeGrid,
                 layout: CompactLayout | BlockedLayout, units: Sequence[int]) -> None:
        super().__init__(ctx)
        #: the uniforms of the terms (their values and their tables' units)
        self.uniforms = terms.uniforms(units)
        self.units = tuple(units)[: len(terms.tables)]
        self.textures: list[moderngl.TextureArray] = []
        self.bytes_allocated = 0
        w, h = layout.size
        with self.building():
            for table in terms.tables:
                if isinstance(layout, BlockedLayout):
                    image = blocked_table(table, lambda values: layout.scatter(grid.ijk, values))
                else:
                    image = np.stack([layout.scatter(grid.ijk, table.layer(l)) for l in range(table.layers)])
                tex = self.own(ctx.texture_array((w, h, len(image)), 4, np.ascontiguousarray(image, "f4").tobytes(),
                                                 dtype="f4"))
                tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
                self.textures.append(tex)
                self.bytes_allocated += w * h * len(image) * 16

    def active_uniforms(self, program: Program) -> dict[str, object]:
        """:attr:`uniforms` that ``program`` uses (a term's uniform may serve its implicit
        functions only, which an explicit pass does not compile)."""
        members = program.members
        return {k: v for k, v in self.uniforms.items() if k in members}

    def bind(self) -> None:
        """Bind every table to its unit."""
        for tex, unit in zip(self.textures, self.units):
            tex.use(unit)
