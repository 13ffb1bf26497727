"""The surface of a node grid as a triangle mesh over node numbers (one-to-one mapping, 3.2).

A cell is the cube of 8 grid positions (i..i+1, j..j+1, k..k+1); it is *full* when all 8 nodes
exist. The surface is every cell face that belongs to exactly one full cell, wound
counter-clockwise seen from outside, plus every square of 4 existing nodes that belongs to no
full cell at all (a one-node-thin sheet, drawn as is). Each quad becomes two triangles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deformgl.grid.nodes import NodeGrid

# For a face normal to `axis`, the two in-plane unit offsets (u, v) with u x v = +axis.
_PLANE = {0: ((0, 1, 0), (0, 0, 1)), 1: ((0, 0, 1), (1, 0, 0)), 2: ((1, 0, 0), (0, 1, 0))}


@dataclass(frozen=True)
class GridSurface:
    """Triangles over node numbers and the nodes they use.

    Attributes:
        nodes: (V,) int64 node numbers used by the surface, sorted.
        triangles: (T, 3) int64 indices into ``nodes``.
        sheet: (T,) bool, True for triangles of sheets (no outside; lit from both sides).
    """

    nodes: np.ndarray
    triangles: np.ndarray
    sheet: np.ndarray

    def edges(self) -> np.ndarray:
        """(E, 2) unique undirected edges (indices into ``nodes``), for the spring overlay."""
        t = self.triangles
        e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
        return np.unique(np.sort(e, axis=1), axis=0)


def _quads(origins: np.ndarray, axis: int, outward_positive: np.ndarray) -> np.ndarray:
    """Corner grid indices (Q, 4, 3) of faces normal to ``axis`` at ``origins``."""
    u, v = (np.array(a) for a in _PLANE[axis])
    corners = np.stack([origins, origins + u, origins + u + v, origins + v], axis=1)
    flip = ~outward_positive
    corners[flip] = corners[flip][:, ::-1]
    return corners


def grid_surface(grid: NodeGrid) -> GridSurface:
    """Extract the drawable surface of a node grid (see module docstring)."""
    occ = np.pad(grid.occupied, 1)
    full = (occ[:-1, :-1, :-1] & occ[1:, :-1, :-1] & occ[:-1, 1:, :-1] & occ[:-1, :-1, 1:]
            & occ[1:, 1:, :-1] & occ[1:, :-1, 1:] & occ[:-1, 1:, 1:] & occ[1:, 1:, 1:])
    # full[c]: the cell whose lowest corner is padded index c (grid index c - 1).
    quads, sheets = [], []
    for axis in range(3):
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[axis], hi[axis] = slice(None, -1), slice(1, None)
        below, above = full[tuple(lo)], full[tuple(hi)]
        # Face between cell (c) below and cell (c + e_axis) above; its plane holds corner c + e_axis.
        boundary = below ^ above
        faces = np.argwhere(boundary)
        origin = faces.copy()
        origin[:, axis] += 1
        quads.append(_quads(origin - 1, axis, below[boundary]))
        sheets.append(np.zeros(len(faces), bool))
        # Squares of 4 existing nodes touching no full cell: one-node-thin sheets.
        u, v = _PLANE[axis]
        sq = occ.copy()
        for off in (u, v, np.add(u, v)):
            sq = sq & np.roll(occ, shift=tuple(-np.array(off)), axis=(0, 1, 2))
        sq_idx = np.argwhere(sq)
        touching = np.zeros(len(sq_idx), bool)
        cells = np.pad(full, 1)  # cells[p + 1] is full[p], the cell with lowest padded corner p
        for side in (0, -1):
            c = sq_idx.copy() + 1
            c[:, axis] += side
            touching |= cells[c[:, 0], c[:, 1], c[:, 2]]
        lone = sq_idx[~touching]
        quads.append(_quads(lone - 1, axis, np.ones(len(lone), bool)))
        sheets.append(np.ones(len(lone), bool))
    corners = np.concatenate(quads)
    sheet = np.concatenate(sheets)
    if len(corners) == 0:
        return GridSurface(np.zeros(0, np.int64), np.zeros((0, 3), np.int64), np.zeros(0, bool))
    node = grid.index[corners[..., 0], corners[..., 1], corners[..., 2]]  # (Q, 4)
    tri = np.concatenate([node[:, [0, 1, 2]], node[:, [0, 2, 3]]])
    tri_sheet = np.concatenate([sheet, sheet])
    used, local = np.unique(tri, return_inverse=True)
    return GridSurface(used, local.reshape(tri.shape), tri_sheet)
