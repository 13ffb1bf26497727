"""The cells' volumetric term (:class:`deformgl.sim.terms.volume.energy.CellVolumes`) as GLSL: its chunk
``shaders/terms/cell.glsl`` (``terms/cell_forces.glsl``'s forces and ``terms/cell_implicit.glsl``'s
Gauss-Newton product from the node's 3x3x3 neighbourhood, which the pass keeps:
``shaders/lib/node_hood.glsl``), its defines, uniforms and the node bits of its full incident
cells; and its transform-feedback form (:func:`volume_feedback`: ``shaders/terms/cell_feedback.glsl``
and its cell table). Every GPU pass that runs the term compiles it through the term list
(:mod:`deformgl.sim.terms.glsl`); XPBD has a form of its own (:mod:`deformgl.sim.terms.volume.xpbd_form`).

The feedback form's table, :data:`CELL_SLOTS` RGBA32I texels per node: its 28 integers are the 27
node numbers of the node's 3x3x3 neighbourhood (integer ``m = 4 s + channel`` holds slot m of
:func:`deformgl.grid.neighbours.neighbourhood`) and, last (texel 6, ``w``), the bit mask of its full
incident cells (:func:`deformgl.sim.terms.volume.tables.incident_cells`)."""

from __future__ import annotations

import numpy as np

from deformgl.grid.neighbours import neighbourhood
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.terms.volume.tables import cell_uniforms, check_cells, incident_cells
from deformgl.sim.terms.base import FeedbackTerm, GlslTerm
from deformgl.sim.terms.volume.energy import CellVolumes

__all__ = ["CELL_FORMS", "CELL_SLOTS", "FEEDBACK", "GLSL", "cell_defines", "volume_feedback", "volume_glsl"]

#: The term as messages name it.
TERM_NAME = "the cells' volumetric term"
#: RGBA32I texels per node of the feedback form's cell table: 27 neighbourhood node numbers and the mask.
CELL_SLOTS = 7

#: The term's form without its instance data (the shipped term list): the centre term needs the
#: body diagonals of the neighbourhood (hood 2), the barrier alone not.
GLSL = GlslTerm("cell", file="terms/cell.glsl", implicit=True, hood=2, held=True,
                defines={"CELL_CENTRE": True, "CELL_BARRIER": True})
#: Its forms (the shader pack's variants): the barrier alone (kappa = 0: nu = 1/4), both terms.
CELL_FORMS = (GlslTerm("cell", file="terms/cell.glsl", implicit=True, hood=1, held=True,
                       defines={"CELL_CENTRE": False, "CELL_BARRIER": True}), GLSL)


def cell_defines(cells: CellVolumes) -> dict[str, object]:
    """``CELL_BARRIER`` always, ``CELL_CENTRE`` where kappa > 0 (a lattice at nu = 1/4 has the
    barrier alone). A barrier of modulus 0 (never a material's) is compiled and adds exact zeros:
    one variant fewer to build and check; a centre term of modulus 0 is not compiled, nor are the
    body diagonals fetched (docs/PERFORMANCE.md, "The cells' volumetric term: cost per step")."""
    return {"CELL_CENTRE": cells.volume_modulus > 0, "CELL_BARRIER": True}


def volume_glsl(cells: CellVolumes, grid: NodeGrid | None) -> GlslTerm:
    """The GLSL form of ``cells`` on ``grid`` (ValueError when they are not the grid's cells)."""
    if grid is None:
        raise ValueError("the cells' volumetric term needs the system's node grid on the GPU")
    check_cells(grid, cells, TERM_NAME)  # (a node finds its cells by grid offsets)
    centre = cells.volume_modulus > 0
    uniforms: dict[str, object] = dict(cell_uniforms(cells))
    if not centre:
        del uniforms["u_cell_kappa"]  # (not compiled: CELL_CENTRE off)
    return GlslTerm("cell", file="terms/cell.glsl", implicit=True, hood=2 if centre else 1, held=True,
                    defines=cell_defines(cells), uniforms=uniforms, node_bits=incident_cells(grid, cells))


def volume_feedback(cells: CellVolumes, grid: NodeGrid | None) -> FeedbackTerm:
    """The transform-feedback form of ``cells`` on ``grid``: ``terms/cell_feedback.glsl`` and its
    cell table (see the module docstring); ValueError (one line) without a grid or when they are
    not the grid's cells. Both terms are compiled, each behind a test of its modulus."""
    if grid is None:
        raise ValueError("the system has cells (a volumetric term) but no node grid; only grid bodies "
                         "(lattice_system) can carry cells")
    check_cells(grid, cells, TERM_NAME)  # (a node finds its cells by grid offsets)
    table = np.zeros((grid.count, 4 * CELL_SLOTS), np.int32)
    table[:, :27] = neighbourhood(grid)
    table[:, -1] = incident_cells(grid, cells)
    return FeedbackTerm("cell", "terms/cell_feedback.glsl", "u_cell_nodes", table, uniforms=dict(cell_uniforms(cells)))


#: The feedback form without its instance data (the shipped list, the shader pack).
FEEDBACK = FeedbackTerm("cell", "terms/cell_feedback.glsl", "u_cell_nodes", np.zeros((0, 4 * CELL_SLOTS), np.int32))
