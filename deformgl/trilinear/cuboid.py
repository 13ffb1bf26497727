"""One trilinear transformation, float64 NumPy (Knuth, Kohlhammer & Kuijper, sections 3.1-3.2).

A trilinear transformation maps the unit cube onto a cuboid given by eight corner points
``p0 ... p7``. Corner ``i`` sits at unit-cube position ``(i & 1, i >> 1 & 1, i >> 2 & 1)``, the
order of Knuth, Kohlhammer & Kuijper, eq. 1. Two equal forms:

* their eq. 1: ``T(u) = sum_i w_i(u) p_i`` with the eight product weights :func:`corner_weights`;
* their Knuth, Kohlhammer & Kuijper, eq. 2-4: ``T(u) = C v(u)`` with the 3x8 coefficient matrix ``C``
  (:func:`coefficient_matrix`) and the parameter vector ``v = (xyz, yz, xz, xy, z, y, x, 1)``
  (:func:`parameter_vector`).

The right half of ``C`` is an affine 3x4 matrix; the left half is zero exactly when the cuboid
is a parallelepiped, i.e. the transformation is linear (section 3.2, :func:`is_linear_coefficients`).
Also here: :class:`Box`, the axis-aligned bounding box a grid spans, and unit lattices.
The GLSL twin is ``shaders/trilinear/cuboid.glsl``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from deformgl.errors import InputError

#: (8, 3) unit-cube position of corner i = x + 2y + 4z, the order of Knuth, Kohlhammer & Kuijper, eq. 1.
CORNERS = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=np.float64)

#: Rows of Knuth, Kohlhammer & Kuijper, eq. 2: C^T = EQ2 @ (p0 ... p7), one row per entry of v
#: (their Knuth, Kohlhammer & Kuijper, eq. 3).
EQ2 = np.array([
    [-1, 1, 1, -1, 1, -1, -1, 1],   # xyz: p7 - p6 - p5 + p4 - p3 + p2 + p1 - p0
    [1, 0, -1, 0, -1, 0, 1, 0],     # yz:  p6 - p4 - p2 + p0
    [1, -1, 0, 0, -1, 1, 0, 0],     # xz:  p5 - p4 - p1 + p0
    [1, -1, -1, 1, 0, 0, 0, 0],     # xy:  p3 - p2 - p1 + p0
    [-1, 0, 0, 0, 1, 0, 0, 0],      # z:   p4 - p0
    [-1, 0, 1, 0, 0, 0, 0, 0],      # y:   p2 - p0
    [-1, 1, 0, 0, 0, 0, 0, 0],      # x:   p1 - p0
    [1, 0, 0, 0, 0, 0, 0, 0],       # 1:   p0
], dtype=np.float64)

#: Default tolerance of the linearity test, relative to the size of the cuboid.
LINEAR_RTOL = 1e-9

#: Largest cell count per axis that composition refines to (section 4.1 resampling).
MAX_COMPOSED_CELLS = 256

Function = Callable[[np.ndarray], np.ndarray]


def corner_weights(u: np.ndarray) -> np.ndarray:
    """Knuth, Kohlhammer & Kuijper, Eq. 1 weights ``(1-x)(1-y)(1-z), x(1-y)(1-z), ..., xyz``.

    Args:
        u: (..., 3) unit-cube coordinates.

    Returns:
        (..., 8) weights, one per corner in Knuth, Kohlhammer & Kuijper, eq. 1 order.
    """
    u = np.asarray(u, dtype=np.float64)
    x, y, z = u[..., 0], u[..., 1], u[..., 2]
    ox, oy, oz = 1.0 - x, 1.0 - y, 1.0 - z
    xy = (ox * oy, x * oy, ox * y, x * y)
    w = np.empty((*u.shape[:-1], 8))
    for i in range(4):
        w[..., i] = xy[i] * oz
        w[..., 4 + i] = xy[i] * z
    return w


def corner_weight_gradients(u: np.ndarray) -> np.ndarray:
    """Derivatives of the Knuth, Kohlhammer & Kuijper, eq. 1 weights: (..., 3, 8), row a = d w / d u_a."""
    u = np.asarray(u, dtype=np.float64)
    x, y, z = u[..., 0], u[..., 1], u[..., 2]
    ox, oy, oz = 1.0 - x, 1.0 - y, 1.0 - z
    out = np.empty((*u.shape[:-1], 3, 8))
    dx = (-oy, oy, -y, y)               # d/dx of the x-y factor of corners 0-3
    dy = (-ox, -x, ox, x)
    xy = (ox * oy, x * oy, ox * y, x * y)
    for i in range(4):
        out[..., 0, i], out[..., 0, 4 + i] = dx[i] * oz, dx[i] * z
        out[..., 1, i], out[..., 1, 4 + i] = dy[i] * oz, dy[i] * z
        out[..., 2, i], out[..., 2, 4 + i] = -xy[i], xy[i]
    return out


def trilinear_corners(corners: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Knuth, Kohlhammer & Kuijper, Eq. 1: transform unit-cube points by the cuboid ``corners``.

    Args:
        corners: (8, 3) or (k, 8, 3) corner points in Knuth, Kohlhammer & Kuijper, eq. 1 order.
        u: (N, 3) unit-cube points (for stacked corners: (k, N, 3) or shared (N, 3)).

    Returns:
        (N, 3) or (k, N, 3) transformed points.
    """
    return corner_weights(u) @ np.asarray(corners, dtype=np.float64)


def coefficient_matrix(corners: np.ndarray) -> np.ndarray:
    """Knuth, Kohlhammer & Kuijper, Eq. 2: the 3x8 coefficient matrix ``C`` of a cuboid (vectorized over leading axes).

    Args:
        corners: (..., 8, 3) corner points in Knuth, Kohlhammer & Kuijper, eq. 1 order.

    Returns:
        (..., 3, 8): column j multiplies entry j of the parameter vector (eq. 3).
    """
    return np.swapaxes(EQ2 @ np.asarray(corners, dtype=np.float64), -1, -2)


def parameter_vector(u: np.ndarray) -> np.ndarray:
    """Knuth, Kohlhammer & Kuijper, Eq. 3: ``v = (xyz, yz, xz, xy, z, y, x, 1)`` for (..., 3) points, shape (..., 8)."""
    u = np.asarray(u, dtype=np.float64)
    x, y, z = u[..., 0], u[..., 1], u[..., 2]
    return np.stack([x * y * z, y * z, x * z, x * y, z, y, x, np.ones_like(x)], -1)


def apply_coefficients(coefficients: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Knuth, Kohlhammer & Kuijper, Eq. 4: ``v' = C v`` for (N, 3) unit-cube points and a (3, 8) matrix; returns (N, 3)."""
    return parameter_vector(u) @ np.asarray(coefficients, dtype=np.float64).T


def is_linear_coefficients(coefficients: np.ndarray, rtol: float = LINEAR_RTOL) -> np.ndarray:
    """The section 3.2 test: is the left half of ``C`` zero within ``rtol`` times the size?

    The size is the largest edge column of the right half (|p1-p0|, |p2-p0|, |p4-p0|) together
    with the left half itself, so a cuboid collapsed to a point is linear and a bent one is not.
    A floor of a few float64 roundings of the coordinates' magnitude (|p0| + the columns) keeps a
    tiny parallelepiped far from the origin linear.

    Args:
        coefficients: (..., 3, 8) coefficient matrices (Knuth, Kohlhammer & Kuijper, eq. 2).
        rtol: tolerance relative to the size.

    Returns:
        bool array of the leading shape (a 0-d array for one matrix).
    """
    c = np.asarray(coefficients, dtype=np.float64)
    norms = np.linalg.norm(c, axis=-2)                    # (..., 8) column lengths
    left = norms[..., :4].max(-1)
    size = np.maximum(norms[..., 4:7].max(-1), left)
    rounding = 32.0 * np.finfo(np.float64).eps * norms.sum(-1)
    return left <= rtol * size + rounding


@dataclass(frozen=True, eq=False)
class Box:
    """An axis-aligned bounding box mapped to the unit cube (section 4).

    Attributes:
        lo: (3,) float64 minimum corner.
        hi: (3,) float64 maximum corner, ``hi > lo`` on every axis.
    """

    lo: np.ndarray
    hi: np.ndarray

    def __post_init__(self) -> None:
        lo = np.asarray(self.lo, dtype=np.float64).reshape(3)
        hi = np.asarray(self.hi, dtype=np.float64).reshape(3)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)):
            raise InputError(f"box needs finite lo < hi on every axis, got lo={lo}, hi={hi}")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)

    @classmethod
    def of_points(cls, points: np.ndarray, min_fraction: float = 1e-3) -> Box:
        """Bounding box of (N, 3) points; flat axes are widened to ``min_fraction`` of the diagonal."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(p) == 0 or not np.all(np.isfinite(p)):
            raise InputError("bounding box of an empty or non-finite point set")
        lo, hi = p.min(0), p.max(0)
        pad = np.maximum(min_fraction * max(float(np.linalg.norm(hi - lo)), 1e-12) - (hi - lo), 0.0) / 2
        return cls(lo - pad, hi + pad)

    @property
    def size(self) -> np.ndarray:
        """(3,) edge lengths."""
        return self.hi - self.lo

    def to_unit(self, points: np.ndarray) -> np.ndarray:
        """Map (..., 3) points of the box to unit-cube coordinates."""
        return (np.asarray(points, dtype=np.float64) - self.lo) / self.size

    def from_unit(self, u: np.ndarray) -> np.ndarray:
        """Map (..., 3) unit-cube coordinates to points of the box."""
        return self.lo + np.asarray(u, dtype=np.float64) * self.size

    def corners(self) -> np.ndarray:
        """(8, 3) corners in Knuth, Kohlhammer & Kuijper, eq. 1 order."""
        return self.from_unit(CORNERS)


def unit_lattice(cells: tuple[int, int, int]) -> np.ndarray:
    """(nx + 1, ny + 1, nz + 1, 3) unit-cube coordinates of the lattice points of a grid."""
    axes = [np.linspace(0.0, 1.0, n + 1) for n in cells]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1)


def grid_corners(points: np.ndarray) -> np.ndarray:
    """(..., 8, 3) outer corners, in Knuth, Kohlhammer & Kuijper, eq. 1 order, of (..., nx+1, ny+1, nz+1, 3) lattices."""
    p = np.asarray(points)
    return np.stack([p[..., -(i & 1), -((i >> 1) & 1), -((i >> 2) & 1), :] for i in range(8)], -2)
