"""A spline body of any shape: knot spans cut by the material, sampled and moment-fitted.

* :func:`inside_body`: the material where an ``inside`` test holds, each span cut into sub-boxes
  whose centres are tested (a grid of Gauss points per sub-box inside);
* :func:`sample_body`: the material of a mesh's fill (:class:`deformgl.grid.fill.CellFill`: the
  inside test of ``s`` sample points along each cell edge, what the lattice's cells integrate),
  a full span by one exact grid of Gauss points, a cut span by one moment-fitted grid;
* :func:`fitted_body`: a body whose cut spans hold a grid per sub-box brought to one fitted grid
  a span.

Moment fitting (Joulaian et al. 2016, section 3): a cut span's material is integrated by the 3 x 3
x 3 Gauss points of its bounding box, their weights solved so that the grid integrates the 27
tensor Legendre polynomials of degree <= 2 per axis over the material as the fine quadrature does:
the mass (``rho int N_a``, degree 2 per axis), the volume, the centroid and the second moments are
kept; the stiffness (degree 4 per axis) is approximated in cut spans. Where that exact fit has a
negative weight (a span's stiffness would be indefinite: modes that grow at any dt), the weights
are the non-negative least-squares fit instead, the volume kept exactly and the centroid and
higher moments as nearly as non-negative weights allow.
"""

from __future__ import annotations

import numpy as np

from deformgl.grid.line_fill import SurfaceSamples
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.terms.spline.basis import SPAN_OFFSETS, gauss_box
from deformgl.sim.terms.spline.body import KNOT_TOLERANCE, SplineBody

__all__ = ["fit_boxes", "fitted_body", "inside_body", "sample_body", "span_quadrature", "span_samples"]

_GAUSS = np.polynomial.legendre.leggauss(3)[0]
#: [point, degree]^-1 of the Legendre polynomials 1, t, (3 t^2 - 1)/2 at the 3 Gauss points
_INVERSE = np.linalg.inv(np.stack([np.ones(3), _GAUSS, 1.5 * _GAUSS * _GAUSS - 0.5]))
_UNIT = np.stack(np.meshgrid(_GAUSS, _GAUSS, _GAUSS, indexing="ij"), axis=-1).reshape(27, 3)


def _control_grid(origin: np.ndarray, spacing: float, centres: np.ndarray) -> tuple[NodeGrid, np.ndarray]:
    """The control grid of spans centred on the grid indices ``centres`` (S, 3) of nodes at
    ``origin + i h`` (their 27 nodes each) and the centres in its indices."""
    low = centres.min(axis=0) - 1
    shape = tuple(int(n) for n in centres.max(axis=0) - low + 2)
    occupied = np.zeros(shape, bool)
    for offset in SPAN_OFFSETS:
        occupied[tuple((centres - low + offset).T)] = True
    return NodeGrid(origin + low * spacing, spacing, occupied), centres - low


def fit_boxes(local: np.ndarray, s: np.ndarray, w: np.ndarray, lo: np.ndarray, hi: np.ndarray,
         widths: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One fitted grid per span: points (C, 27, 3) at the Gauss points of [lo, hi] (C, 3) and
    weights (C, 27) reproducing the 27 Legendre moments of the points ``s`` (P, 3) with weights
    ``w`` (P,), point p in span ``local[p]``; ``widths`` (P, 3): each point the centre of a box of
    those sides (span units) whose moments are integrated exactly (``w`` its volume)."""
    mid, half = (hi + lo) / 2.0, np.maximum((hi - lo) / 2.0, 1e-12)
    t = (s - mid[local]) / half[local]  # in [-1, 1]
    # per axis the mean of 1, t, (3 t^2 - 1)/2 over the point's extent (a box: t^2 gains its
    # variance, (width / 2 half)^2 / 3)
    spread = 0.0 if widths is None else (widths / (2.0 * half[local])) ** 2 / 3.0
    legendre = np.stack([np.ones_like(t), t, 1.5 * (t * t + spread) - 0.5], axis=-1)  # (P, 3 axes, 3 degrees)
    moments = np.zeros((len(lo), 3, 3, 3))
    np.add.at(moments, local, w[:, None, None, None] * legendre[:, 0, :, None, None]
              * legendre[:, 1, None, :, None] * legendre[:, 2, None, None, :])
    weights = np.einsum("la,mb,nc,sabc->slmn", _INVERSE, _INVERSE, _INVERSE, moments).reshape(len(lo), 27)
    negative = np.nonzero((weights < 0).any(axis=1))[0]
    if len(negative):
        weights[negative] = _nonnegative(moments[negative].reshape(len(negative), 27))
    return mid[:, None, :] + half[:, None, :] * _UNIT[None], weights


#: The Legendre moments' matrix on the Gauss grid, [moment (a, b, c), point (l, m, n)]
_MOMENTS = np.einsum("al,bm,cn->abclmn", *(np.stack([np.ones(3), _GAUSS, 1.5 * _GAUSS * _GAUSS - 0.5]),) * 3).reshape(27, 27)
#: The share of h^3 the inside test must give a knot span for its measured surface boxes to count
#: (:func:`span_samples`)
MEASURED_SHARE = 0.05
#: Each moment's row weight in the non-negative fit: the volume first, then the first moments
#: (the centroid), then the rest (the degree of a moment: the sum of its three degrees)
_ROW_WEIGHT = np.array([100.0 if d == 0 else 10.0 if d == 1 else 1.0
                        for d in np.indices((3, 3, 3)).reshape(3, 27).sum(axis=0)])


def _nonnegative(moments: np.ndarray) -> np.ndarray:
    """(C, 27) weights >= 0 of the Gauss grid nearest to the moments (C, 27) in the row-weighted
    least-squares sense (scipy's NNLS; Lawson & Hanson 1974), scaled to keep the volume exactly:
    a rule with a negative weight makes the span's stiffness indefinite (modes that grow at any
    dt), so where the exact fit has one the rule trades higher moments for positivity."""
    from scipy.optimize import nnls

    a = _ROW_WEIGHT[:, None] * _MOMENTS
    out = np.empty_like(moments)
    for k, m in enumerate(moments):
        w = nnls(a, _ROW_WEIGHT * m)[0]
        total = float(w @ _MOMENTS[0])
        out[k] = w * (m[0] / total if total > 0 else 0.0)
    return out


def fitted_body(body: SplineBody) -> SplineBody:
    """``body`` with each span that holds other than one grid of 27 Gauss points integrated by one
    moment-fitted grid on the bounding box of its points (the module docstring); ``body`` itself
    where every span holds one grid."""
    starts = np.searchsorted(body.point_span, np.arange(len(body.span_nodes) + 1))
    per = np.diff(starts)
    cut = per != 27
    if not cut.any():
        return body
    spans = np.nonzero(cut)[0]
    selector = np.repeat(cut, per)
    s, w = body.point_s[selector], body.point_weight[selector]
    local = np.searchsorted(spans, body.point_span[selector])  # each point's cut span, 0..C-1
    lo = np.full((len(spans), 3), np.inf)
    hi = np.full((len(spans), 3), -np.inf)
    np.minimum.at(lo, local, s)
    np.maximum.at(hi, local, s)
    points, weights = fit_boxes(local, s, w, lo, hi)
    keep = ~selector
    point_s = np.concatenate([body.point_s[keep], points.reshape(-1, 3)])
    point_weight = np.concatenate([body.point_weight[keep], weights.ravel()])
    point_span = np.concatenate([body.point_span[keep], np.repeat(spans, 27)])
    order = np.argsort(point_span, kind="stable")
    return SplineBody(body.grid, body.span_nodes, point_span[order], point_s[order], point_weight[order],
                      body.youngs_modulus, body.poissons_ratio, body.density, body.dilatation)


def inside_body(inside, lo, hi, spacing: float, *, youngs_modulus: float, poissons_ratio: float, density: float,
                origin=None, subdivisions: int = 4, dilatation: str = "p1") -> SplineBody:
    """A body of the material where ``inside(points (P, 3)) -> (P,) bool`` holds, within the box
    [lo, hi] (m): each knot span is cut into ``subdivisions``^3 sub-boxes, those whose centre
    is inside kept (a span all inside is one box). The sampled geometry, not the exact one: its
    volume converges as the sub-boxes shrink.

    Raises:
        ValueError: no material inside the box, h <= 0, subdivisions < 1.
    """
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    if not spacing > 0 or subdivisions < 1:
        raise ValueError(f"spline body: spacing must be > 0 m and subdivisions >= 1, got {spacing}, {subdivisions}")
    origin = lo if origin is None else np.asarray(origin, np.float64)
    first = np.floor((lo - origin) / spacing - 0.5 + KNOT_TOLERANCE).astype(np.int64) + 1
    last = np.ceil((hi - origin) / spacing + 0.5 - KNOT_TOLERANCE).astype(np.int64) - 1
    centres = np.argwhere(np.ones(tuple(int(n) for n in last - first + 1), bool)) + first
    k = subdivisions
    sub = (np.argwhere(np.ones((k, k, k), bool)) + 0.5) / k - 0.5  # sub-box centres, span units
    x_c = origin + centres * spacing
    samples = x_c[:, None, :] + sub[None] * spacing
    flags = np.asarray(inside(samples.reshape(-1, 3)), bool).reshape(len(centres), k ** 3)
    flags &= np.all((samples >= lo) & (samples <= hi), axis=2)
    keep = flags.any(axis=1)
    if not keep.any():
        raise ValueError("spline body: no material inside the box")
    centres, flags = centres[keep], flags[keep]
    full = flags.all(axis=1)
    span_of = np.concatenate([np.nonzero(full)[0], np.nonzero(~full)[0][np.nonzero(flags[~full])[0]]])
    cut_sub = sub[np.nonzero(flags[~full])[1]]
    box_lo = np.concatenate([np.full((int(full.sum()), 3), -0.5), cut_sub - 0.5 / k])
    box_hi = np.concatenate([np.full((int(full.sum()), 3), 0.5), cut_sub + 0.5 / k])
    grid, local = _control_grid(origin, spacing, centres)
    return SplineBody.from_span_boxes(grid, local, box_lo, box_hi, span_of, youngs_modulus=youngs_modulus,
                                      poissons_ratio=poissons_ratio, density=density, dilatation=dilatation)


def span_samples(samples: int, inside: np.ndarray, surface: SurfaceSamples | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The fill's material as boxes in knot spans: each box's span (the grid index of its centre
    node, (M, 3)), its centre in span coordinates (M, 3), its sides in span units (M, 3) and the
    inside sample it is of (M,), a row of ``np.argwhere(inside)`` (-1: a measured box whose
    centre is outside). Sample ``p`` is the box of side ``1 / samples`` centred on
    ``(p + 1/2) / samples`` node units from the fill's origin; with ``surface`` the boxes it
    measured hold their measured share instead, narrowed along its axis about its centroid
    (:mod:`deformgl.grid.line_fill`), in the knot spans the inside test gives at least
    :data:`MEASURED_SHARE` of h^3 (a sliver span keeps the inside test; a measured box alone in a
    span is left out). A box across a knot plane (odd ``samples``) is split there."""
    s = int(samples)
    if surface is not None and s < 2:  # (a box measured out to half a cell beyond would cross two knot planes)
        raise ValueError(f"spline body: measured surface boxes need at least 2 samples per cell edge, got {s}")
    where = np.argwhere(inside)
    t = (where + 0.5) / s  # node units from origin
    widths = np.full(t.shape, 1.0 / s)
    index = np.arange(len(where))
    if surface is not None and len(surface.index):
        row = np.full(inside.shape, -1, np.int64)
        row[tuple(where.T)] = index
        rows = row[tuple(surface.index.T)]
        # the spans the inside test gives at least MEASURED_SHARE of h^3 take the measured boxes;
        # a sliver span keeps the inside test (a sliver measured thinner than its samples can leave
        # its control points next to no stiffness: the dragon at 24 along, its topmost vertex
        # read through one sagged 56 times its FEM's)
        keys = _span_keys(where, s)
        spans, counts = np.unique(keys, return_counts=True)
        at = np.searchsorted(spans, _span_keys(surface.index, s))
        found = spans[np.minimum(at, len(spans) - 1)] == _span_keys(surface.index, s)
        share = np.where(found, counts[np.minimum(at, len(spans) - 1)], 0) / float(s) ** 3
        use = share >= MEASURED_SHARE
        measured = (rows >= 0) & use
        rows = np.where(measured, rows, -1)
        t[rows[measured], surface.axis[measured]] += surface.centre[measured] / s
        widths[rows[measured], surface.axis[measured]] = surface.fraction[measured] / s
        extra = (row[tuple(surface.index.T)] < 0) & use & (surface.fraction > 0)
        t_extra = (surface.index[extra] + 0.5) / s
        w_extra = np.full(t_extra.shape, 1.0 / s)
        added = np.arange(len(t_extra))
        t_extra[added, surface.axis[extra]] += surface.centre[extra] / s
        w_extra[added, surface.axis[extra]] = surface.fraction[extra] / s
        keep = widths.min(axis=1) > 0
        t = np.concatenate([t[keep], t_extra])
        widths = np.concatenate([widths[keep], w_extra])
        index = np.concatenate([index[keep], np.full(len(t_extra), -1, np.int64)])
    for d in range(3):
        lo, hi = t[:, d] - widths[:, d] / 2.0, t[:, d] + widths[:, d] / 2.0
        knot = np.floor(hi - 0.5) + 0.5  # the highest knot plane below the box's top
        on = (lo < knot - 1e-9) & (knot < hi - 1e-9)
        if on.any():
            lower_t, lower_w = t[on].copy(), widths[on].copy()
            lower_t[:, d] = (lo[on] + knot[on]) / 2.0
            lower_w[:, d] = knot[on] - lo[on]
            t[on, d] = (knot[on] + hi[on]) / 2.0
            widths[on, d] = hi[on] - knot[on]
            t = np.concatenate([t, lower_t])
            widths = np.concatenate([widths, lower_w])
            index = np.concatenate([index, index[on]])
    centre = np.floor(t + 0.5).astype(np.int64)  # the span holding the box
    extra = index < 0
    if extra.any():  # a measured box adds to the spans the inside test gave material, never one of its own
        keys = centre[:, 0] * (1 << 42) + centre[:, 1] * (1 << 21) + centre[:, 2]  # (|index| < 2^20)
        keep = ~extra | np.isin(keys, keys[~extra])
        centre, t, widths, index = centre[keep], t[keep], widths[keep], index[keep]
    return centre, t - centre, widths, index


def _span_keys(samples_ijk: np.ndarray, s: int) -> np.ndarray:
    """(M,) an integer key of the knot span holding each sample's centre."""
    c = np.floor((samples_ijk + 0.5) / s + 0.5).astype(np.int64) + (1 << 19)
    return c[:, 0] * (1 << 42) + c[:, 1] * (1 << 21) + c[:, 2]


def span_quadrature(span_of: np.ndarray, count: int, local_s: np.ndarray, widths: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The Gauss points of ``count`` spans holding the boxes centred on ``local_s`` (M, 3) with
    sides ``widths`` (M, 3), span units, box m in span ``span_of[m]``: a span its boxes fill (volume
    1) one exact 3 x 3 x 3 grid, a cut one a grid moment-fitted to its boxes' exact moments on their
    extent (:func:`fit_boxes`). Returns each point's span, sorted (Q,), its span coordinates
    (Q, 3) and weight (Q,), span units (times h^3 for m^3)."""
    volume = np.prod(widths, axis=1)
    full = np.abs(np.bincount(span_of, volume, minlength=count) - 1.0) < 1e-9
    cut = np.nonzero(~full)[0]
    points_full, weights_full = gauss_box(np.full((int(full.sum()), 3), -0.5), np.full((int(full.sum()), 3), 0.5))
    is_cut = ~full[span_of]
    local = np.searchsorted(cut, span_of[is_cut])
    cs, cw = local_s[is_cut], widths[is_cut]
    lo = np.full((len(cut), 3), np.inf)
    hi = np.full((len(cut), 3), -np.inf)
    np.minimum.at(lo, local, cs - cw / 2.0)
    np.maximum.at(hi, local, cs + cw / 2.0)
    points_cut, weights_cut = fit_boxes(local, cs, volume[is_cut], np.maximum(lo, -0.5), np.minimum(hi, 0.5), cw)
    point_span = np.repeat(np.concatenate([np.nonzero(full)[0], cut]), 27)
    point_s = np.concatenate([points_full.reshape(-1, 3), points_cut.reshape(-1, 3)])
    point_w = np.concatenate([weights_full.ravel(), weights_cut.ravel()])
    order = np.argsort(point_span, kind="stable")
    return point_span[order], point_s[order], point_w[order]


def sample_body(origin, spacing: float, samples: int, inside: np.ndarray, *, youngs_modulus: float,
                poissons_ratio: float, density: float, dilatation: str = "p1",
                surface: SurfaceSamples | None = None, boxes: tuple | None = None) -> SplineBody:
    """The body of a fill's samples: ``inside`` (bool, ``samples`` per cell edge along each axis)
    the inside test of the sample points ``origin + h (i + 1/2) / samples``, each the centre of a
    sample box of side ``h / samples`` (the fill's volume). A knot span all of whose sample centres
    are inside is one exact grid of Gauss points; a cut one is one grid moment-fitted to its inside
    samples (each its box's volume at its centre) on their bounding box within the span.
    ``boxes``: :func:`span_samples` of these samples and ``surface`` where the caller has them.

    Raises:
        ValueError: no sample inside, h <= 0 or samples < 1.
    """
    inside = np.asarray(inside, bool)
    s = int(samples)
    if not spacing > 0 or s < 1:
        raise ValueError(f"spline body: spacing must be > 0 m and samples >= 1, got {spacing}, {samples}")
    origin = np.asarray(origin, np.float64)
    if not inside.any():
        raise ValueError("spline body: no sample inside the mesh")
    centre, local_s, widths, _ = span_samples(s, inside, surface) if boxes is None else boxes
    centres, span_of = np.unique(centre, axis=0, return_inverse=True)
    point_span, point_s, point_w = span_quadrature(span_of.ravel(), len(centres), local_s, widths)
    grid, local_centres = _control_grid(origin, spacing, centres)
    ijk = local_centres[:, None, :] + SPAN_OFFSETS[None]
    span_nodes = grid.index[ijk[..., 0], ijk[..., 1], ijk[..., 2]]
    point_w = point_w * spacing ** 3
    return SplineBody(grid, span_nodes, point_span, point_s, point_w, float(youngs_modulus),
                      float(poissons_ratio), float(density), dilatation)
