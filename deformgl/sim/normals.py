"""Packed normals (Mosegaard & Sørensen 2005, eq. 3 and section 3.2), NumPy side.

The approximate normal of a node is packed into the alpha channel of its RGBA32F position texel.
A float32 render target must carry it bit-exactly, so the packed value is always a *normal*
positive float (never NaN, Inf, a denormal or negative): the octahedral coordinates of the
direction, quantised to ``LEVELS + 1`` = 46,159 steps each (15.5 bits), give an index
``c = qx * 46159 + qy < 2^31 - 2^24``, stored as the float whose bit pattern is ``c + 2^23``
(exponent field 1..254). Round trip error at most 0.006 degrees. A node whose unit-vector sum is
short has no defined normal and stores :data:`NO_NORMAL` (0.0, bit pattern 0: not a denormal).
``shaders/lib/octahedral.glsl`` is the GLSL twin (``floatBitsToUint``/``uintBitsToFloat``).
"""

from __future__ import annotations

import numpy as np

#: Quantisation steps per octahedral coordinate minus one: (LEVELS + 1)^2 < 2^31 - 2^24.
LEVELS = 46158
_BIAS = 1 << 23  # lifts every code into the normal-float range (exponent field >= 1)
NO_NORMAL = 0.0
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
    """Pack direction vectors (N, 3), any length, into float32 codes; short ones -> NO_NORMAL."""
    v = np.asarray(vectors, dtype=np.float64)
    length = np.linalg.norm(v, axis=-1)
    ok = length >= MIN_SUM_LENGTH
    safe = np.where(ok[..., None], v, np.array([0.0, 0.0, 1.0]))
    q = np.rint(np.clip(octahedral_encode(safe) * 0.5 + 0.5, 0.0, 1.0) * LEVELS).astype(np.uint32)
    bits = q[..., 0] * np.uint32(LEVELS + 1) + q[..., 1] + np.uint32(_BIAS)
    return np.where(ok, bits, np.uint32(0)).astype(np.uint32).view(np.float32)


def unpack_normals(packed: np.ndarray) -> np.ndarray:
    """Unpack float32 codes into unit vectors (N, 3); NO_NORMAL gives the zero vector."""
    bits = np.ascontiguousarray(packed, dtype=np.float32).view(np.uint32)
    valid = bits >= _BIAS
    c = np.where(valid, bits - np.uint32(_BIAS), 0).astype(np.int64)
    e = np.stack([c // (LEVELS + 1), c % (LEVELS + 1)], axis=-1) / LEVELS * 2.0 - 1.0
    return np.where(valid[..., None], octahedral_decode(e), 0.0)


def unit_sums(grid, x: np.ndarray) -> np.ndarray:
    """(N, 3) sum of the unit vectors ``(p_i - p_j)/|p_i - p_j|`` to the existing ones of each
    node's 18 neighbours (Mosegaard & Sørensen 2005, eq. 3; the normal before packing).

    Args:
        grid: the :class:`~deformgl.grid.nodes.NodeGrid`.
        x: (N, 3) float64 positions.
    """
    x = np.asarray(x, dtype=np.float64)
    total = np.zeros_like(x)
    for j in range(grid.neighbours.shape[1]):  # one neighbour at a time: (N, 3) temporaries only
        nb = grid.neighbours[:, j]
        present = nb >= 0
        d = x[present] - x[nb[present]]                                # p_i - p_j
        length = np.linalg.norm(d, axis=1, keepdims=True)
        total[present] += d / np.where(length > 0, length, 1.0)
    return total


def rest_normals(grid) -> np.ndarray:
    """(N, 3) rest node normals (Mosegaard & Sørensen 2005, eq. 3) exactly as the GPU unpacks
    them (zero where undefined): the unit-vector sums of the rest positions, packed and unpacked."""
    return unpack_normals(pack_normals(unit_sums(grid, grid.rest_positions)))
