"""The lattice's volumetric term (:mod:`deformgl.sim.volume`: any Poisson's ratio, the inversion
barrier) on the fragment backend: what its passes need besides the springs, and a per-node pass
that evaluates the term alone.

The term is computed inside the pass that computes the springs, per node, gathered from the
node's (up to 8) full incident cells (``shaders/lib/cell_forces.glsl`` ``cell_forces``, the
float32 twin of :func:`~deformgl.sim.volume.volume_forces`): in the foundation's Verlet pass
(``shaders/sim/verlet.frag``, define ``CELLS``) the 18 neighbour positions the springs fetched are
kept and only the 8 body diagonals of the 3x3x3 neighbourhood are fetched besides
(``shaders/sim/cells/node_hood.glsl``); the integrator stages (``shaders/sim/integrators``) do
the same at the stage's evaluation state.
Measured on a 30^3 block (27,000 nodes, nu = 0.45, llvmpipe on 2 cores, CPU time per Verlet
step of the foundation pass, springs alone 2.0 ms): in the pass +0.56x (+0.21x at nu = 1/4,
the barrier alone); a pass of its own per node writing a force texture that the spring pass
adds, +1.4x (27 fetches per node and a second pass); a pass per cell (each cell once, the
forces on its 8 corners into 8 render targets, 8 fetches per node to gather them) +1.2x, the
gather from 8 distinct textures costing more than the cells themselves. The per-node function
is unrolled over the 8 cells with literal indices: the looped form kept its arrays in memory
on llvmpipe and cost 3.8x as much (9.9 against 2.6 ms for the 27,000 nodes).

What travels (the node layout of :class:`~deformgl.grid.nodes.CompactLayout`):

* the incident-cell mask in the caller's node data: bits ``CELL_SHIFT`` (6) to 13 of the flag
  channel G (:func:`cell_flags`; ``shaders/lib/node_flags.glsl`` ``cell_bits``); bit q: the
  cell whose corner 0 is the node at offset (qx - 1, qy - 1, qz - 1) is full.
* for the centre term on grids that are not dense, the node numbers of the 8 body diagonals
  (:func:`diagonal_table`, 2 RGBA32I layers); dense grids (every node of the box exists) compute
  them from the node-number strides, and the barrier alone never reads them.
* defines: ``CELLS``; ``CELL_BARRIER``, and ``CELL_CENTRE`` where kappa > 0 (:func:`cell_terms`):
  a centre term of modulus 0 is not compiled, which at nu = 1/4 (the barrier alone) saves 0.4x
  of the spring step (llvmpipe runs the body of a uniform branch anyway) and the diagonals.
"""

from __future__ import annotations

import moderngl
import numpy as np

from deformgl.gl.es_context import read_texture
from deformgl.gl.programs import Program
from deformgl.gl.resources import GLOwner, restore_framebuffer
from deformgl.grid.nodes import CompactLayout, NodeGrid, layout_uniforms
from deformgl.sim.backends.cell_tables import cell_uniforms, check_cells, incident_cells, neighbourhood
from deformgl.sim.backends.compact_textures import compact_image, float_texture, layer_texture
from deformgl.sim.volume import CellVolumes

__all__ = ["CELL_SHIFT", "DIAGONAL_SLOTS", "active_cells", "check_cells", "cell_flags", "cell_kind", "cell_terms",
           "term_uniforms", "diagonal_table", "NodeCellForces"]

#: Bit of incident cell q in the node data's flag channel is ``1 << (CELL_SHIFT + q)``
#: (``shaders/lib/node_flags.glsl``).
CELL_SHIFT = 6
#: Neighbourhood slots of the body diagonals (2 qx - 1, 2 qy - 1, 2 qz - 1), in the order of q.
DIAGONAL_SLOTS = (0, 2, 6, 8, 18, 20, 24, 26)


def cell_kind(cells: CellVolumes | None) -> str:
    """The ``cells`` argument of :class:`~deformgl.sim.backends.foundation.NodeTextures` for a
    system's active cells: "none", "barrier" (the barrier alone) or "centre"."""
    if cells is None:
        return "none"
    return "centre" if cells.volume_modulus > 0 else "barrier"


def cell_flags(grid: NodeGrid, cells: CellVolumes | None) -> np.ndarray:
    """(N,) int64 incident-cell bits of the node data's flag channel (0 without cells)."""
    if cells is None:
        return np.zeros(grid.count, np.int64)
    return incident_cells(grid, cells).astype(np.int64) << CELL_SHIFT


def active_cells(cells: CellVolumes | None) -> CellVolumes | None:
    """``cells`` when they exert a force (at least one cell, a modulus > 0), else None."""
    if cells is None or cells.count == 0 or (cells.volume_modulus == 0 and cells.barrier_modulus == 0):
        return None
    return cells


def cell_terms(cells: CellVolumes) -> dict[str, bool]:
    """The term defines of ``lib/cell_forces.glsl``: ``CELL_BARRIER`` always, ``CELL_CENTRE`` where
    kappa > 0 (a lattice at nu = 1/4 has the barrier alone). A barrier of modulus 0 (never a
    material's) is compiled and adds exact zeros: one variant fewer to build and check."""
    return {"CELL_CENTRE": cells.volume_modulus > 0, "CELL_BARRIER": True}


def term_uniforms(cells: CellVolumes) -> dict[str, float]:
    """The uniforms of ``lib/cell_forces.glsl`` the compiled terms (:func:`cell_terms`) read."""
    values = cell_uniforms(cells)
    if cells.volume_modulus == 0:
        del values["u_cell_kappa"]
    return values


def diagonal_table(grid: NodeGrid) -> np.ndarray:
    """(N, 8) int32: column q the node at the body diagonal (2 qx - 1, 2 qy - 1, 2 qz - 1), the
    node itself where absent (``shaders/sim/cells/node_hood.glsl``)."""
    return np.ascontiguousarray(neighbourhood(grid)[:, list(DIAGONAL_SLOTS)])


class NodeCellForces(GLOwner):
    """The volumetric term alone, per node, into a force texture (``shaders/sim/cells/node_cells.frag``):
    ``lib/cell_forces.glsl`` checked against :func:`~deformgl.sim.volume.volume_forces` without
    springs or an integrator, and the force field of the term at any positions.

    Args:
        ctx: GL context.
        cells: full unit cells of ``grid`` (:func:`check_cells`).
        grid: the node grid (node order of ``cells``).
        layout: "compact" (neighbours from the node-number strides on dense grids) or "indexed"
            (the 7-layer neighbourhood table always).
    """

    def __init__(self, ctx: moderngl.Context, cells: CellVolumes, grid: NodeGrid, *, layout: str = "compact") -> None:
        if layout not in ("compact", "indexed"):
            raise ValueError(f"NodeCellForces: layout must be 'compact' or 'indexed', got {layout!r}")
        check_cells(grid, cells)
        super().__init__(ctx)
        self.grid, self.cells = grid, cells
        self.layout = CompactLayout.for_grid(grid, int(ctx.info["GL_MAX_TEXTURE_SIZE"]), arithmetic=layout == "compact")
        size = self.layout.size
        n = grid.count
        with self.building():
            node = np.stack([np.zeros(n), 1 + cell_flags(grid, cells), np.zeros(n), np.zeros(n)], axis=1)
            self.node = float_texture(self, ctx, size, compact_image(size, node))
            self.positions = float_texture(self, ctx, size, compact_image(size, grid.rest_positions))
            self.force = float_texture(self, ctx, size)
            self.fbo = self.own(ctx.framebuffer(color_attachments=[self.force]))
            self.hood = None if self.layout.dense else layer_texture(self, ctx, size, neighbourhood(grid), "i4", 7)
            self.program = self.own(Program(ctx, "sim/fullscreen.vert", "sim/cells/node_cells.frag",
                                            defines={"COMPACT_DENSE": self.layout.dense, **cell_terms(cells)}))
            uniforms: dict[str, object] = {**term_uniforms(cells), "u_x": 0, "u_node": 1,
                                           **layout_uniforms(self.layout.width)}
            uniforms.update({"u_strides": self.layout.strides} if self.layout.dense else {"u_cell_hood": 2})
            self.program.set(**uniforms)
            self.vao = self.own(ctx.vertex_array(self.program.gl, []))

    def forces(self, x: np.ndarray) -> np.ndarray:
        """(N, 3) float32 force in N of the term at positions ``x`` (N, 3) (uploaded as float32;
        one draw, one read-back)."""
        x = np.asarray(x, np.float64)
        if x.shape != (self.grid.count, 3):
            raise ValueError(f"NodeCellForces.forces: positions of shape {x.shape}, expected ({self.grid.count}, 3)")
        self.positions.write(compact_image(self.layout.size, x).tobytes())
        previous = self.ctx.fbo
        self.positions.use(0)
        self.node.use(1)
        if self.hood is not None:
            self.hood.use(2)
        self.fbo.use()
        self.vao.render(moderngl.TRIANGLES, vertices=3)
        restore_framebuffer(self.ctx, previous)
        data = np.frombuffer(read_texture(self.force), np.float32).reshape(-1, 4)
        return data[: self.grid.count, :3].copy()
