"""Closest points on a triangle surface, vectorised NumPy: for each point the nearest of its
candidate triangles and the barycentric weights of the closest point on it (Mosegaard &
Sørensen 2005, eq. 4), in blocks of bounded memory. :func:`deformgl.mapping.binding.bind` uses it
to find where each vertex of the detailed mesh sits on the node surface."""

from __future__ import annotations

import itertools

import numpy as np
from scipy.spatial import cKDTree

#: Most (vertex, candidate triangle) pairs :func:`closest_on_triangles` handles at once (about
#: 0.5 KB of temporaries each).
PAIR_BLOCK = 1 << 20


def row_dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products of two (n, k) arrays: (n,)."""
    return np.einsum("ij,ij->i", a, b)


def _triangle_weights(ap: np.ndarray, ab: np.ndarray, ac: np.ndarray, abab: np.ndarray, abac: np.ndarray,
                      acac: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weights (v, w) of corners b and c of the closest point on non-degenerate triangles.

    Ericson, Real-Time Collision Detection, 5.1.5: the Voronoi region of the point decides
    between a corner, an edge and the interior (the first region test that holds wins). With
    ``ap = p - a``, ``ab = b - a``, ``ac = c - a``: ``d1 = ab.ap``, ``d2 = ac.ap``, and the dot
    products with ``bp = ap - ab`` and ``cp = ap - ac`` follow from ``ab.ab``, ``ab.ac``,
    ``ac.ac``. Every denominator is a squared edge length or ``|ab x ac|^2``, positive for a
    non-degenerate triangle. The weight of corner a is ``1 - v - w``.
    """
    d1, d2 = row_dot(ab, ap), row_dot(ac, ap)
    d3, d4 = d1 - abab, d2 - abac
    d5, d6 = d1 - abac, d2 - acac
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2

    def ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
        return np.clip(num / np.where(den > 0, den, 1.0), 0.0, 1.0)

    t_ab, t_ac = ratio(d1, d1 - d3), ratio(d2, d2 - d6)
    t_bc = ratio(d4 - d3, (d4 - d3) + (d5 - d6))
    den = va + vb + vc
    zero, one = np.zeros_like(d1), np.ones_like(d1)
    regions = [
        (d1 <= 0) & (d2 <= 0),                           # corner a
        (d3 >= 0) & (d4 <= d3),                          # corner b
        (vc <= 0) & (d1 >= 0) & (d3 <= 0),               # edge ab
        (d6 >= 0) & (d5 <= d6),                          # corner c
        (vb <= 0) & (d2 >= 0) & (d6 <= 0),               # edge ac
        (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0),     # edge bc
    ]
    v = np.select(regions, [zero, one, t_ab, zero, zero, 1.0 - t_bc], ratio(vb, den))
    w = np.select(regions, [zero, zero, zero, one, t_ac, t_bc], ratio(vc, den))
    w = np.minimum(w, 1.0 - v)                           # interior rounding: keep 1 - v - w >= 0
    return v, w


def _segment_weights(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Weights (M, 3) of the closest point on the three edges of (degenerate) triangles."""
    corners = (a, b, c)
    best = np.full(len(p), np.inf)
    out = np.zeros((len(p), 3))
    for i, j in ((0, 1), (1, 2), (2, 0)):
        e = corners[j] - corners[i]
        ee = row_dot(e, e)
        t = np.clip(row_dot(p - corners[i], e) / np.where(ee > 0, ee, 1.0), 0.0, 1.0) * (ee > 0)
        q = corners[i] + t[:, None] * e
        d2 = row_dot(p - q, p - q)
        better = d2 < best
        best = np.where(better, d2, best)
        w = np.zeros((len(p), 3))
        w[:, i], w[:, j] = 1.0 - t, t
        out = np.where(better[:, None], w, out)
    return out


def _block_bounds(lengths: np.ndarray, budget: int) -> list[tuple[int, int]]:
    """Split consecutive points into blocks of at most ``budget`` candidates (>= 1 point each)."""
    cum = np.cumsum(lengths)
    out, lo = [], 0
    while lo < len(lengths):
        base = int(cum[lo - 1]) if lo else 0
        hi = max(int(np.searchsorted(cum, base + budget, side="right")), lo + 1)
        out.append((lo, hi))
        lo = hi
    return out


def closest_on_triangles(points: np.ndarray, corners: np.ndarray, degenerate: np.ndarray,
                         node_points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For every point, the closest triangle and the barycentric weights of the closest point.

    Candidates: the distance ``d`` to the nearest node (a triangle corner) bounds the distance
    to the surface, so the closest triangle has its centroid within ``d + R`` of the point, R
    its circumradius about the centroid (k-d trees, then an exact per-pair filter). Points are
    handled in blocks of at most :data:`PAIR_BLOCK` candidate pairs, so memory stays bounded
    even for points far from the surface (many candidates each). Among equally close triangles
    the lowest index wins.

    Args:
        points: (V, 3) query points.
        corners: (T, 3, 3) triangle corner positions.
        degenerate: (T,) bool, triangles handled as three segments.
        node_points: (K, 3) the corner positions as a point set (every corner among them).

    Returns:
        (V,) int64 triangle index and (V, 3) weights (>= 0, sum 1).
    """
    nearest, _ = cKDTree(node_points).query(points, workers=-1)
    centroid = corners.mean(axis=1)
    radius = np.linalg.norm(corners - centroid[:, None, :], axis=2).max(axis=1)
    slack = 1e-9 * (float(radius.max()) + float(np.abs(corners).max()))
    tree = cKDTree(centroid)
    reach = nearest + radius.max() + slack
    lengths = tree.query_ball_point(points, reach, workers=-1, return_length=True)
    tri_out = np.empty(len(points), dtype=np.int64)
    w_out = np.empty((len(points), 3))
    for lo, hi in _block_bounds(lengths, PAIR_BLOCK):
        lists = tree.query_ball_point(points[lo:hi], reach[lo:hi], workers=-1, return_sorted=False)
        counts = np.asarray(lengths[lo:hi], dtype=np.int64)
        tri = np.fromiter(itertools.chain.from_iterable(lists), dtype=np.int64, count=int(counts.sum()))
        pt = np.repeat(np.arange(lo, hi), counts)
        gap = np.linalg.norm(points[pt] - centroid[tri], axis=1)
        keep = gap <= nearest[pt] + radius[tri] + slack
        tri_out[lo:hi], w_out[lo:hi] = _closest_among(points, corners, degenerate, tri[keep], pt[keep] - lo,
                                                      lo, hi - lo)
    return tri_out, w_out


def _closest_among(points: np.ndarray, corners: np.ndarray, degenerate: np.ndarray, tri: np.ndarray,
                   pt: np.ndarray, offset: int, count: int) -> tuple[np.ndarray, np.ndarray]:
    """Closest of the candidate pairs (tri, pt) for points ``offset .. offset + count``; pairs are
    grouped by ``pt`` (0-based in the block), in order."""
    p, c = points[pt + offset], corners[tri]
    ap, ab, ac = p - c[:, 0], c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]
    v, w = _triangle_weights(ap, ab, ac, row_dot(ab, ab), row_dot(ab, ac), row_dot(ac, ac))
    weights = np.stack([1.0 - v - w, v, w], axis=1)
    deg = degenerate[tri]
    if deg.any():
        weights[deg] = _segment_weights(p[deg], c[deg, 0], c[deg, 1], c[deg, 2])
        v, w = weights[:, 1], weights[:, 2]
    gap = ap - v[:, None] * ab - w[:, None] * ac           # p - q, q the closest point
    d2 = row_dot(gap, gap)
    counts = np.bincount(pt, minlength=count)
    if (counts == 0).any():  # the bound above makes this impossible; keep the failure loud
        raise RuntimeError("closest_on_triangles: a point has no candidate triangle")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    best = np.minimum.reduceat(d2, starts)
    tie = d2 <= best[pt]
    best_tri = np.minimum.reduceat(np.where(tie, tri, len(corners)), starts)
    chosen = np.flatnonzero(tie & (tri == best_tri[pt]))
    return tri[chosen], weights[chosen]


def clean_weights(w: np.ndarray) -> np.ndarray:
    """Mosegaard & Sørensen 2005, Eq. 4 weights: tiny negatives clipped, renormalised to sum 1."""
    w = np.clip(w, 0.0, None)
    return w / w.sum(axis=1, keepdims=True)
