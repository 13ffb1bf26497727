"""Anchors on a deforming triangle mesh and the attachment grids they drive (Knuth, Kohlhammer &
Kuijper, section 5), on the CPU in float64 NumPy.

An anchor is two points registered on one triangle of the base mesh by barycentric coordinates:
the anchor position and a second point giving the tangent direction. With the triangle's normal
they define a local frame, recomputed from the mesh's current vertex positions whatever animates
the mesh. A 1D or 2D array of anchors builds the :class:`~deformgl.trilinear.grid.Trilinear` grid of an
attached object, so that the object follows the surface:

* 2D, anchors (I, J): lattice point (i, j, k) = origin_ij + z_k normal_ij, cells (I-1, J-1, 1);
* 1D, anchors (I,): lattice point (i, j, k) = origin_i + y_j bitangent_i + z_k normal_i, cells
  (I-1, 1, 1);

where y_j and z_k are the attached object's box bounds (its local y across the strip, z the
height above the surface). Anchors spaced like the box's lattice on a flat rest surface give the
identity at rest.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import cast

import numpy as np

from deformgl.errors import InputError
from deformgl.trilinear.cuboid import Box
from deformgl.trilinear.grid import Trilinear


@dataclass(frozen=True)
class Anchor:
    """One anchor (section 5).

    Attributes:
        triangle: index of the triangle of the base mesh.
        point: barycentric coordinates (3,) of the anchor position on that triangle.
        tangent_point: barycentric coordinates (3,) of the point giving the tangent direction.
    """

    triangle: int
    point: tuple[float, float, float]
    tangent_point: tuple[float, float, float]


@dataclass(frozen=True)
class Frames:
    """Local frames of an array of anchors; every field has the array's shape + (3,).

    ``tangent``, ``bitangent`` and ``normal`` are orthonormal and right-handed
    (``tangent x bitangent = normal``).
    """

    origin: np.ndarray
    tangent: np.ndarray
    bitangent: np.ndarray
    normal: np.ndarray


class AnchorArray:
    """A 1D (I,) or 2D (I, J) array of anchors, stored as arrays for vectorized updates.

    Args:
        triangles: int array of the array's shape.
        points: barycentric anchor positions, shape + (3,).
        tangent_points: barycentric tangent points, shape + (3,).

    Raises:
        InputError: bad shapes, fewer than 2 anchors along an axis, or barycentric coordinates
            that do not sum to 1.
    """

    def __init__(self, triangles: np.ndarray, points: np.ndarray, tangent_points: np.ndarray) -> None:
        self.triangles = np.asarray(triangles, dtype=np.int64)
        self.points = np.asarray(points, dtype=np.float64)
        self.tangent_points = np.asarray(tangent_points, dtype=np.float64)
        shape = self.triangles.shape
        if len(shape) not in (1, 2) or min(shape) < 2:
            raise InputError(f"an anchor array must be 1D or 2D with at least 2 anchors per axis, got {shape}")
        for name, bary in (("point", self.points), ("tangent_point", self.tangent_points)):
            if bary.shape != shape + (3,):
                raise InputError(f"anchor {name}s need shape {shape + (3,)}, got {bary.shape}")
            if not np.all(np.isfinite(bary)) or not np.allclose(bary.sum(-1), 1.0, atol=1e-9):
                raise InputError(f"anchor {name}s must be finite barycentric coordinates summing to 1")

    @classmethod
    def of(cls, anchors: Sequence[Anchor] | Sequence[Sequence[Anchor]]) -> AnchorArray:
        """From a list (1D) or a list of equal-length lists (2D) of :class:`Anchor`."""
        rows: list[Anchor | Sequence[Anchor]] = list(anchors)
        shape: tuple[int, ...]
        flat: Sequence[object]
        if rows and not isinstance(rows[0], Anchor):
            table = [list(cast("Sequence[Anchor]", r)) for r in rows]
            if len({len(r) for r in table}) != 1:
                raise InputError("a 2D anchor array needs rows of equal length")
            flat, shape = [x for r in table for x in r], (len(table), len(table[0]))
        else:
            flat, shape = rows, (len(rows),)
        items = [x for x in flat if isinstance(x, Anchor)]
        if len(items) != len(flat):
            raise InputError("an anchor array needs Anchor items")
        return cls(np.array([x.triangle for x in items], dtype=np.int64).reshape(shape),
                   np.array([x.point for x in items], dtype=np.float64).reshape(shape + (3,)),
                   np.array([x.tangent_point for x in items], dtype=np.float64).reshape(shape + (3,)))

    @classmethod
    def on_mesh(cls, vertices: np.ndarray, triangles: np.ndarray, positions: np.ndarray,
                tangent_positions: np.ndarray) -> AnchorArray:
        """Register anchors at surface ``positions`` (shape + (3,)) with tangent points, each
        on the triangle that contains its projection and is nearest (:func:`locate_on_mesh`)."""
        pos = np.asarray(positions, dtype=np.float64)
        tan = np.asarray(tangent_positions, dtype=np.float64)
        if pos.shape != tan.shape or pos.shape[-1] != 3:
            raise InputError(f"anchor positions {pos.shape} and tangent positions {tan.shape} must match (..., 3)")
        tri, bary = locate_on_mesh(vertices, triangles, pos.reshape(-1, 3))
        tb = barycentric(np.asarray(vertices, np.float64)[np.asarray(triangles)[tri]], tan.reshape(-1, 3))
        shape = pos.shape[:-1]
        return cls(tri.reshape(shape), bary.reshape(shape + (3,)), tb.reshape(shape + (3,)))

    @property
    def shape(self) -> tuple[int, ...]:
        """(I,) or (I, J)."""
        return self.triangles.shape

    def frames(self, vertices: np.ndarray, triangles: np.ndarray) -> Frames:
        """The anchors' frames on the mesh's current vertex positions (N, 3) (section 5)."""
        return anchor_frames(self, vertices, triangles)

    def grid(self, vertices: np.ndarray, triangles: np.ndarray, box: Box) -> Trilinear:
        """The attached object's deformation grid over its ``box`` (see the module docstring)."""
        return attachment_grid(self.frames(vertices, triangles), box)


def barycentric(corners: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Barycentric coordinates (N, 3) of points (N, 3) projected into triangles (N, 3, 3)."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    e1, e2, d = b - a, c - a, points - a
    d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    d1, d2 = (d * e1).sum(1), (d * e2).sum(1)
    den = d11 * d22 - d12 * d12
    if np.any(np.abs(den) <= 1e-300):
        raise InputError("barycentric coordinates on a degenerate triangle")
    v = (d22 * d1 - d12 * d2) / den
    w = (d11 * d2 - d12 * d1) / den
    return np.stack([1.0 - v - w, v, w], 1)


def locate_on_mesh(vertices: np.ndarray, triangles: np.ndarray, points: np.ndarray,
                   tol: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """For each point, the nearest triangle whose projection contains it, and the barycentric
    coordinates there (brute force over all triangles; meant for registering anchors).

    Raises:
        InputError: a point projects into no triangle.
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    normal = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    area2 = np.linalg.norm(normal, axis=1)
    usable = np.flatnonzero(area2 > 1e-12 * max(float(np.ptp(v, axis=0).max()), 1e-300) ** 2)
    t = t[usable]                                          # zero-area faces hold no anchor
    corners = v[t]                                         # (T, 3, 3)
    normal = normal[usable] / area2[usable, None]
    tri_out = np.empty(len(p), dtype=np.int64)
    bary_out = np.empty((len(p), 3))
    for i, q in enumerate(p):
        bary = barycentric(corners, np.broadcast_to(q, (len(t), 3)))
        dist = np.abs(((q - corners[:, 0]) * normal).sum(1))
        inside = np.all(bary >= -tol, axis=1)
        if not inside.any():
            raise InputError(f"anchor point {q.tolist()} does not project into any triangle of the mesh")
        best = np.flatnonzero(inside)[np.argmin(dist[inside])]
        tri_out[i], bary_out[i] = usable[best], bary[best]
    return tri_out, bary_out


def anchor_frames(anchors: AnchorArray, vertices: np.ndarray, triangles: np.ndarray) -> Frames:
    """Frames of all anchors from the current vertex positions, vectorized.

    origin = barycentric interpolation of the triangle's vertices; normal = the triangle's unit
    normal; tangent = direction to the tangent point projected into the tangent plane;
    bitangent = normal x tangent.

    Raises:
        InputError: wrong vertex array, a triangle index out of range, a degenerate triangle, or
            a tangent point on the anchor's normal line.
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
        raise InputError(f"vertex positions must be finite (N, 3), got shape {v.shape}")
    tri = anchors.triangles.reshape(-1)
    if tri.min() < 0 or tri.max() >= len(t):
        raise InputError(f"anchor triangle index out of range (mesh has {len(t)} triangles)")
    corners = v[t[tri]]                                    # (k, 3, 3)
    origin = np.einsum("kc,kcd->kd", anchors.points.reshape(-1, 3), corners)
    target = np.einsum("kc,kcd->kd", anchors.tangent_points.reshape(-1, 3), corners)
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    if np.any(length <= 1e-300):
        raise InputError("an anchor lies on a degenerate triangle")
    normal /= length
    d = target - origin
    tangent = d - (d * normal).sum(1, keepdims=True) * normal
    tl = np.linalg.norm(tangent, axis=1, keepdims=True)
    if np.any(tl <= 1e-12 * np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)):
        raise InputError("an anchor's tangent point coincides with the anchor or lies on its normal")
    tangent /= tl
    shape = anchors.shape + (3,)
    return Frames(origin.reshape(shape), tangent.reshape(shape), np.cross(normal, tangent).reshape(shape),
                  normal.reshape(shape))


def attachment_grid(frames: Frames, box: Box) -> Trilinear:
    """The trilinear grid of an attached object from 1D or 2D anchor frames (section 5).

    Args:
        frames: frames of an (I,) or (I, J) anchor array.
        box: the attached object's box; x runs across anchors i, y across anchors j (2D) or
            along the bitangent (1D), z along the normal (height above the surface).

    Returns:
        The grid, (I-1, J-1, 1) cells (2D) or (I-1, 1, 1) cells (1D).
    """
    lo, hi = box.lo, box.hi
    heights = np.array([lo[2], hi[2]])
    o, n = frames.origin, frames.normal
    if o.ndim == 3:                                        # 2D: (I, J, 3)
        pts = o[:, :, None, :] + heights[None, None, :, None] * n[:, :, None, :]
    elif o.ndim == 2:                                      # 1D: (I, 3)
        across = np.array([lo[1], hi[1]])
        pts = (o[:, None, None, :] + across[None, :, None, None] * frames.bitangent[:, None, None, :]
               + heights[None, None, :, None] * n[:, None, None, :])
    else:
        raise InputError(f"anchor frames must come from a 1D or 2D array, got origin shape {o.shape}")
    return Trilinear(box, pts)
