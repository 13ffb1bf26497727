"""Cells that carry the mesh: how much of every grid cell the solid fills, and which nodes hold it.

A cell is the cube between 8 grid nodes (its corner 0 at node ``(i, j, k)``). Each cell is cut
into ``s^3`` sub-cubes and the centre of each is tested against the mesh with the voxeliser's
vote of 26 half-rays (:func:`deformgl.grid.voxelize.inside_points`, leaky meshes included),
enclosed voids filled as the voxeliser fills them. A cell's **fraction** is the share of its
sample points inside: the midpoint rule for the volume of mesh in it, exact for a cell the
mesh fills or misses and within about one sample layer (``h / s``) of the surface otherwise.
``s`` gives about :data:`SAMPLES_ALONG_LONGEST` samples along the mesh's longest side (at least
:data:`MIN_SAMPLES` and at most :data:`MAX_PER_CELL` per cell edge), so the fill resolves the same geometry at every grid
resolution.

The grid of a filled mesh is the corners of every cell whose fraction is above zero: every
point of the mesh's material lies in a cell whose 8 corners exist, and no node is outside the
material's cells (nor a spring, unless a cell holds it). The lattice (``deformgl.sim.materials``)
gives each cell its fraction of a full cell's stiffness and mass (Nesme, Kry, Jeřábková & Faure
2009 build each coarse cell from the fine geometry it holds; this is the volume-fraction
version of it, docs/EQUATIONS.md "Cells that carry the mesh").

Regions select material, not space: :meth:`CellFill.node_weights` spreads every sample point
inside the mesh over its cell's 8 corners with the trilinear weights, so a node's weight is its
share of the material around it; a region holds a node when most of that share lies in the region
(:func:`deformgl.scene.physics.region_nodes`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import trimesh
from scipy import ndimage

from deformgl.errors import InputError
from deformgl.grid.voxelize import Voxelization, grid_frame, inside_points

__all__ = ["SAMPLES_ALONG_LONGEST", "MIN_SAMPLES", "MAX_SAMPLES", "CellFill", "fill_cells"]

#: sample points along the longest side of the mesh's bounding box (the fill's resolution).
SAMPLES_ALONG_LONGEST = 240
#: most sample points along a cell edge: a coarse grid's cells are sampled no finer (the fill's
#: cost grows as s^3 per cell; 16^3 resolve a 2 mm fin in a 9 mm cell with 3.5 samples across).
MAX_PER_CELL = 16
#: fewest sample points along a cell edge (``s^3`` per cell).
MIN_SAMPLES = 2
#: most sample points in all (a finer grid is an InputError before the work).
MAX_SAMPLES = 1 << 26


@dataclass(frozen=True, eq=False)
class CellFill:
    """The mesh's material in the cells of a node grid (immutable).

    Attributes:
        samples: ``s``, sample points along a cell edge.
        inside: ``(s (nx - 1), s (ny - 1), s (nz - 1))`` bool for a grid of ``(nx, ny, nz)``
            nodes: sample ``(p, q, r)``, at ``origin + h ((p, q, r) + 1/2) / s``, is inside the
            mesh. It lies in cell ``(p, q, r) // s``.
    """

    samples: int
    inside: np.ndarray

    def __post_init__(self) -> None:
        inside = np.array(self.inside, dtype=bool)
        s = int(self.samples)
        if inside.ndim != 3 or s < 1 or any(n % s for n in inside.shape):
            raise ValueError(f"CellFill: inside of shape {inside.shape} is not whole cells of {s} samples")
        inside.setflags(write=False)
        object.__setattr__(self, "inside", inside)
        object.__setattr__(self, "samples", s)

    @property
    def cells(self) -> tuple[int, int, int]:
        """The cell grid's shape ``(nx - 1, ny - 1, nz - 1)``."""
        s = self.samples
        return tuple(n // s for n in self.inside.shape)

    @cached_property
    def fraction(self) -> np.ndarray:
        """``cells`` float64 in [0, 1]: the share of each cell's volume inside the mesh."""
        s = self.samples
        cx, cy, cz = self.cells
        out = self.inside.reshape(cx, s, cy, s, cz, s).mean(axis=(1, 3, 5))
        out.setflags(write=False)
        return out

    @cached_property
    def octants(self) -> np.ndarray:
        """``cells + (2, 2, 2)`` float64 in [0, 1]: the share of each octant of each cell inside the
        mesh (octant ``(ox, oy, oz)``: the half-cells at the low (0) or high (1) side of each axis;
        with an odd ``s`` the middle sample plane is split between the two halves)."""
        s = self.samples
        cx, cy, cz = self.cells
        half = np.clip(s / 2.0 - np.arange(s), 0.0, 1.0)  # sample m's share of the low half
        sides = np.stack([half, 1.0 - half])              # (2, s)
        blocks = self.inside.reshape(cx, s, cy, s, cz, s).astype(np.float64)
        out = np.einsum("aibjck,xi,yj,zk->abcxyz", blocks, sides, sides, sides, optimize=True) / (s ** 3 / 8.0)
        out.setflags(write=False)
        return out

    def volume(self, spacing: float) -> float:
        """The material's volume, ``h^3`` times the sum of the fractions (m^3 for h in m)."""
        return float(self.fraction.sum()) * spacing ** 3

    def inside_positions(self, origin: np.ndarray, spacing: float) -> np.ndarray:
        """(M, 3) float64 world positions of the inside samples (order of ``np.argwhere(inside)``)."""
        return np.asarray(origin, np.float64) + spacing * (np.argwhere(self.inside) + 0.5) / self.samples

    def node_weights(self, index: np.ndarray, select: np.ndarray | None = None) -> np.ndarray:
        """Each node's share of the material: the trilinear weights of the inside samples.

        Args:
            index: ``(nx, ny, nz)`` node number of each grid point (-1 where none), the
                grid's :attr:`~deformgl.grid.nodes.NodeGrid.index`.
            select: ``(M,)`` bool over the inside samples (their argwhere order): count only
                these; None: all.

        Returns:
            ``(N,)`` float64, in sample counts (a cell full of material gives each corner
            ``s^3 / 8``).
        """
        s = self.samples
        points = np.argwhere(self.inside)
        if select is not None:
            points = points[np.asarray(select, bool)]
        cell, local = np.divmod(points, s)
        t = (local + 0.5) / s
        count = int(index.max()) + 1
        out = np.zeros(count, np.float64)
        for corner in np.ndindex(2, 2, 2):
            c = np.array(corner)
            w = np.prod(np.where(c == 1, t, 1.0 - t), axis=1)
            ijk = cell + c
            node = index[ijk[:, 0], ijk[:, 1], ijk[:, 2]]
            there = node >= 0  # a corner whose springs the cell's material does not reach is no node
            out += np.bincount(node[there], weights=w[there], minlength=count)
        return out


def fill_cells(mesh: trimesh.Trimesh, *, nodes_along_longest: int | None = None, spacing: float | None = None,
               source: str = "mesh", offset=None) -> tuple[Voxelization, CellFill]:
    """The grid of the cells that hold the mesh's material, and their fill.

    The frame (spacing, origin) is :func:`~deformgl.grid.voxelize.voxelize`'s (moved by ``-offset``
    cells, :func:`~deformgl.grid.voxelize.grid_frame`); the nodes are the corners of the cells with
    material (module docstring), trimmed to them.

    Raises:
        InputError: as :func:`~deformgl.grid.voxelize.voxelize`; or the samples would be more
            than :data:`MAX_SAMPLES`, or no sample is inside the mesh (an open surface, or one
            thinner than the sample spacing), naming ``source``.
    """
    triangles, shape, origin, h = grid_frame(mesh, nodes_along_longest=nodes_along_longest, spacing=spacing,
                                             source=source, offset=offset)
    cells = np.array(shape) - 1
    unshifted = shape if offset is None else tuple(n - int(d > 0) for n, d in zip(shape, offset))
    along = max(int(max(unshifted)) - 3, 1)  # cells along the longest side of the mesh's box (any offset)
    s = max(MIN_SAMPLES, min(MAX_PER_CELL, math.ceil(SAMPLES_ALONG_LONGEST / along)))
    while s > MIN_SAMPLES and float(np.prod(cells * s, dtype=np.float64)) > MAX_SAMPLES:
        s -= 1
    total = float(np.prod(cells * s, dtype=np.float64))
    if total > MAX_SAMPLES:
        raise InputError(f"{source}: spacing {h:g} is too fine for the cells' material fill: {total:.3g} sample "
                         f"points at {s} per cell edge, more than the {MAX_SAMPLES} allowed; use a coarser grid")
    # sample (p, q, r) is at node-index point ((p, q, r) + 1/2) / s
    inside = inside_points(triangles * s - 0.5, tuple(int(n) for n in cells * s))
    inside = ndimage.binary_fill_holes(inside)
    cx, cy, cz = (int(n) for n in cells)
    material = inside.reshape(cx, s, cy, s, cz, s).any(axis=(1, 3, 5))
    if not material.any():
        raise InputError(f"{source}: no part of the mesh encloses any volume at spacing {h:g} (sample spacing "
                         f"{h / s:.3g}): it is an open surface, or thinner than that; a solid material needs "
                         f"a closed mesh")
    occupied = np.zeros(shape, bool)
    for dx, dy, dz in np.ndindex(2, 2, 2):
        occupied[dx:dx + cx, dy:dy + cy, dz:dz + cz] |= material
    used = [np.flatnonzero(occupied.any(axis=other)) for other in ((1, 2), (0, 2), (0, 1))]
    lo = [int(u[0]) for u in used]
    hi = [int(u[-1]) for u in used]  # nodes lo..hi, cells lo..hi-1 (each cell with material inside)
    nodes = occupied[lo[0]:hi[0] + 1, lo[1]:hi[1] + 1, lo[2]:hi[2] + 1]
    samples = inside[lo[0] * s:hi[0] * s, lo[1] * s:hi[1] * s, lo[2] * s:hi[2] * s]
    vox = Voxelization(origin=origin + h * np.array(lo, np.float64), spacing=h, occupied=nodes)
    return vox, CellFill(samples=s, inside=samples)
