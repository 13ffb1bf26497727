"""Turning a triangle mesh into the occupied nodes of a regular simulation grid.

Node ``(i, j, k)`` sits at ``origin + spacing * (i, j, k)`` and owns the cube of side ``spacing``
centred on it. A node is occupied when its cube meets the solid: the surface or the space it
encloses. The mesh need not be watertight (the shipped dragons have holes). Occupancy is:

1. **Surface nodes**: an exact triangle/cube overlap test (separating axes) for every triangle
   and every cube its bounding box touches, so no surface node is missed, thin parts included.
2. **Interior nodes**: a cube that meets no triangle is inside exactly when its corners are,
   and a node is occupied when any of its 8 cube corners is inside. A corner is inside when a
   strict majority (14 or more) of its 26 half-rays along :data:`RAY_DIRECTIONS` (axes, face and
   body diagonals of the lattice) cross the surface an odd number of times. On a closed surface
   all 26 agree; a hole only corrupts the half-rays passing through it, so a point is misjudged
   only when holes fill about half of its view, i.e. within about a cell of a large hole, and
   an open sheet (crossed once per line) never makes a point inside. Crossings come from
   rasterising every triangle onto the lines of corners along each direction, as if each line
   were moved aside by an infinitesimal step, so a line through an edge or a vertex is counted
   exactly like a line beside it (once where the surface goes on, twice or not at all where
   the line grazes it).
3. **Enclosed voids are filled**: empty nodes that cannot reach the outside through empty nodes
   (6-connected) are occupied. This fills the overlap of intersecting parts (which parity calls
   outside), narrow crevices closed off by surface nodes, and the rare misjudged point; a hollow
   mesh (a closed inner wall) is therefore filled solid.

Where a hole removed surface, a cube that met only the missing part and holds no inside corner
is not occupied: the position of the missing surface is unknown. The returned grid is tight:
its first and last plane along every axis hold occupied nodes.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy import ndimage

from deformgl.errors import InputError

#: Largest node grid (before trimming) :func:`voxelize` builds; a finer spacing is an InputError.
MAX_GRID_NODES = 1 << 24
_BLOCK = 1 << 18  # candidate (triangle, node) pairs handled per vectorised batch
_EDGES = ((1, 2), (2, 0), (0, 1))  # edge e of a triangle is the one opposite vertex e

#: Lattice lines along which inside/outside is voted: 3 axes, 6 face and 4 body diagonals.
RAY_DIRECTIONS: tuple[tuple[int, int, int], ...] = (
    (1, 0, 0), (0, 1, 0), (0, 0, 1),
    (1, 1, 0), (1, -1, 0), (1, 0, 1), (1, 0, -1), (0, 1, 1), (0, 1, -1),
    (1, 1, 1), (1, 1, -1), (1, -1, 1), (1, -1, -1),
)  # fmt: skip


@dataclass(frozen=True)
class Voxelization:
    """Occupied nodes of a regular grid.

    Attributes:
        origin: ``(3,)`` float64 world position of node ``(0, 0, 0)``.
        spacing: Grid spacing ``h`` in world units.
        occupied: ``(nx, ny, nz)`` bool; node ``(i, j, k)`` sits at
            ``origin + spacing * (i, j, k)``.

    Both arrays are read-only copies of what was passed in.
    """

    origin: np.ndarray
    spacing: float
    occupied: np.ndarray

    def __post_init__(self) -> None:
        """Copy and freeze the arrays, checking their shapes and the spacing.

        Raises:
            ValueError: ``origin`` is not 3 finite numbers, ``spacing`` is not positive and
                finite, or ``occupied`` is not 3-D.
        """
        origin = np.array(self.origin, dtype=np.float64)
        if origin.shape != (3,) or not np.isfinite(origin).all():
            raise ValueError(f"origin must be 3 finite numbers, got {self.origin!r}")
        spacing = float(self.spacing)
        if not (math.isfinite(spacing) and spacing > 0):
            raise ValueError(f"spacing must be positive and finite, got {self.spacing!r}")
        occupied = np.array(self.occupied, dtype=bool)
        if occupied.ndim != 3:
            raise ValueError(f"occupied must be a 3-D array, got shape {occupied.shape}")
        origin.flags.writeable = False
        occupied.flags.writeable = False
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "spacing", spacing)
        object.__setattr__(self, "occupied", occupied)


def node_positions(vox: Voxelization) -> np.ndarray:
    """World positions of the occupied nodes.

    Args:
        vox: A voxelization.

    Returns:
        ``(N, 3)`` float64 positions in C order (the order of ``np.nonzero(vox.occupied)``).
    """
    return vox.origin + vox.spacing * np.argwhere(vox.occupied).astype(np.float64)


def voxelize(
    mesh: trimesh.Trimesh,
    *,
    nodes_along_longest: int | None = None,
    spacing: float | None = None,
    source: str = "mesh",
) -> Voxelization:
    """Find the grid nodes whose cubes meet the solid bounded by a (possibly leaky) mesh.

    See the module docstring for the method. The grid is centred on the bounding box of the
    mesh's faces: with spacing ``h`` and box extent ``E`` along an axis, the returned grid has
    ``round(E / h) + 1`` nodes along that axis, and the box faces lie within ``h / 4`` of its
    outermost node planes, so never on a cube face.

    Args:
        mesh: Triangle mesh; vertices used by no face are ignored (they may lie outside
            every occupied cube).
        nodes_along_longest: ``n >= 2``: use ``h = L / (n - 1)`` where ``L`` is the longest
            extent of the bounding box. The two outermost nodes along that axis then sit exactly
            on the box faces (their cubes overhang the mesh by ``h / 2``), so the grid has
            exactly ``n`` nodes along it, for any mesh; a box mesh fills it completely.
        spacing: The grid spacing ``h > 0`` in world units.
        source: Name of the mesh (file or scene key) used in error messages.

    Returns:
        The occupied nodes, in a grid trimmed to them.

    Raises:
        ValueError: Not exactly one of ``nodes_along_longest`` and ``spacing`` is given, or it
            is out of range.
        InputError: The mesh has no faces, a bad face index, non-finite vertices, zero extent
            (with ``nodes_along_longest``), or the spacing makes a grid of more than
            :data:`MAX_GRID_NODES` nodes.
    """
    index_space, shape, origin, h = grid_frame(mesh, nodes_along_longest=nodes_along_longest,
                                               spacing=spacing, source=source)
    occupied = _surface_nodes(index_space, shape) | _inside_corner_nodes(index_space, shape)
    occupied = ndimage.binary_fill_holes(occupied)
    if not occupied.any():  # every finite triangle lies in some cube; kept as a safeguard
        raise InputError(f"{source}: no grid node is occupied at spacing {h:g}")
    used = [np.flatnonzero(occupied.any(axis=other)) for other in ((1, 2), (0, 2), (0, 1))]
    trim = tuple(slice(int(u[0]), int(u[-1]) + 1) for u in used)
    first = np.array([u[0] for u in used], dtype=np.float64)
    return Voxelization(origin=origin + h * first, spacing=h, occupied=occupied[trim])


def grid_frame(mesh: trimesh.Trimesh, *, nodes_along_longest: int | None, spacing: float | None,
               source: str, offset=None) -> tuple[np.ndarray, tuple[int, int, int], np.ndarray, float]:
    """The padded node grid :func:`voxelize` builds around a mesh, before any node is occupied.
    ``offset`` (3,), in cells, each in [0, 1): the nodes moved by ``-offset h`` against the mesh
    (one more plane of padding on the high side): the same body on a shifted grid.

    Returns:
        ``(triangles, shape, origin, h)``: ``(F, 3, 3)`` triangle vertices in index space (node
        ``(i, j, k)`` at integer point ``(i, j, k)``), the grid shape with one empty plane of
        padding on every side, the world position of node ``(0, 0, 0)`` and the spacing.

    Raises:
        ValueError, InputError: as :func:`voxelize`.
    """
    _check_resolution(nodes_along_longest, spacing)
    vertices = np.asarray(mesh.vertices, dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
    if len(faces) == 0:
        at = "" if spacing is None else f" at spacing {spacing:g}"
        raise InputError(f"{source}: the mesh has no faces, so no grid node is occupied{at}")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InputError(f"{source}: a face index is out of range ({len(vertices)} vertices)")
    triangles = vertices[faces]
    if not np.isfinite(triangles).all():
        raise InputError(f"{source}: the mesh has non-finite vertex coordinates")
    low, high = triangles.min(axis=(0, 1)), triangles.max(axis=(0, 1))
    extent = high - low
    if nodes_along_longest is not None:
        if extent.max() == 0:
            raise InputError(f"{source}: the mesh has zero extent, so it has no longest axis")
        h = float(extent.max()) / (nodes_along_longest - 1)
    else:
        h = float(spacing)  # type: ignore[arg-type]  # checked above
    nodes = np.rint(extent / h) + 1
    size = math.prod(float(n) + 2 for n in nodes)  # a float: no overflow
    if size > MAX_GRID_NODES:
        dims = "x".join(f"{n:.6g}" for n in nodes)
        raise InputError(
            f"{source}: spacing {h:g} is too fine for a mesh of extent "
            f"{', '.join(f'{e:g}' for e in extent)}: the grid would have {dims} nodes, "
            f"more than the {MAX_GRID_NODES} allowed"
        )
    # One empty plane of padding on every side, so the outside is connected around the mesh.
    shape = tuple(int(n) + 2 for n in nodes)
    origin = (low + high) / 2 - h * ((nodes - 1) / 2 + 1)
    if offset is not None:
        shift = np.asarray(offset, np.float64)
        if shift.shape != (3,) or not np.all((shift >= 0.0) & (shift < 1.0)):
            raise ValueError(f"grid offset must be 3 fractions of a cell in [0, 1), got {offset}")
        origin = origin - h * shift
        shape = tuple(n + int(d > 0) for n, d in zip(shape, shift))
    index_space = (triangles - origin) / h  # node (i, j, k) is at integer point (i, j, k)
    return index_space, shape, origin, h  # type: ignore[return-value]  # shape has 3 entries


def _check_resolution(nodes_along_longest: int | None, spacing: float | None) -> None:
    """Raise ValueError unless exactly one valid resolution argument is given."""
    if (nodes_along_longest is None) == (spacing is None):
        raise ValueError("give exactly one of nodes_along_longest and spacing")
    if nodes_along_longest is not None:
        if isinstance(nodes_along_longest, bool) or not isinstance(
            nodes_along_longest, (int, np.integer)
        ):
            raise ValueError(f"nodes_along_longest must be an int, got {nodes_along_longest!r}")
        if nodes_along_longest < 2:
            raise ValueError(f"nodes_along_longest must be >= 2, got {nodes_along_longest}")
    elif isinstance(spacing, bool) or not isinstance(spacing, (int, float, np.number)):
        raise ValueError(f"spacing must be a number, got {spacing!r}")
    elif not (math.isfinite(spacing) and spacing > 0):
        raise ValueError(f"spacing must be positive and finite, got {spacing!r}")


def _candidates(low: np.ndarray, counts: np.ndarray) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Enumerate, in batches, the lattice points of a box of integer points per triangle.

    Args:
        low: ``(F, d)`` int64 first lattice point of each triangle's box.
        counts: ``(F, d)`` int64 number of lattice points along each axis (0 for none).

    Yields:
        ``(triangle, point)``: ``(P,)`` triangle indices and ``(P, d)`` lattice points.
    """
    per_triangle = counts.prod(axis=1)
    ends = np.cumsum(per_triangle)
    total = int(ends[-1]) if len(ends) else 0
    for start in range(0, total, _BLOCK):
        pair = np.arange(start, min(total, start + _BLOCK), dtype=np.int64)
        triangle = np.searchsorted(ends, pair, side="right")
        local = pair - (ends[triangle] - per_triangle[triangle])
        point = np.empty((len(pair), low.shape[1]), dtype=np.int64)
        for axis in range(low.shape[1] - 1, -1, -1):
            point[:, axis] = local % counts[triangle, axis]
            local //= counts[triangle, axis]
        yield triangle, low[triangle] + point


def _surface_nodes(triangles: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """Nodes whose closed unit cube meets a triangle (triangles in index space)."""
    low = np.clip(np.ceil(triangles.min(axis=1) - 0.5), 0, np.array(shape) - 1).astype(np.int64)
    high = np.clip(np.floor(triangles.max(axis=1) + 0.5), 0, np.array(shape) - 1).astype(np.int64)
    hit = np.zeros(math.prod(shape), dtype=bool)
    for triangle, node in _candidates(low, high - low + 1):
        overlap = _triangle_meets_unit_cube(triangles[triangle] - node[:, None, :])
        hit[np.ravel_multi_index(tuple(node[overlap].T), shape)] = True
    return hit.reshape(shape)


def _triangle_meets_unit_cube(v: np.ndarray) -> np.ndarray:
    """Separating-axis test of triangles against the cube ``[-1/2, 1/2]^3``.

    The cube's own face axes are not tested: callers only pass cubes that meet the triangle's
    bounding box.

    Args:
        v: ``(P, 3, 3)`` triangle vertices relative to the cube centre.

    Returns:
        ``(P,)`` bool, True where the closed triangle and the closed cube intersect.
    """
    meets = np.ones(len(v), dtype=bool)
    for i, j in _EDGES:
        edge = v[:, j] - v[:, i]
        for a in range(3):  # axis = unit_a x edge, which has component a equal to zero
            b, c = (a + 1) % 3, (a + 2) % 3
            proj = edge[:, b, None] * v[:, :, c] - edge[:, c, None] * v[:, :, b]
            radius = 0.5 * (np.abs(edge[:, b]) + np.abs(edge[:, c]))
            meets &= (proj.min(axis=1) <= radius) & (proj.max(axis=1) >= -radius)
    normal = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    offset = np.einsum("ij,ij->i", normal, v[:, 0])
    meets &= np.abs(offset) <= 0.5 * np.abs(normal).sum(axis=1)
    return meets


def inside_points(triangles: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """Which integer points of a box are inside a (possibly leaky) surface, by the vote of their
    26 half-rays (module docstring, step 2).

    Args:
        triangles: ``(F, 3, 3)`` vertices in the points' index space (point ``(i, j, k)`` at
            integer coordinates ``(i, j, k)``).
        shape: The box of points.

    Returns:
        ``shape`` bool.
    """
    votes = np.zeros(shape, dtype=np.uint8)
    for direction in RAY_DIRECTIONS:
        votes += _odd_half_rays(triangles, shape, direction)
    # A strict majority of half-rays, i.e. more lines whose two half-rays both say inside than
    # lines whose two both say outside: a line whose half-rays disagree passed a hole or an
    # open edge, and abstains. Ties go outside, so an open sheet is never thickened.
    return votes > len(RAY_DIRECTIONS)


def _inside_corner_nodes(triangles: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """Nodes with at least one cube corner inside the surface (triangles in index space)."""
    corners = tuple(n + 1 for n in shape)
    # corner (i, j, k) is at index point (i, j, k) - 1/2
    inside = inside_points(triangles + 0.5, corners)
    nodes = np.zeros(shape, dtype=bool)
    for di, dj, dk in np.ndindex(2, 2, 2):
        nodes |= inside[di : di + shape[0], dj : dj + shape[1], dk : dk + shape[2]]
    return nodes


def _odd_half_rays(
    triangles: np.ndarray, shape: tuple[int, ...], direction: tuple[int, int, int]
) -> np.ndarray:
    """Per node, how many of its two half-rays along a lattice direction cross the surface oddly.

    The lattice is sheared so that the direction becomes the unit step along axis ``a`` (its
    first non-zero component, which is 1): ``(x_b - d_b x_a, x_c - d_c x_a, x_a)``. Nodes stay
    at integer points, each node's line along ``direction`` becomes a column, and the shear
    does not change how often a line crosses the surface.

    Args:
        triangles: ``(F, 3, 3)`` vertices in index space.
        shape: Node grid shape.
        direction: Integer direction with components in ``{-1, 0, 1}``, first non-zero one 1.

    Returns:
        ``shape`` uint8 array of 0, 1 or 2.
    """
    a = next(axis for axis in range(3) if direction[axis])
    b, c = (a + 1) % 3, (a + 2) % 3
    nodes = np.ogrid[tuple(slice(0, n) for n in shape)]  # broadcastable index ranges
    columns: list[np.ndarray] = []
    flat: list[np.ndarray] = []
    sizes: list[int] = []
    for other in (b, c):
        step = direction[other]
        offset = (shape[a] - 1) * max(step, 0)  # keeps sheared coordinates >= 0
        flat.append(triangles[:, :, other] - step * triangles[:, :, a] + offset)
        columns.append(nodes[other] - step * nodes[a] + offset)
        sizes.append(shape[other] + abs(step) * (shape[a] - 1))
    na = shape[a]
    parity = _crossing_parity(np.stack(flat, axis=2), triangles[:, :, a], sizes[0], sizes[1], na)
    column_start = (columns[0] * sizes[1] + columns[1]) * (na + 1)
    odd_below = parity.reshape(-1)[column_start + nodes[a]]
    odd_total = parity.reshape(-1)[np.broadcast_to(column_start + na, shape)]
    return odd_below + (odd_below ^ odd_total)


def _crossing_parity(
    flat: np.ndarray, depth: np.ndarray, nb: int, nc: int, na: int
) -> np.ndarray:
    """Parity of the surface crossings below each point of the lattice columns.

    Columns run along the depth axis through integer points ``(p, q)`` of the projection plane.
    Edge functions are evaluated on each edge's lexicographically ordered endpoints, so the two
    triangles sharing an edge get bit-identical values, and a point exactly on an edge belongs
    to the triangle lying left of the ordered edge. That is the exact outcome of moving every
    column by an infinitesimal step ``(-eta, 1) * eps``: a column through an edge or vertex
    counts as a column in general position would.

    Args:
        flat: ``(F, 3, 2)`` triangle vertices projected on the plane (index space).
        depth: ``(F, 3)`` vertex coordinates along the column axis (index space).
        nb: Number of lattice points along the plane's first axis.
        nc: Number along its second axis.
        na: Number of nodes along the column.

    Returns:
        ``(nb, nc, na + 1)`` uint8: entry ``[p, q, k]`` is 1 when an odd number of crossings of
        column ``(p, q)`` lie at depth ``< k`` (for ``k < na``); entry ``[p, q, na]`` is the
        parity of all of the column's crossings.
    """
    limit = np.array([nb - 1, nc - 1])
    low = np.ceil(np.minimum(np.minimum(flat[:, 0], flat[:, 1]), flat[:, 2]))
    high = np.floor(np.maximum(np.maximum(flat[:, 0], flat[:, 1]), flat[:, 2]))
    low, high = np.clip(low, 0, limit).astype(np.int64), np.clip(high, 0, limit).astype(np.int64)
    counts = np.maximum(high - low + 1, 0)
    d1, d2 = flat[:, 1] - flat[:, 0], flat[:, 2] - flat[:, 0]
    area = np.sign(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    # Most triangles are smaller than a cell and cover no column; edge-on ones cover none.
    used = (counts[:, 0] > 0) & (counts[:, 1] > 0) & (area != 0)
    flat, depth, area, low, counts = flat[used], depth[used], area[used], low[used], counts[used]
    start = np.stack([flat[:, i] for i, _ in _EDGES], axis=1)  # (F, 3 edges, 2)
    end = np.stack([flat[:, j] for _, j in _EDGES], axis=1)
    swap = (end[..., 0] < start[..., 0]) | (
        (end[..., 0] == start[..., 0]) & (end[..., 1] < start[..., 1])
    )
    first = np.where(swap[..., None], end, start)
    last = np.where(swap[..., None], start, end)
    orient = np.where(swap, -1.0, 1.0)  # +1 where the ordered edge runs along the triangle's cycle
    left = orient * area[:, None] > 0  # the triangle lies left of the ordered edge
    cells: list[np.ndarray] = []
    for triangle, column in _candidates(low, counts):
        p = column[:, None, :].astype(np.float64)
        e0, e1 = first[triangle], last[triangle]
        w = (e1[..., 0] - e0[..., 0]) * (p[..., 1] - e0[..., 1]) - (
            e1[..., 1] - e0[..., 1]
        ) * (p[..., 0] - e0[..., 0])
        hit = np.where(left[triangle], w >= 0, w < 0).all(axis=1)
        weight = w[hit] * orient[triangle[hit]]  # barycentric weights times twice the area
        crossing = (weight * depth[triangle[hit]]).sum(axis=1) / weight.sum(axis=1)
        # A crossing at depth t lies below node k exactly when floor(t) + 1 <= k.
        level = np.clip(np.floor(crossing) + 1, 0, na).astype(np.int64)
        cells.append((column[hit, 0] * nc + column[hit, 1]) * (na + 1) + level)
    parity = np.zeros(nb * nc * (na + 1), dtype=np.uint8)
    if cells:
        cell, count = np.unique(np.concatenate(cells), return_counts=True)
        parity[cell] = count & 1
    # uint8 sums wrap modulo 256, which keeps their parity
    return np.cumsum(parity.reshape(nb, nc, na + 1), axis=2, dtype=np.uint8) & 1
