"""The fill's surface samples measured against the mesh: how much of each sample box next to the
surface the solid fills, exactly along one axis.

The fill (:mod:`deformgl.grid.fill`) keeps or drops each sample box whole, by the inside test of
its centre: within half a sample of every surface, so a feature a few samples thick carries its
volume to within a sample's width (the finned bar's 2 mm fin: -11 % to +8 % between 12 and 48
nodes along, issue 44). Here the boxes on the surface (inside ones with an outside face
neighbour, and outside ones with an inside face neighbour) are measured along lines: for each
axis, a 3 x 3 bundle of lines through the box along it (at -1/3, 0 and 1/3 of a sample across),
where the mesh's triangles cross each line. The solid is where the winding number of the
crossings so far is not zero, so the result is the same for either orientation of the normals,
and overlapping shells count once. So the solid's length inside the box along each line, and its
centroid there, are exact, and the box's share is their mean. Each box takes, among the axes
whose lines the surface crosses inside it, the one whose lines' lengths spread least (the axis
most nearly along the surface's normal): exact for a surface normal to an axis, and within the
midpoint rule of the bundle across the two others.

A box is measured only where the crossings agree with the fill's inside test at its centre (a
leaky mesh's crossings do not count; the vote stands there).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

__all__ = ["SurfaceSamples", "surface_samples"]

#: Lines are moved off the sample centres by this much (sample units), so that none passes
#: exactly through a triangle's edge or vertex (a crossing counted twice or not at all).
_NUDGE = (1.2345678e-7, 2.7182818e-7, 3.1415926e-7)


@dataclass(frozen=True)
class SurfaceSamples:
    """Measured sample boxes of a fill.

    Attributes:
        index: (K, 3) the boxes' sample indices (into the fill's ``inside``).
        fraction: (K,) the share of each box the solid fills (a box on the samples' outer face:
            with the material beyond it, up to 1 + ``reach``).
        axis: (K,) the axis along which it was measured.
        centre: (K,) the centroid of that share along ``axis``, in sample units from the box's
            centre.
    """

    index: np.ndarray
    fraction: np.ndarray
    axis: np.ndarray
    centre: np.ndarray


def _crossings(triangles: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The lines along ``axis`` through the integer points of the other two axes: for every
    crossing of a triangle, the line's two integer coordinates (C, 2), the depth along ``axis``
    (C,) and +1 entering / -1 leaving (outward normals)."""
    b, c = (axis + 1) % 3, (axis + 2) % 3
    p = triangles[:, :, [b, c]] - np.array([_NUDGE[b], _NUDGE[c]])
    d = triangles[:, :, axis]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    area = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]  # twice the projected signed area
    keep = np.abs(area) > 1e-12
    p, d, e1, e2, area = p[keep], d[keep], e1[keep], e2[keep], area[keep]
    lo = np.ceil(p.min(axis=1)).astype(np.int64)
    hi = np.floor(p.max(axis=1)).astype(np.int64)
    counts = np.maximum(hi - lo + 1, 0)
    per = counts[:, 0] * counts[:, 1]
    tri = np.repeat(np.arange(len(p)), per)
    local = np.arange(len(tri)) - np.repeat(np.cumsum(per) - per, per)
    q = lo[tri] + np.stack([local // np.maximum(counts[tri, 1], 1), local % np.maximum(counts[tri, 1], 1)], axis=1)
    r = q - p[tri, 0]
    # barycentric coordinates of the line in the projected triangle
    u = (r[:, 0] * e2[tri, 1] - r[:, 1] * e2[tri, 0]) / area[tri]
    v = (e1[tri, 0] * r[:, 1] - e1[tri, 1] * r[:, 0]) / area[tri]
    hit = (u >= 0) & (v >= 0) & (u + v <= 1)
    tri, q, u, v = tri[hit], q[hit], u[hit], v[hit]
    depth = d[tri, 0] + u * (d[tri, 1] - d[tri, 0]) + v * (d[tri, 2] - d[tri, 0])
    # the normal's component along the axis has the sign of the projected area ((b, c, axis) is
    # right-handed): positive leaves the solid along +axis
    return q, depth, np.where(area[tri] > 0, -1.0, 1.0)


#: lines per box along each of the two other axes (SUB^2 lines a box, at offsets -1/3, 0, 1/3 of a
#: sample: the midpoint rule across the line, exact along it)
SUB = 3


def _indicator_crossings(triangles: np.ndarray, axis: int, shape: tuple[int, ...], margin: float
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    """The sub-lines along ``axis`` (:data:`SUB` per sample along each other axis) and where the
    solid begins and ends on them: the sorted keys (line * span + depth - base), the depths (sample
    units), +1 where the solid begins / -1 where it ends, and (span, base). The solid is where the
    winding number of the crossings so far is not zero: the same for either orientation of the
    mesh's normals, and overlapping shells count once. ``margin``: how far (samples) beyond the
    array's ends a query along a line may reach."""
    b, c = (axis + 1) % 3, (axis + 2) % 3
    scaled = np.array(triangles, np.float64)
    scaled[:, :, [b, c]] = scaled[:, :, [b, c]] * SUB + 1.0  # sub-line (q b, q c) at sample (q - 1) / SUB
    q, depth, sign = _crossings(scaled, axis)
    width = SUB * np.array([shape[b], shape[c]]) + 2
    ours = np.all((q >= 0) & (q < width), axis=1)
    q, depth, sign = q[ours], depth[ours], sign[ours]
    base = float(min(depth.min(initial=0.0), 0.0)) - margin - 2.0
    span = float(max(depth.max(initial=0.0), shape[axis]) + margin - base + 2.0)  # each line's keys and queries
    line = q[:, 0] * int(width[1]) + q[:, 1]
    order = np.lexsort((depth, line))
    line, depth, sign = line[order], depth[order], sign[order]
    starts = np.searchsorted(line, line)  # each crossing's line's first crossing
    running = np.cumsum(sign)
    winding = running - (running[starts] - sign[starts])
    inside = winding != 0
    before = np.concatenate([[False], inside[:-1]])
    before[starts == np.arange(len(starts))] = False
    change = inside.astype(np.int64) - before.astype(np.int64)
    keep = change != 0
    return line[keep] * span + (depth[keep] - base), depth[keep], change[keep].astype(np.float64), span, base


def _along(triangles: np.ndarray, axis: int, index: np.ndarray, shape: tuple[int, ...], low: np.ndarray,
           high: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For sample boxes ``index`` (K, 3), each from ``low`` to ``high`` (K,) along ``axis``
    (sample units from its centre): the solid's share of it (the mean length inside along its
    :data:`SUB`^2 lines, sample units), its centroid along ``axis`` from the box's centre, whether
    the solid holds the box's centre on its central line (K, 2: just below and just above it, for
    a surface through the centre), and the spread (standard deviation) of the lines' lengths
    where the surface crosses a line in the box (inf where it crosses none): least along the
    surface's normal."""
    b, c = (axis + 1) % 3, (axis + 2) % 3
    margin = float(max(-np.min(low, initial=0.0), np.max(high, initial=0.0))) + 1.0
    key, depth, change, span, base = _indicator_crossings(triangles, axis, shape, margin)
    width = SUB * shape[c] + 2
    level = np.concatenate([[0.0], np.cumsum(change)])  # (integers: exact)
    t = index[:, axis].astype(np.float64)
    lo, hi = t + low, t + high
    lengths = np.zeros((len(index), SUB * SUB))
    moment = np.zeros(len(index))
    cut = np.zeros(len(index), bool)
    centre = np.zeros((len(index), 2))
    offsets = range(-(SUB // 2), SUB // 2 + 1)
    for n, (jb, jc) in enumerate((jb, jc) for jb in offsets for jc in offsets):
        own = ((SUB * index[:, b] + 1 + jb) * width + SUB * index[:, c] + 1 + jc) * span
        first = np.searchsorted(key, own)
        at_lo = np.searchsorted(key, own + (lo - base))
        at_hi = np.searchsorted(key, own + (hi - base))
        state = level[at_lo] - level[first]  # the solid at the box's low end: 0 or 1
        length = state * (hi - lo)
        moment += state * ((hi - t) ** 2 - (lo - t) ** 2) / 2.0
        cut |= at_hi > at_lo
        for k in range(int((at_hi - at_lo).max(initial=0))):  # the few crossings inside each box
            i = at_lo + k
            j = np.minimum(i, len(depth) - 1)
            d = np.where(i < at_hi, change[j], 0.0)
            length += d * (hi - depth[j])
            moment += d * ((hi - t) ** 2 - (depth[j] - t) ** 2) / 2.0
        lengths[:, n] = length
        if jb == 0 and jc == 0:
            for side, shift in enumerate((-1e-6, 1e-6)):
                centre[:, side] = level[np.searchsorted(key, own + (t + shift - base))] - level[first]
    mean = lengths.mean(axis=1)
    middle = np.where(mean > 1e-12, moment / (SUB * SUB) / np.maximum(mean, 1e-12), 0.0)
    return mean, middle, centre, np.where(cut, lengths.std(axis=1), np.inf)


def surface_samples(triangles: np.ndarray, inside: np.ndarray, reach: float = 0.0) -> SurfaceSamples:
    """The fill's surface boxes measured against the mesh (module docstring).

    Args:
        triangles: (F, 3, 3) the mesh's triangles in sample index space (sample ``p`` at the
            integer point ``p``), outward normals.
        inside: the fill's inside test of the samples.
        reach: how far (samples) the material may lie beyond the samples' outermost faces and still
            count (the spline body: half a cell, to the knot plane beyond the outermost node):
            the boxes on the array's faces are measured out to it along the axis that leaves it.
    """
    inside = np.asarray(inside, bool)
    edge = np.zeros(inside.shape, bool)
    for a in range(3):
        edge[(slice(None),) * a + (0,)] = edge[(slice(None),) * a + (-1,)] = True
    near = ((inside & ~ndimage.binary_erosion(inside, border_value=1)) | (ndimage.binary_dilation(inside) & ~inside)
            | (inside & edge))
    index = np.argwhere(near)
    midpoint = inside[tuple(index.T)].astype(np.float64)
    best = np.full(len(index), np.inf)
    fraction, axis, centre = midpoint.copy(), np.zeros(len(index), np.int64), np.zeros(len(index))
    tri = np.asarray(triangles, np.float64)
    for a in range(3):
        low = np.where(index[:, a] == 0, -0.5 - reach, -0.5)
        high = np.where(index[:, a] == inside.shape[a] - 1, 0.5 + reach, 0.5)
        length, middle, centre_state, spread = _along(tri, a, index, inside.shape, low, high)
        agree = np.any(np.abs(centre_state - midpoint[:, None]) < 0.5, axis=1)
        f = np.clip(length, 0.0, high - low)
        better = agree & (spread < best)
        best[better] = spread[better]
        fraction[better], axis[better] = f[better], a
        centre[better] = np.clip(middle[better], low[better] + f[better] / 2.0, high[better] - f[better] / 2.0)
    return SurfaceSamples(index, fraction, axis, centre)
