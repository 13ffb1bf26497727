"""Normals under a trilinear transformation (Knuth, Kohlhammer & Kuijper, section 4.2): the
``direct`` mode (inverse-transpose Jacobian) and the ``tangent`` mode (transformed tangents),
plus a finite-difference Jacobian for checks."""

from __future__ import annotations

import numpy as np

from deformgl.errors import InputError
from deformgl.trilinear.cuboid import Function

NORMAL_MODES = ("direct", "tangent")


def tangent_frame(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A tangent and bitangent with ``t x b = n`` for (N, 3) unit normals (GLSL twin in cuboid.glsl)."""
    n = np.asarray(normals, dtype=np.float64)
    helper = np.where((np.abs(n[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    t = np.cross(helper, n)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return t, np.cross(n, t)


def transform_normals(jacobians: np.ndarray, normals: np.ndarray, mode: str) -> np.ndarray:
    """Transform (N, 3) normals by the Jacobians (N, 3, 3) at their vertices (4.2).

    ``"direct"`` transforms the normal like a direction: ``J n`` (smooth across cells, not
    necessarily orthogonal to the surface). ``"tangent"`` transforms the tangent frame and takes
    ``sign(det J) (J t) x (J b)``: orthogonal to the deformed surface, with seams at cell borders.

    Returns:
        (N, 3) unit normals.
    """
    if mode not in NORMAL_MODES:
        raise InputError(f"normal mode must be one of {NORMAL_MODES}, got {mode!r}")
    n = np.asarray(normals, dtype=np.float64)
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    if mode == "direct":
        out = np.einsum("nij,nj->ni", jacobians, n)
    else:
        t, b = tangent_frame(n)
        out = np.cross(np.einsum("nij,nj->ni", jacobians, t), np.einsum("nij,nj->ni", jacobians, b))
        out *= np.sign(np.linalg.det(jacobians))[:, None]
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def finite_difference_jacobian(f: Function, points: np.ndarray, step: float) -> np.ndarray:
    """Central-difference Jacobian of ``f`` at (N, 3) points: (N, 3, 3)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    cols = []
    for a in range(3):
        e = np.zeros(3)
        e[a] = step
        cols.append((f(p + e) - f(p - e)) / (2.0 * step))
    return np.stack(cols, -1)
