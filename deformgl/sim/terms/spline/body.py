"""A spline body's immutable model data: its control grid, its knot spans with the material each
holds as Gauss points, its material constants, and the float64 sums every form of the term
builds on (mass, linear stiffness, the field at any point).

The body (issue 44): displacement ``u(x) = sum_a N_a(x) u_a`` with the quadratic B-spline basis of
:mod:`~deformgl.sim.terms.spline.basis` on the node grid, the node positions ``x_a = X_a + u_a``
its control points. Every integral is a sum over the Gauss points of the material in each knot
span (the finite cell method, Parvizian, Düster & Rank 2007): a span's material is a union of
axis-aligned boxes in its span coordinates, each integrated by 3 x 3 x 3 Gauss points, exact for
the basis's polynomials. A box body (:meth:`SplineBody.from_box`) has one box per span, so its
integrals are exact at any grid offset.

Linear elasticity with the span's mean dilatation (B-bar, Hughes 1980, eq. 27: the volumetric
strain replaced by its mean over the span's material, so that ν up to 0.499 does not lock),
isotropic, Lamé μ and bulk modulus κ = λ + 2μ/3:

    E(u) = sum_q w_q μ ε_dev(x_q) : ε_dev(x_q) + sum_spans κ V θ̄^2 / 2,   θ̄ = (1/V) sum_q w_q tr ε(x_q).

Arrays here are float64 and node-ordered like the grid's (``np.argwhere`` of its occupancy).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from deformgl.grid.nodes import NodeGrid
from deformgl.sim.terms.spline.basis import SPAN_OFFSETS, gauss_box, span_basis

__all__ = ["DILATATIONS", "SplineBody", "lame"]

#: Spans per chunk of the vectorised sums (bounds the temporaries: 27 x 27 x 3 floats a point).
CHUNK = 1024
#: A face within this many spans of a knot plane lies on it (the span beyond it holds no material).
KNOT_TOLERANCE = 1e-9
#: Up to this many kinds of span the forces are summed with each kind's matrix, beyond it at the
#: Gauss points (:meth:`SplineBody.span_forces`).
MAX_PATTERNS = 64
#: The volumetric strain's treatment (:attr:`SplineBody.dilatation`).
DILATATIONS = ("p1", "p0", "full")


def lame(youngs_modulus: float, poissons_ratio: float) -> tuple[float, float]:
    """(μ, κ) in Pa: the shear and bulk moduli of an isotropic material of Young's modulus E (Pa)
    and Poisson's ratio ν (-1 < ν < 1/2)."""
    if not youngs_modulus > 0:
        raise ValueError(f"spline body: Young's modulus must be > 0 Pa, got {youngs_modulus}")
    if not -1.0 < poissons_ratio < 0.5:
        raise ValueError(f"spline body: Poisson's ratio must be in (-1, 0.5), got {poissons_ratio}")
    mu = youngs_modulus / (2.0 * (1.0 + poissons_ratio))
    kappa = youngs_modulus / (3.0 * (1.0 - 2.0 * poissons_ratio))
    return mu, kappa


@dataclass(frozen=True, eq=False)
class SplineBody:
    """The spline body on its control grid (see the module docstring).

    Attributes:
        grid: the control points, the grid's nodes (every node whose basis function's support
            meets the material).
        span_nodes: (S, 27) node numbers of each knot span's nodes (:data:`SPAN_OFFSETS` order; the
            centre node is column 13).
        point_span: (Q,) the span of each Gauss point.
        point_s: (Q, 3) its span coordinates, in [-1/2, 1/2].
        point_weight: (Q,) its weight, m^3 (a span's weights sum to its material's volume).
        youngs_modulus: E in Pa; poissons_ratio: ν; density: ρ in kg/m^3.
        dilatation: how the volumetric strain enters (:data:`DILATATIONS`): "p1" (default) its
            L2 projection per span onto linear functions, "p0" onto the span's mean (the mean
            dilatation), "full" the strain itself at every Gauss point (which locks as ν → 1/2).
    """

    grid: NodeGrid
    span_nodes: np.ndarray
    point_span: np.ndarray
    point_s: np.ndarray
    point_weight: np.ndarray
    youngs_modulus: float
    poissons_ratio: float
    density: float
    dilatation: str = "p1"

    def __post_init__(self) -> None:
        lame(self.youngs_modulus, self.poissons_ratio)
        if self.dilatation not in DILATATIONS:
            raise ValueError(f"spline body: dilatation must be one of {', '.join(DILATATIONS)}, got {self.dilatation!r}")
        if not self.density > 0:
            raise ValueError(f"spline body: density must be > 0 kg/m^3, got {self.density}")
        if self.span_nodes.ndim != 2 or self.span_nodes.shape[1] != 27 or np.any(self.span_nodes < 0):
            raise ValueError("spline body: every knot span needs its 27 nodes on the control grid")
        if np.any(np.diff(self.point_span) < 0):
            raise ValueError("spline body: the Gauss points must be sorted by span")
        for name in ("span_nodes", "point_span", "point_s", "point_weight"):
            getattr(self, name).setflags(write=False)

    # -- construction -----------------------------------------------------------------------

    @classmethod
    def from_box(cls, lo, hi, spacing: float, *, youngs_modulus: float, poissons_ratio: float,
                 density: float, origin=None, dilatation: str = "p1") -> "SplineBody":
        """A box of material [lo, hi] (m) on the node grid of ``spacing`` h (m) whose nodes lie at
        ``origin + i h`` (default: a node on ``lo``'s corner, as the lattice's workloads put
        them). The spans are the knot spans that hold material; the control grid the nodes of
        their supports (one layer of nodes around the material's spans).

        Raises:
            ValueError: an empty box, h <= 0, or material constants out of range.
        """
        lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        if not spacing > 0:
            raise ValueError(f"spline body: spacing must be > 0 m, got {spacing}")
        if lo.shape != (3,) or hi.shape != (3,) or np.any(hi <= lo):
            raise ValueError(f"spline body: an empty box {lo.tolist()}..{hi.tolist()}")
        origin = lo if origin is None else np.asarray(origin, np.float64)
        # span c holds material where c + 1/2 > t_lo and c - 1/2 < t_hi (t = (x - origin) / h), by
        # more than a rounding error: a face on a knot plane adds no empty layer of spans
        t_lo, t_hi = (lo - origin) / spacing, (hi - origin) / spacing
        first = np.floor(t_lo - 0.5 + KNOT_TOLERANCE).astype(np.int64) + 1
        last = np.ceil(t_hi + 0.5 - KNOT_TOLERANCE).astype(np.int64) - 1
        spans_shape = last - first + 1
        shape = tuple(int(n) for n in spans_shape + 2)
        grid = NodeGrid(origin + (first - 1) * spacing, spacing, np.ones(shape, bool))
        centres = np.argwhere(np.ones(tuple(int(n) for n in spans_shape), bool)) + 1  # grid indices
        x_c = grid.origin + centres * spacing
        box_lo = np.maximum(-0.5, (lo - x_c) / spacing)
        box_hi = np.minimum(0.5, (hi - x_c) / spacing)
        return cls.from_span_boxes(grid, centres, box_lo, box_hi, np.arange(len(centres)),
                                   youngs_modulus=youngs_modulus, poissons_ratio=poissons_ratio,
                                   density=density, dilatation=dilatation)

    @classmethod
    def from_span_boxes(cls, grid: NodeGrid, centres: np.ndarray, box_lo: np.ndarray, box_hi: np.ndarray,
                        box_span: np.ndarray, *, youngs_modulus: float, poissons_ratio: float,
                        density: float, dilatation: str = "p1") -> "SplineBody":
        """A body whose spans are centred on the grid indices ``centres`` (S, 3) and hold the
        material boxes [box_lo, box_hi] (B, 3) in span coordinates, box b in span ``box_span[b]``.

        Raises:
            ValueError: a span whose 27 nodes are not all on ``grid``.
        """
        centres = np.asarray(centres, np.int64)
        ijk = centres[:, None, :] + SPAN_OFFSETS[None]
        inside = np.all((ijk >= 0) & (ijk < np.array(grid.shape)), axis=2)
        nodes = np.full(ijk.shape[:2], -1, np.int64)
        nodes[inside] = grid.index[ijk[inside][:, 0], ijk[inside][:, 1], ijk[inside][:, 2]]
        order = np.argsort(np.asarray(box_span, np.int64), kind="stable")  # (the sums walk spans in order)
        points, weights = gauss_box(np.asarray(box_lo)[order], np.asarray(box_hi)[order])
        keep = weights > 0
        span = np.repeat(np.asarray(box_span, np.int64)[order], points.shape[1]).reshape(weights.shape)
        h3 = grid.spacing ** 3
        return cls(grid, nodes, span[keep], points[keep], weights[keep] * h3,
                   float(youngs_modulus), float(poissons_ratio), float(density), dilatation)

    # -- what the sums share ----------------------------------------------------------------

    @property
    def spacing(self) -> float:
        """h in m."""
        return float(self.grid.spacing)

    @property
    def count(self) -> int:
        """Control points (nodes)."""
        return int(self.grid.count)

    @property
    def rest_positions(self) -> np.ndarray:
        """(N, 3) the control points at rest: the nodes' rest positions, m."""
        return self.grid.rest_positions

    @cached_property
    def moduli(self) -> tuple[float, float]:
        """(μ, κ) in Pa."""
        return lame(self.youngs_modulus, self.poissons_ratio)

    @cached_property
    def span_volume(self) -> np.ndarray:
        """(S,) material volume of each span, m^3."""
        return np.bincount(self.point_span, self.point_weight, minlength=len(self.span_nodes))

    @cached_property
    def span_centroids(self) -> np.ndarray:
        """(S, 3) the centroid of each span's material in its span coordinates."""
        moments = np.stack([np.bincount(self.point_span, self.point_weight * self.point_s[:, d],
                                        minlength=len(self.span_nodes)) for d in range(3)], axis=1)
        return moments / np.maximum(self.span_volume, 1e-300)[:, None]

    @property
    def volume(self) -> float:
        """The body's volume, m^3."""
        return float(self.point_weight.sum())

    def chunks(self):
        """(span range, point selector) pairs of at most :data:`CHUNK` spans (points are sorted by span)."""
        starts = np.searchsorted(self.point_span, np.arange(0, len(self.span_nodes) + CHUNK, CHUNK))
        for k in range(len(starts) - 1):
            if starts[k] < starts[k + 1]:
                yield slice(k * CHUNK, min((k + 1) * CHUNK, len(self.span_nodes))), slice(starts[k], starts[k + 1])

    def point_gradients(self, points: slice) -> np.ndarray:
        """(P, 27, 3) basis gradients at the Gauss points ``points``, 1/m."""
        return span_basis(self.point_s[points], self.spacing)[1]

    @cached_property
    def _projection(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The volumetric strain's projection: per Gauss point its P functions (Q, P) (1, and for
        "p1" the span coordinates about the material's centroid), per span the inverse of their
        Gram matrix (S, P, P), m^-3, and ``sum_q w_q phi_k grad N_a`` (S, P, 27, 3), m^2."""
        s_count = len(self.span_nodes)
        w = self.point_weight
        if self.dilatation == "p1":
            phi = np.concatenate([np.ones((len(w), 1)), self.point_s - self.span_centroids[self.point_span]], axis=1)
        else:
            phi = np.ones((len(w), 1))
        p = phi.shape[1]
        gram = np.zeros((s_count, p, p))
        np.add.at(gram, self.point_span, w[:, None, None] * phi[:, :, None] * phi[:, None, :])
        inverse = np.linalg.pinv(gram, rcond=1e-10, hermitian=True)  # (a thin cut span: its mean only)
        moments = np.zeros((s_count, p, 27, 3))
        for spans, points in self.chunks():
            g = self.point_gradients(points) * w[points, None, None]
            np.add.at(moments, self.point_span[points], phi[points, :, None, None] * g[:, None])
        return phi, inverse, moments

    def dilatations(self, local: np.ndarray) -> np.ndarray:
        """(Q,) the projected volumetric strain at every Gauss point for local displacements of
        every span's nodes (S, 27, 3), m ("full": None, the strain itself is used)."""
        phi, inverse, moments = self._projection
        c = np.einsum("skl,slad,sad->sk", inverse, moments, local)
        return np.einsum("qk,qk->q", phi, c[self.point_span])

    @cached_property
    def lumped_mass(self) -> np.ndarray:
        """(N,) kg: ``m_a = rho int N_a dV`` (the row sums of the consistent mass; they sum to ρ V
        exactly, the basis being a partition of unity)."""
        values = span_basis(self.point_s, self.spacing)[0] * (self.density * self.point_weight)[:, None]
        return np.bincount(self.span_nodes[self.point_span].ravel(), values.ravel(), minlength=self.count)

    # -- the field ----------------------------------------------------------------------------

    def locate(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For world points (P, 3), m: their span's 27 node numbers (P, 27), basis values (P, 27)
        and gradients (P, 27, 3), 1/m.

        Raises:
            ValueError: a point whose span's nodes are not all on the control grid.
        """
        p = np.asarray(points, np.float64)
        t = (p - self.grid.origin) / self.spacing
        # the nearest node, kept where its span's 27 nodes fit the grid (a point on a knot plane
        # at the body's face belongs to the span inside: rint would round half to even)
        centre = np.clip(np.rint(t).astype(np.int64), 1, np.array(self.grid.shape) - 2)
        s = t - centre
        if np.any(np.abs(s) > 0.5 + KNOT_TOLERANCE):
            bad = int(np.argmax(np.any(np.abs(s) > 0.5 + KNOT_TOLERANCE, axis=1)))
            raise ValueError(f"spline body: point {bad} at {p[bad].tolist()} m is outside the control grid's spans")
        ijk = centre[:, None, :] + SPAN_OFFSETS[None]
        inside = np.all((ijk >= 0) & (ijk < np.array(self.grid.shape)), axis=2)
        nodes = np.full(ijk.shape[:2], -1, np.int64)
        nodes[inside] = self.grid.index[ijk[inside][:, 0], ijk[inside][:, 1], ijk[inside][:, 2]]
        if np.any(nodes < 0):
            bad = int(np.argmax(np.any(nodes < 0, axis=1)))
            raise ValueError(f"spline body: point {bad} at {p[bad].tolist()} m is outside the control grid's spans")
        values, gradients = span_basis(s, self.spacing)
        return nodes, values, gradients

    def face_points(self, axis: int, value: float, lo, hi) -> tuple[np.ndarray, np.ndarray]:
        """Gauss points (P, 3) and weights (P,), m^2, of the rectangle ``x[axis] = value``,
        ``lo <= x <= hi`` on the other two axes (m), cut at the knot planes so that each piece lies in
        one span (3 x 3 points a piece: the basis's products integrated exactly)."""
        lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        h, o = self.spacing, self.grid.origin
        other = [a for a in range(3) if a != axis]
        cuts = []
        for a in other:
            knots = o[a] + (np.arange(np.floor((lo[a] - o[a]) / h - 0.5), np.ceil((hi[a] - o[a]) / h + 0.5) + 1) + 0.5) * h
            edges = np.unique(np.clip(knots, lo[a], hi[a]))
            cuts.append(np.stack([edges[:-1], edges[1:]], axis=1))
        pieces = np.array([(a0, a1, b0, b1) for a0, a1 in cuts[0] for b0, b1 in cuts[1] if a1 > a0 and b1 > b0])
        if not len(pieces):
            raise ValueError(f"spline body: an empty face at x[{axis}] = {value}")
        g, w = np.polynomial.legendre.leggauss(3)
        ga, gb = np.meshgrid(g, g, indexing="ij")
        wab = np.outer(w, w).ravel()
        half_a, mid_a = (pieces[:, 1] - pieces[:, 0]) / 2, (pieces[:, 1] + pieces[:, 0]) / 2
        half_b, mid_b = (pieces[:, 3] - pieces[:, 2]) / 2, (pieces[:, 3] + pieces[:, 2]) / 2
        points = np.empty((len(pieces), 9, 3))
        points[:, :, axis] = value
        points[:, :, other[0]] = mid_a[:, None] + half_a[:, None] * ga.ravel()[None]
        points[:, :, other[1]] = mid_b[:, None] + half_b[:, None] * gb.ravel()[None]
        weights = (half_a * half_b)[:, None] * wab[None]
        return points.reshape(-1, 3), weights.ravel()

    def field(self, points: np.ndarray, node_values: np.ndarray) -> np.ndarray:
        """The B-spline field of per-node values (N, C) at world points (P, 3): (P, C)."""
        nodes, values, _ = self.locate(points)
        return np.einsum("pa,pac->pc", values, np.asarray(node_values, np.float64)[nodes])

    # -- linear elasticity ----------------------------------------------------------------------

    def stresses(self, local: np.ndarray) -> tuple[np.ndarray, float]:
        """For local displacements of every span's nodes (S, 27, 3), m: the stress at each Gauss
        point (Q, 3, 3), Pa (``2 μ ε_dev + κ θ I``, θ the volumetric strain as
        :attr:`dilatation` takes it), and the elastic energy, J."""
        mu, kappa = self.moduli
        theta = None if self.dilatation == "full" else self.dilatations(local)
        stress = np.empty((len(self.point_s), 3, 3))
        energy = 0.0
        eye = np.eye(3)
        for spans, points in self.chunks():
            g = self.point_gradients(points)
            h = np.einsum("qai,qaj->qij", local[self.point_span[points]], g)  # displacement gradient
            eps = 0.5 * (h + h.transpose(0, 2, 1))
            trace = np.trace(eps, axis1=1, axis2=2)
            dev = eps - trace[:, None, None] / 3.0 * eye
            vol = trace if theta is None else theta[points]
            stress[points] = 2.0 * mu * dev + (kappa * vol)[:, None, None] * eye
            w = self.point_weight[points]
            energy += float(mu * np.einsum("q,qij,qij->", w, dev, dev) + 0.5 * kappa * np.sum(w * vol * vol))
        return stress, energy

    def span_forces(self, local: np.ndarray, *, by_points: bool | None = None) -> tuple[np.ndarray, float]:
        """The elastic forces on every span's nodes (S, 27, 3), N, in the span's frame, for local
        displacements (S, 27, 3), m, and the energy, J (the projected θ is the L2 projection of
        tr ε, so ``sum_q w_q θ tr(δε) = sum_q w_q θ δθ``: the forces are the energy's gradient).

        Two ways to the same sums: ``-K_e u~`` with each :attr:`span_patterns` pattern's matrix
        (a few kinds of span: a box body) or the stresses at the Gauss points (``by_points``; the
        default where there are more than :data:`MAX_PATTERNS` kinds)."""
        ids, first = self.span_patterns
        if by_points is False or (by_points is None and len(first) <= MAX_PATTERNS):
            flat = np.asarray(local, np.float64).reshape(len(local), 81)
            forces = np.empty_like(flat)
            for p, k in enumerate(self.pattern_matrices):
                sel = ids == p
                forces[sel] = -flat[sel] @ k
            return forces.reshape(local.shape), -0.5 * float(np.einsum("si,si->", forces, flat))
        stress, energy = self.stresses(local)
        forces = np.zeros_like(local)
        for spans, points in self.chunks():
            g = self.point_gradients(points) * self.point_weight[points, None, None]
            f = -np.einsum("qij,qaj->qai", stress[points], g)
            np.add.at(forces, self.point_span[points], f)
        return forces, energy

    def linear_forces(self, u: np.ndarray) -> np.ndarray:
        """``-K u``: the linear elastic forces (N, 3), N, of node displacements u (N, 3), m."""
        local = np.asarray(u, np.float64)[self.span_nodes]
        forces, _ = self.span_forces(local)
        out = np.zeros((self.count, 3))
        np.add.at(out, self.span_nodes, forces)
        return out

    @cached_property
    def span_patterns(self) -> tuple[np.ndarray, np.ndarray]:
        """Spans whose material has the same Gauss points and weights have the same stiffness
        matrix (a box body has at most 27 kinds: full, and cut low or high along each axis): (S,)
        each span's pattern and (U,) one span of each pattern."""
        count = len(self.span_nodes)
        starts = np.searchsorted(self.point_span, np.arange(count + 1))
        scale = self.spacing ** 3
        seen: dict[bytes, int] = {}
        ids = np.empty(count, np.int64)
        for span in range(count):
            a, b = starts[span], starts[span + 1]
            key = (np.rint(self.point_s[a:b] * 1e9).astype(np.int64).tobytes()
                   + np.rint(self.point_weight[a:b] / scale * 1e12).astype(np.int64).tobytes())
            ids[span] = seen.setdefault(key, len(seen))
        first = np.zeros(len(seen), np.int64)
        first[ids[::-1]] = np.arange(count)[::-1]
        return ids, first

    @cached_property
    def pattern_matrices(self) -> np.ndarray:
        """(U, 81, 81) the stiffness matrix of each :attr:`span_patterns` pattern, N/m (row 3a + i:
        the span's node a, axis i); built where there are at most :data:`MAX_PATTERNS`."""
        return np.stack([self._span_matrix(int(span)) for span in self.span_patterns[1]])

    @cached_property
    def _span_starts(self) -> np.ndarray:
        """(S + 1,) where each span's Gauss points start."""
        return np.searchsorted(self.point_span, np.arange(len(self.span_nodes) + 1))

    def _span_matrix(self, span: int) -> np.ndarray:
        """(81, 81) one span's stiffness matrix, N/m."""
        mu, kappa = self.moduli
        pts = np.arange(self._span_starts[span], self._span_starts[span + 1])
        g = span_basis(self.point_s[pts], self.spacing)[1]
        w = self.point_weight[pts]
        dots = np.einsum("q,qad,qbd->ab", w, g, g)
        cross = np.einsum("q,qaj,qbi->aibj", w, g, g)  # G_a,j G_b,i
        vol = np.einsum("q,qai,qbj->aibj", w, g, g)    # G_a,i G_b,j
        shear = kappa - 2.0 * mu / 3.0 if self.dilatation == "full" else -2.0 * mu / 3.0
        k = mu * (dots[:, None, :, None] * np.eye(3)[None, :, None, :] + cross) + shear * vol
        if self.dilatation != "full":
            _, inverse, moments = self._projection
            k += kappa * np.einsum("kai,kl,lbj->aibj", moments[span], inverse[span], moments[span])
        return k.reshape(81, 81)

    def span_matrices(self, spans: slice) -> np.ndarray:
        """(s, 81, 81) the stiffness matrices of the spans ``spans``, N/m (each kind's once where
        there are few kinds, else span by span)."""
        if len(self.span_patterns[1]) <= MAX_PATTERNS:
            return self.pattern_matrices[self.span_patterns[0][spans]]
        return np.stack([self._span_matrix(s) for s in range(spans.start, spans.stop)])

    def assemble(self, rotations: np.ndarray | None = None) -> sp.csr_matrix:
        """The stiffness (3N, 3N), N/m: the spans' matrices, each turned by its rotation (S, 3, 3)
        as ``R K_e R^T`` (the corotational form; None: the linear K)."""
        rows, cols, vals = [], [], []
        dof = (3 * self.span_nodes[:, :, None] + np.arange(3)).reshape(len(self.span_nodes), 81)
        for start in range(0, len(self.span_nodes), 256):
            spans = slice(start, min(start + 256, len(self.span_nodes)))
            k = self.span_matrices(spans)
            if rotations is not None:
                r = rotations[spans]
                k = k.reshape(-1, 27, 3, 27, 3)
                k = np.einsum("sij,sajbk,slk->saibl", r, k, r).reshape(-1, 81, 81)
            d = dof[spans]
            rows.append(np.repeat(d, 81, axis=1).ravel())
            cols.append(np.tile(d, (1, 81)).ravel())
            vals.append(k.ravel())
        n = 3 * self.count
        return sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(n, n)).tocsr()
