"""The grid neighbours the GPU gathers read, beyond ``NodeGrid.neighbours``: the 18 of Mosegaard &
Sørensen 2005, section 3.1 (``NEIGHBOUR_OFFSETS``), then the 6 flexion neighbours at 2h along the
axes of Movania & Feng 2012, section 3 — the table the fragment backend's springs and the physics
terms that couple a node to its neighbours (:mod:`deformgl.sim.terms`) index alike."""

from __future__ import annotations

import numpy as np

from deformgl.grid.nodes import NodeGrid

__all__ = ["FLEXION_OFFSETS", "grid_neighbours"]

#: Flexion neighbour offsets, after the 18 of grid.NEIGHBOUR_OFFSETS.
FLEXION_OFFSETS = np.array([(2, 0, 0), (-2, 0, 0), (0, 2, 0), (0, -2, 0), (0, 0, 2), (0, 0, -2)],
                           dtype=np.int64)


def grid_neighbours(grid: NodeGrid, flexion: bool) -> np.ndarray:
    """(N, 18 or 24) int64 node number of each neighbour, -1 where no spring can be.

    Columns 0-17 are ``grid.neighbours``; with ``flexion`` columns 18-23 are the nodes at
    ``FLEXION_OFFSETS``, present only where the node between exists too (as ``from_grid``).
    """
    nb = grid.neighbours
    if not flexion:
        return nb
    padded = np.pad(grid.index, 2, constant_values=-1)
    base = grid.ijk + 2
    cols = []
    for off in FLEXION_OFFSETS:
        mid = padded[tuple((base + off // 2).T)]
        far = padded[tuple((base + off).T)]
        cols.append(np.where(mid >= 0, far, -1))
    return np.concatenate([nb, np.stack(cols, axis=1)], axis=1)
