"""Across-sheet neighbours of the grid surface's nodes: the normal of a one-node-thin sheet.

The packed node normal (Mosegaard & Sørensen 2005, eq. 3: the sum of unit vectors towards the
missing neighbours) is a volume's outward direction. A one-node-thin sheet (a cloth) has no
inside: the unit vectors towards its neighbours in the plane cancel, the sum is zero at rest and
short and erratic once deformed (``deformgl.sim.normals.MIN_SUM_LENGTH``), so a node with a sum
just over the threshold points anywhere and shows as a dark speck, and the rest are drawn with
their triangles' flat normals. A node that lies only on sheet squares gets the sheet's own
normal instead, by central differences of its neighbours in the sheet's plane (the one-sided
difference at a border), cross(p(i+1) - p(i-1), p(j+1) - p(j-1)), computed in the vertex shader
from the positions of the frame. Every other surface node keeps its packed normal.
"""

from __future__ import annotations

import numpy as np

from deformgl.grid.nodes import NodeGrid
from deformgl.grid.surface import GridSurface

# For a square normal to `axis`, its in-plane axes (u, v) with u x v = +axis (grid/surface.py).
_IN_PLANE = {0: (1, 2), 1: (2, 0), 2: (0, 1)}


def sheet_neighbours(grid: NodeGrid, surface: GridSurface) -> np.ndarray:
    """(V, 4) node numbers, per node of ``surface.nodes``: its neighbours after and before it
    along the sheet's first in-plane axis u, then after and before along the second v (the node
    itself where the grid has no neighbour there). A node on no sheet square, or also on a
    volume's face, gets itself four times: the vertex shader's difference is zero and it draws
    the packed normal.

    The sheet's axis of a node is the normal axis of most of its sheet triangles (the grid axis
    along which a triangle's three nodes share their index); u x v points along +axis, the side
    the sheet squares are wound towards.
    """
    nodes = surface.nodes
    out = np.repeat(nodes[:, None], 4, axis=1).astype(np.int64)
    if len(nodes) == 0 or not surface.sheet.any():
        return out
    ijk = grid.ijk.astype(np.int64)
    tri_ijk = ijk[nodes[surface.triangles]]                       # (T, 3, 3)
    flat = (tri_ijk == tri_ijk[:, :1, :]).all(axis=1)             # (T, 3) axes of constant index
    axis_of = np.argmax(flat, axis=1)
    votes = np.zeros((len(nodes), 3), np.int64)
    solid = np.zeros(len(nodes), bool)
    for corner in range(3):
        local = surface.triangles[:, corner]
        np.add.at(votes, (local[surface.sheet], axis_of[surface.sheet]), 1)
        solid[local[~surface.sheet]] = True
    on_sheet = (votes.sum(axis=1) > 0) & ~solid
    axis = np.argmax(votes, axis=1)
    shape = np.array(grid.shape)
    index = np.full(grid.shape, -1, np.int64)
    index[tuple(ijk.T)] = np.arange(len(ijk))
    for a in range(3):
        pick = np.flatnonzero(on_sheet & (axis == a))
        if len(pick) == 0:
            continue
        here = ijk[nodes[pick]]
        for column, (along, step) in enumerate(((_IN_PLANE[a][0], 1), (_IN_PLANE[a][0], -1),
                                                (_IN_PLANE[a][1], 1), (_IN_PLANE[a][1], -1))):
            there = here.copy()
            there[:, along] += step
            inside = (there[:, along] >= 0) & (there[:, along] < shape[along])
            found = np.full(len(pick), -1, np.int64)
            found[inside] = index[tuple(there[inside].T)]
            out[pick, column] = np.where(found >= 0, found, nodes[pick])
    return out
