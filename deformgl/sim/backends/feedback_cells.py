"""The volumetric term of the transform-feedback backend: each node's cell table as a texture.

:mod:`deformgl.sim.volume` adds, per full grid cell, a centre term (any Poisson's ratio) and a
corner barrier (no inversion) to the springs. The feedback backend gathers them per node in the
vertex shader of every stage (``shaders/feedback/cells.glsl`` calling
``shaders/terms/cell_forces.glsl``), from one RGBA32I texture of :data:`CELL_SLOTS` texels per node:
node n's texels are its slots s = 0..6 in the node layout (``shaders/lib/node_texel.glsl``
``node_slot_texel(n, CELL_SLOTS, s)``), whose 28 integers are the 27 node numbers of its 3x3x3
neighbourhood (integer ``m = 4 s + channel`` holds slot m of
:func:`deformgl.grid.neighbours.neighbourhood`) and, last (texel 6, ``w``), the bit mask
of its full incident cells (:func:`deformgl.sim.cell_tables.incident_cells`).

Only grid bodies have cells; the tables assume the system's cells are cells of its node grid, as
:func:`deformgl.sim.materials.lattice_system` builds them, and :func:`check_system_cells` refuses any
other.
"""

from __future__ import annotations

import numpy as np

from deformgl.grid.neighbours import neighbourhood
from deformgl.sim.cell_tables import check_cells, incident_cells
from deformgl.sim.springs import SpringSystem

__all__ = ["CELL_SLOTS", "has_cells", "cell_node_row_limit", "cell_image"]

#: RGBA32I texels per node of the cell table: 27 neighbourhood node numbers and the mask.
CELL_SLOTS = 7
#: integer index of the incident-cell mask among a node's 4 * CELL_SLOTS integers.
_MASK = 4 * CELL_SLOTS - 1


def has_cells(system: SpringSystem) -> bool:
    """Whether the system carries a volumetric term to gather (cells set, at least one full
    cell), after :func:`check_system_cells`; ``cells`` set on a system without a node grid is an error."""
    if system.cells is None:
        return False
    check_system_cells(system)
    return system.cells.count > 0


def check_system_cells(system: SpringSystem) -> None:
    """Raise ValueError (one line) unless ``system.cells`` are distinct cells of ``system.grid``
    (:func:`~deformgl.sim.cell_tables.check_cells`)."""
    cells, grid = system.cells, system.grid
    if cells is None:
        return
    if grid is None:
        raise ValueError("FeedbackSimulation: the system has cells (a volumetric term) but no node "
                         "grid; only grid bodies (lattice_system) can carry cells")
    check_cells(grid, cells, "FeedbackSimulation")


def cell_node_row_limit(limit: int) -> int:
    """The largest power of two of nodes per row whose cell table fits a texture ``limit`` texels
    wide (``CELL_SLOTS`` texels per node)."""
    width = 1
    while 2 * width * CELL_SLOTS <= limit:
        width *= 2
    return width


def cell_image(system: SpringSystem, node_row: int, rows: int) -> np.ndarray:
    """(rows, CELL_SLOTS * node_row, 4) int32: the cell table texture's texels (padding nodes:
    zeros, no cells)."""
    if system.grid is None or system.cells is None:
        raise ValueError("cell_image: the system has no node grid or no cells")
    n = system.count
    table = np.zeros((rows * node_row, 4 * CELL_SLOTS), np.int32)
    table[:n, :27] = neighbourhood(system.grid)
    table[:n, _MASK] = incident_cells(system.grid, system.cells)
    return table.reshape(rows, node_row * CELL_SLOTS, 4)
