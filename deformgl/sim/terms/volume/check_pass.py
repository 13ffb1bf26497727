"""The cells' volumetric term (:mod:`deformgl.sim.terms.volume.energy`: any Poisson's ratio, the inversion
barrier) alone, per node, in a pass of its own (:class:`NodeCellForces`, ``shaders/terms/cell_alone.frag``):
the term's check against float64 and its force field at any positions.

In a simulation the term is one of the system's physics terms (:mod:`deformgl.sim.terms.volume.chunks`):
computed inside the pass that computes the springs, per node, gathered from the node's (up to 8)
full incident cells (``shaders/terms/cell_forces.glsl`` ``cell_forces``, the float32 twin of
:func:`~deformgl.sim.terms.volume.energy.volume_forces`) from the 18 neighbour positions the springs fetched
and, for the centre term, the 8 body diagonals of the 3x3x3 neighbourhood, rather than in a pass
of its own like this one or a pass per cell, and unrolled over the 8 cells with literal indices
(llvmpipe keeps a looped form's arrays in memory); a centre term of modulus 0 is not compiled
(llvmpipe runs the body of a uniform branch anyway). What each costs: docs/PERFORMANCE.md, "The
cells' volumetric term: cost per step".
"""

from __future__ import annotations

import moderngl
import numpy as np

from deformgl.gl.es_context import read_texture
from deformgl.gl.programs import Program
from deformgl.gl.resources import GLOwner, restore_framebuffer
from deformgl.grid.nodes import CompactLayout, NodeGrid, layout_uniforms
from deformgl.grid.neighbours import neighbourhood
from deformgl.sim.terms.volume.tables import check_cells
from deformgl.sim.backends.compact_textures import compact_image, float_texture, layer_texture
from deformgl.sim.terms.glsl import TERM_SHIFT
from deformgl.sim.terms.volume.energy import CellVolumes
from deformgl.sim.terms.volume.chunks import volume_glsl

__all__ = ["check_cells", "NodeCellForces"]

class NodeCellForces(GLOwner):
    """The volumetric term alone, per node, into a force texture (``shaders/terms/cell_alone.frag``):
    ``terms/cell_forces.glsl`` checked against :func:`~deformgl.sim.terms.volume.energy.volume_forces` without
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
            form = volume_glsl(cells, grid)
            node = np.stack([np.zeros(n), 1 + (np.asarray(form.node_bits, np.int64) << TERM_SHIFT), np.zeros(n),
                             np.zeros(n)], axis=1)
            self.node = float_texture(self, ctx, size, compact_image(size, node))
            self.positions = float_texture(self, ctx, size, compact_image(size, grid.rest_positions))
            self.force = float_texture(self, ctx, size)
            self.fbo = self.own(ctx.framebuffer(color_attachments=[self.force]))
            self.hood = None if self.layout.dense else layer_texture(self, ctx, size, neighbourhood(grid), "i4", 7)
            self.program = self.own(Program(ctx, "sim/fullscreen.vert", "terms/cell_alone.frag",
                                            defines={"COMPACT_DENSE": self.layout.dense, **form.defines}))
            uniforms: dict[str, object] = {**form.uniforms, "u_x": 0, "u_node": 1,
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
