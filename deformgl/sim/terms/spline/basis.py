"""The quadratic B-spline basis on the node grid and the Gauss points of a knot span.

Node ``i`` of a grid of spacing h at ``X_i`` is the control point of the uniform quadratic
B-spline centred on it, ``N_i(x) = B((x - X_i) / h)`` per axis, with

    B(t) = 3/4 - t^2            for |t| <= 1/2,
    B(t) = (3/2 - |t|)^2 / 2    for 1/2 <= |t| <= 3/2,   0 beyond

(knots at ``X_i ± h/2`` and ``X_i ± 3h/2``; Piegl & Tiller 1997, eq. 2.5 on a uniform knot vector).
The knot span of node c is ``[X_c - h/2, X_c + h/2]`` along each axis; in it exactly the 3 x 3 x 3
nodes ``c + (dx, dy, dz)``, ``d in {-1, 0, 1}``, are non-zero, and with the span's coordinate
``s = (x - X_c) / h`` in [-1/2, 1/2] they are ``(1/2 - s)^2 / 2``, ``3/4 - s^2`` and
``(1/2 + s)^2 / 2``. They sum to 1 and reproduce linear functions (``sum X_i N_i(x) = x``), so a
body at rest is its control points at the nodes' rest positions.
"""

from __future__ import annotations

import itertools

import numpy as np

__all__ = ["SPAN_OFFSETS", "axis_basis", "span_basis", "gauss_box"]

#: The 27 nodes of a knot span relative to its centre node, z fastest (``np.argwhere`` order).
SPAN_OFFSETS = np.array(list(itertools.product((-1, 0, 1), repeat=3)), dtype=np.int64)


def axis_basis(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The three non-zero basis functions of a span along one axis at span coordinates ``s``
    (..., in [-1/2, 1/2]): values (..., 3) and their derivatives d/ds (..., 3), for the nodes at
    offsets -1, 0, +1."""
    s = np.asarray(s, np.float64)
    values = np.stack([0.5 * (0.5 - s) ** 2, 0.75 - s * s, 0.5 * (0.5 + s) ** 2], axis=-1)
    slopes = np.stack([s - 0.5, -2.0 * s, s + 0.5], axis=-1)
    return values, slopes


def span_basis(s: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """The 27 basis functions of a span (:data:`SPAN_OFFSETS` order) at span coordinates ``s``
    (..., 3): values (..., 27) and gradients in world units (..., 27, 3), 1/m."""
    values, slopes = axis_basis(s)  # (..., 3 axes, 3 offsets)
    dx, dy, dz = SPAN_OFFSETS.T + 1
    vx, vy, vz = values[..., 0, dx], values[..., 1, dy], values[..., 2, dz]
    sx, sy, sz = slopes[..., 0, dx], slopes[..., 1, dy], slopes[..., 2, dz]
    gradients = np.stack([sx * vy * vz, vx * sy * vz, vx * vy * sz], axis=-1) / spacing
    return vx * vy * vz, gradients


#: 3-point Gauss-Legendre on [-1, 1], exact to degree 5 per axis: inside a span the stiffness
#: integrands (products of two gradients) and the consistent mass are of degree at most 4 per axis,
#: so a box of material in a span is integrated exactly.
_GAUSS_POINTS, _GAUSS_WEIGHTS = np.polynomial.legendre.leggauss(3)


def gauss_box(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """3 x 3 x 3 Gauss points of the boxes [lo, hi] (B, 3) in span coordinates: points (B, 27, 3)
    and weights (B, 27) that sum to each box's volume in span units (multiply by h^3 for m^3)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    half, mid = (hi - lo) / 2.0, (hi + lo) / 2.0
    grid = np.array(list(itertools.product(range(3), repeat=3)))
    unit = _GAUSS_POINTS[grid]  # (27, 3)
    weights = np.prod(_GAUSS_WEIGHTS[grid], axis=1)  # (27,)
    points = mid[:, None, :] + half[:, None, :] * unit[None]
    return points, weights[None, :] * np.prod(half, axis=1)[:, None]
