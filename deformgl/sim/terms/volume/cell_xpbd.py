"""The cells' XPBD constraints on the GPU (:class:`XpbdCells`, float32: the passes of
:class:`~deformgl.sim.terms.volume.xpbd_form.CellConstraints`, the term's
:class:`~deformgl.sim.terms.constraints.XpbdPasses`).

A Jacobi sweep with cells is two passes: the cell pass (one fragment per node; the node at corner
0 of a full cell owns that cell) reads the iterate and the cell multipliers of the last sweep and
writes the new multipliers and their changes; the node sweep then reads the same iterate and those
changes and gathers ``w_i grad_i C d_lambda`` of the constraints of its (up to 8) incident cells.

Textures (compact layout of the nodes, NEAREST, ``texelFetch``; a cell's values at its owner's
texel, 0 at every other texel; docs/ARCHITECTURE.md):

* neighbourhood: RGBA32I array, 7 layers: column ``4 l + c`` the node at slot
  ``(dx + 1) + 3 (dy + 1) + 9 (dz + 1)`` of the 3x3x3 neighbourhood
  (:func:`~deformgl.grid.neighbours.neighbourhood`; the node itself where absent), column
  27 0; static. A node's full incident cells are its term bits (:meth:`XpbdCells.node_bits`:
  ``64 << q`` in the XPBD node data's flags);
* lambda, 2 sets (ping-pong per sweep) of 2 RGBA32F: the barrier multipliers of corners 0..3 and
  4..7 (>= 0);
* state, 2 sets of 1 RGBA32F: R the volume multiplier, G its change in this sweep, B the mask of
  corners whose barrier multiplier is > 0 (8 bits, exact), A 1 where any multiplier of the cell
  changed in this sweep, else 0 (a node fetches its 27 positions only when one of its cells did);
* delta, 2 RGBA32F (one set, rewritten every sweep): the barrier multipliers' changes.

All multipliers are cleared at each substep's start (set 0).
"""

from __future__ import annotations

import moderngl
import numpy as np

from deformgl.errors import GLError
from deformgl.gl.es_context import read_texture
from deformgl.gl.programs import Program
from deformgl.gl.resources import GLOwner
from deformgl.grid.neighbours import neighbourhood
from deformgl.grid.nodes import CompactLayout, NodeGrid
from deformgl.sim.backends.compact_textures import float_texture, layer_texture
from deformgl.sim.terms.constraints import XpbdChunk, XpbdPasses
from deformgl.sim.terms.volume.energy import CellVolumes
from deformgl.sim.terms.volume.tables import cell_uniforms, incident_cells

__all__ = ["CELL_SAMPLERS", "XpbdCells"]

#: The cells' samplers, in the order of their texture units (from the backend's ``first_unit``).
CELL_SAMPLERS = ("u_cell_nodes", "u_cell_lambda0", "u_cell_lambda1", "u_cell_state", "u_cell_delta0", "u_cell_delta1")
_NEIGHBOURHOOD_LAYERS = 7
_VEC4 = 16


class XpbdCells(GLOwner, XpbdPasses):
    """The cells' multipliers and the cell pass of :class:`XpbdFragment`.

    Args:
        ctx: the GL context.
        grid: the system's node grid.
        layout: its compact layout.
        cells: the cells (``VolumeTerm.cells``).
        chunk: its chunk and pass with the cells' constraints
            (:func:`~deformgl.sim.terms.volume.xpbd_form.chunk`).
        omega: the relaxation.
        first_unit: the texture unit of its first sampler (:data:`CELL_SAMPLERS` in order).
    """

    def __init__(self, ctx: moderngl.Context, grid: NodeGrid, layout: CompactLayout,
                 cells: CellVolumes, chunk: XpbdChunk, omega: float, first_unit: int) -> None:
        targets = 5
        if targets > int(ctx.info.get("GL_MAX_DRAW_BUFFERS", 8)):
            raise GLError(f"xpbd: the cell pass needs {targets} render targets, the context has "
                          f"{ctx.info.get('GL_MAX_DRAW_BUFFERS')}")
        super().__init__(ctx)
        self.cells, self.layout, self.chunk = cells, layout, chunk
        self.samplers = {name: first_unit + k for k, name in enumerate(CELL_SAMPLERS)}
        self.owners = np.ascontiguousarray(cells.corners[:, 0])   # (C,) each cell's corner-0 node
        self.mask = incident_cells(grid, cells)
        with self.building():
            size = layout.size
            self.tex_nodes = layer_texture(self, ctx, size, neighbourhood(grid), "i4", _NEIGHBOURHOOD_LAYERS)
            self.lambdas = [[float_texture(self, ctx, size) for _ in range(2)] for _ in range(2)]
            self.states = [float_texture(self, ctx, size) for _ in range(2)]
            self.deltas = [float_texture(self, ctx, size) for _ in range(2)]
            self.program = self.own(Program(ctx, "sim/fullscreen.vert", self.chunk.passes[0], defines=self.chunk.defines))
            self.program.set(**self.sweep_uniforms(self.program), u_omega=float(omega))
            self.vao = self.own(ctx.vertex_array(self.program.gl, []))
            self._fbos = [self.own(ctx.framebuffer(color_attachments=[*self.lambdas[b], self.states[b],
                                                                      *self.deltas]))
                          for b in range(2)]
            self._clear = self.own(ctx.framebuffer(color_attachments=[*self.lambdas[0], self.states[0]]))
        w, h_px = size
        self.bytes_allocated = (_NEIGHBOURHOOD_LAYERS + 8) * w * h_px * _VEC4

    def programs(self) -> list[Program]:
        """The cell pass."""
        return [self.program]

    def sweep_uniforms(self, program: Program) -> dict[str, object]:
        """The uniforms of ``terms/cell_forces.glsl`` and the cells' samplers that ``program``
        uses (the backend sets ``u_node``, ``u_p``, ``u_h`` and ``u_width_log2`` of every pass)."""
        values: dict[str, object] = {**cell_uniforms(self.cells), **self.samplers}
        return {k: v for k, v in values.items() if k in program.members}

    def node_bits(self) -> np.ndarray:
        """(N,) the incident-cell mask (bit q: full incident cell q)."""
        return self.mask

    def clear(self) -> None:
        """Zero the multipliers of set 0 (a substep's start)."""
        self._clear.clear(0.0, 0.0, 0.0, 0.0)

    def sweep(self, a: int, b: int) -> None:
        """The cell pass from multiplier set ``a`` to set ``b`` at the iterate bound to ``u_p``;
        then binds set b's state and the changes for the node sweep."""
        units = self.samplers
        self.tex_nodes.use(units["u_cell_nodes"])
        self.lambdas[a][0].use(units["u_cell_lambda0"])
        self.lambdas[a][1].use(units["u_cell_lambda1"])
        self.states[a].use(units["u_cell_state"])
        self._fbos[b].use()
        self.vao.render(moderngl.TRIANGLES, vertices=3)
        self.states[b].use(units["u_cell_state"])
        self.deltas[0].use(units["u_cell_delta0"])
        self.deltas[1].use(units["u_cell_delta1"])

    def read(self, b: int) -> tuple[np.ndarray, np.ndarray]:
        """The multipliers of set ``b`` in float64: ((C,) volume, (C, 8) barrier)."""
        n = len(self.mask)

        def texels(tex: moderngl.Texture) -> np.ndarray:
            data = np.frombuffer(read_texture(tex), dtype=np.float32).reshape(-1, 4)[:n]
            return data[self.owners].astype(np.float64)

        barrier = np.concatenate([texels(t) for t in self.lambdas[b]], axis=1)
        return texels(self.states[b])[:, 0].copy(), barrier
