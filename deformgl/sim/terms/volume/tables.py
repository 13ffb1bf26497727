"""Per-node tables of the volumetric term (:mod:`deformgl.sim.terms.volume.energy`) for the GPU backends:
each node's 3x3x3 neighbourhood and the mask of its full incident cells, in the node order of the
system, ready for :func:`~deformgl.sim.backends.compact_textures.layer_texture` or a buffer.

Conventions (those of ``shaders/terms/cell_forces.glsl``): neighbourhood slot
``(dx + 1) + 3 (dy + 1) + 9 (dz + 1)`` holds the node at offset (dx, dy, dz) (slot 13: the node
itself; an absent node: the node itself, whose cells are then not full); incident cell
``q = qx + 2 qy + 4 qz`` is the cell whose lower corner is at offset (qx - 1, qy - 1, qz - 1), and
bit q of the mask is set when that cell is one of ``system.cells``.
"""

from __future__ import annotations

import numpy as np

from deformgl.grid.nodes import NodeGrid
from deformgl.sim.terms.volume.energy import CORNER_SIGNS, CellVolumes

__all__ = ["check_cells", "incident_cells", "cell_uniforms"]

#: (8, 3) offset of corner c = dx + 2 dy + 4 dz from the cell's corner 0 (the volume's corner signs).
_CORNER_OFFSETS = ((CORNER_SIGNS + 1.0) / 2.0).astype(np.int64)


def check_cells(grid: NodeGrid, cells: CellVolumes, who: str = "cells") -> None:
    """The cells must be unit cells of ``grid`` (corner c of each at its corner 0 + (dx, dy, dz),
    c = dx + 2 dy + 4 dz), each listed once: a node finds its cells by grid offsets.

    Raises:
        ValueError: (one line, starting with ``who``) a cell that is not a unit cell of the grid,
            named with its corners, or one listed twice.
    """
    if cells.count == 0:
        return
    corners = np.asarray(cells.corners, np.int64)
    if corners.min() < 0 or corners.max() >= grid.count:
        raise ValueError(f"{who}: corner node numbers outside the grid's {grid.count} nodes")
    ijk = grid.ijk.astype(np.int64)
    wrong = np.any(ijk[corners] != ijk[corners[:, :1]] + _CORNER_OFFSETS[None, :, :], axis=2)
    if wrong.any():
        bad = int(np.argmax(wrong.any(axis=1)))
        raise ValueError(f"{who}: cell {bad} (corners {corners[bad].tolist()}) is not a unit cell of the system's "
                         f"node grid (corner {int(np.argmax(wrong[bad]))} is not at corner 0 + (dx, dy, dz), "
                         f"c = dx + 2 dy + 4 dz); build them with terms.volume.energy.grid_cells on the system's grid")
    if len(np.unique(corners[:, 0])) != cells.count:
        raise ValueError(f"{who}: a grid cell is listed more than once")


def incident_cells(grid: NodeGrid, cells: CellVolumes) -> np.ndarray:
    """(N,) int32 bit mask of each node's incident cells that are in ``cells`` (bit q: the cell
    whose lower corner is at offset (qx - 1, qy - 1, qz - 1), q = qx + 2 qy + 4 qz)."""
    mask = np.zeros(grid.count, np.int32)
    if cells.count == 0:
        return mask
    # the node at corner c = dx + 2 dy + 4 dz of a cell sees it as its incident cell 7 - c
    for c in range(8):
        np.bitwise_or.at(mask, cells.corners[:, c], np.int32(1 << (7 - c)))
    return mask


def cell_uniforms(cells: CellVolumes) -> dict[str, float]:
    """The uniforms of ``shaders/terms/cell_forces.glsl``."""
    return {"u_cell_h": cells.spacing, "u_cell_kappa": cells.volume_modulus,
            "u_cell_barrier": cells.barrier_modulus, "u_cell_jb": cells.barrier_j}
