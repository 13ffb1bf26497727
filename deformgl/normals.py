"""Packed normals (Mosegaard & Sørensen 2005, eq. 3 and section 3.2), NumPy side.

The approximate normal of a node is packed into the alpha channel of its RGBA32F position texel.
A float32 render target must carry it bit-exactly, so the packed value is an *integer* below
2^24 (exact in float32, never NaN, Inf or denormal): two 12-bit octahedral coordinates,
``packed = qx * 4096 + qy``. A node whose unit-vector sum is (near) zero has no defined normal
and stores :data:`NO_NORMAL` (-1.0). ``shaders/lib/octahedral.glsl`` is the GLSL twin.
"""

from __future__ import annotations

import numpy as np

BITS = 12
LEVELS = (1 << BITS) - 1  # 4095
NO_NORMAL = -1.0
#: A unit-vector sum shorter than this has no reliable direction. On a surface the sum of
#: neighbour unit vectors is at least about 0.9 (a flat face gives 3.8); interior nodes and nodes
#: with symmetric neighbours (grooves, one-node-thin parts) give 0 at rest and small, erratic
#: vectors once deformed.
MIN_SUM_LENGTH = 0.5


def _sign_not_zero(v: np.ndarray) -> np.ndarray:
    return np.where(v >= 0.0, 1.0, -1.0)


def octahedral_encode(n: np.ndarray) -> np.ndarray:
    """Unit vectors (N, 3) -> octahedral coordinates (N, 2) in [-1, 1]."""
    n = np.asarray(n, dtype=np.float64)
    p = n / np.sum(np.abs(n), axis=-1, keepdims=True)
    xy = p[..., :2]
    folded = (1.0 - np.abs(xy[..., ::-1])) * _sign_not_zero(xy)
    return np.where(p[..., 2:3] >= 0.0, xy, folded)


def octahedral_decode(e: np.ndarray) -> np.ndarray:
    """Octahedral coordinates (N, 2) -> unit vectors (N, 3)."""
    e = np.asarray(e, dtype=np.float64)
    z = 1.0 - np.abs(e[..., 0]) - np.abs(e[..., 1])
    t = np.clip(-z, 0.0, None)[..., None]
    xy = e - t * _sign_not_zero(e)
    v = np.concatenate([xy, z[..., None]], axis=-1)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def pack_normals(vectors: np.ndarray) -> np.ndarray:
    """Pack direction vectors (N, 3), any length, into float32 integers; zero-ish -> NO_NORMAL."""
    v = np.asarray(vectors, dtype=np.float64)
    length = np.linalg.norm(v, axis=-1)
    ok = length >= MIN_SUM_LENGTH
    safe = np.where(ok[..., None], v, np.array([0.0, 0.0, 1.0]))
    e = octahedral_encode(safe)
    q = np.rint(np.clip(e * 0.5 + 0.5, 0.0, 1.0) * LEVELS).astype(np.int64)
    packed = (q[..., 0] * (LEVELS + 1) + q[..., 1]).astype(np.float32)
    return np.where(ok, packed, np.float32(NO_NORMAL)).astype(np.float32)


def unpack_normals(packed: np.ndarray) -> np.ndarray:
    """Unpack float32 integers into unit vectors (N, 3); NO_NORMAL gives the zero vector."""
    p = np.asarray(packed, dtype=np.float64)
    valid = p >= 0.0
    q = np.where(valid, p, 0.0).astype(np.int64)
    e = np.stack([q // (LEVELS + 1), q % (LEVELS + 1)], axis=-1) / LEVELS * 2.0 - 1.0
    return np.where(valid[..., None], octahedral_decode(e), 0.0)
