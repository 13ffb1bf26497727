"""The grid neighbours the GPU gathers read, beyond ``NodeGrid.neighbours``: the 18 of Mosegaard &
Sørensen 2005, section 3.1 (``NEIGHBOUR_OFFSETS``), then the 6 flexion neighbours at 2h along the
axes of Movania & Feng 2012, section 3 — the table the fragment backend's springs and the physics
terms that couple a node to its neighbours (:mod:`deformgl.sim.terms`) index alike — and each
node's 3x3x3 neighbourhood (:func:`neighbourhood`, its body diagonals :func:`diagonal_table`), which
the passes keep for the terms that read it (``shaders/lib/node_hood.glsl``)."""

from __future__ import annotations

from itertools import product

import numpy as np

from deformgl.grid.nodes import NodeGrid

__all__ = ["DIAGONAL_SLOTS", "FLEXION_OFFSETS", "diagonal_table", "grid_neighbours", "neighbourhood"]

#: Neighbourhood slots of the body diagonals (2 qx - 1, 2 qy - 1, 2 qz - 1), in the order of q.
DIAGONAL_SLOTS = (0, 2, 6, 8, 18, 20, 24, 26)
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


def neighbourhood(grid: NodeGrid) -> np.ndarray:
    """(N, 27) int32 node numbers of every node's 3x3x3 neighbourhood (absent: the node itself)."""
    padded = np.pad(grid.index, 1, constant_values=-1)
    ijk = grid.ijk.astype(np.int64) + 1
    own = np.arange(grid.count, dtype=np.int64)
    table = np.empty((grid.count, 27), np.int32)
    for dz, dy, dx in product((-1, 0, 1), repeat=3):
        slot = (dx + 1) + 3 * (dy + 1) + 9 * (dz + 1)
        other = padded[ijk[:, 0] + dx, ijk[:, 1] + dy, ijk[:, 2] + dz].astype(np.int64)
        table[:, slot] = np.where(other >= 0, other, own)
    return table


def diagonal_table(grid: NodeGrid) -> np.ndarray:
    """(N, 8) int32: column q the node at the body diagonal (2 qx - 1, 2 qy - 1, 2 qz - 1), the
    node itself where absent (``shaders/lib/node_hood.glsl``)."""
    return np.ascontiguousarray(neighbourhood(grid)[:, list(DIAGONAL_SLOTS)])
