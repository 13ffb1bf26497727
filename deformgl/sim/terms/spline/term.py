"""The spline body as physics terms of a :class:`~deformgl.sim.springs.SpringSystem` whose nodes are
its control points: :class:`SplineCells` (the corotational elastic body) and
:class:`SplineAnchor` (a region held by a penalty on the material in it), and
:func:`spline_system` that builds the system (no springs; the nodes' masses the body's lumped
masses).

Corotational elasticity (Müller & Gross 2004, section 4; SOFA's "large" hexahedra): each knot span
turns its nodes back by the rotation ``R`` of the polar decomposition ``F = R S`` of the
deformation gradient at its material's centroid, takes the linear elastic forces of the local
displacements ``u~_a = R^T (x_a - x_c) - (X_a - X_c)`` (c the span's centre node) and turns them
forward: ``f_a = R f~_a``. ``R`` is a proper rotation even where the span is inverted (det F <= 0:
the singular vector of the smallest singular value flipped, Irving, Teran & Fedkiw 2004, section 5),
so an inverted span is pushed back. The forces of a fixed ``R`` are its energy's gradient; the
Hessian is ``R K_e R^T`` per span (positive semi-definite).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from deformgl.grid.nodes import NodeGrid
from deformgl.sim.springs import SpringSystem
from deformgl.sim.terms.base import GlslTerm, Term, TermNeeds
from deformgl.sim.terms.spline.basis import span_basis
from deformgl.sim.terms.spline.body import SplineBody
from deformgl.sim.terms.spline.glsl_form import anchor_glsl, spline_glsl

__all__ = ["NEEDS", "SplineAnchor", "SplineCells", "polar_rotations", "spline_system"]

#: The backends' forms the spline terms do not have yet, each with the phrase a refusal gives.
_NO_FORM = {"fragment": "GLSL", "implicit": "implicit-Euler", "feedback": "transform-feedback", "xpbd": "XPBD"}
#: What a spline body costs and refuses, from the scene alone (:class:`~deformgl.sim.terms.TermNeeds`,
#: ``[material] model = "spline"``): on the host its Gauss points (27 a span, a span a node at
#: most: 27 x 4 float64), span tables and the volumetric projection's moments (4 x 27 x 3 float64
#: a span) and functions (27 x 4); on the GPU its node tables (7 RGBA32F layers each for the
#: cells and an anchor) and the span pass's textures (53 texels a span, counted per node texel).
#: Implicit Euler and XPBD have no form of it.
NEEDS = TermNeeds("material.model", host_bytes_per_node=27 * 4 * 8 + 28 * 4 + 72 * 4 + (4 * 27 * 3 + 27 * 4) * 8,
                  node_layers=14, texel_bytes=53 * 16,
                  refused=(("implicit-euler", "model = \"spline\" has no implicit-Euler form yet (the explicit "
                            "integrators run it)"),
                           ("xpbd", "model = \"spline\" has no XPBD form yet (the explicit integrators run it)")))
#: The spline terms have a GLSL form (the fragment backend's explicit stages).
_GPU_NO_FORM = {k: v for k, v in _NO_FORM.items() if k != "fragment"}


def polar_rotations(f: np.ndarray) -> np.ndarray:
    """(S, 3, 3) the rotations of the polar decompositions of deformation gradients (S, 3, 3),
    proper (det +1) also where det F <= 0."""
    u, _, vt = np.linalg.svd(f)
    flip = np.linalg.det(u) * np.linalg.det(vt) < 0
    u[flip, :, 2] *= -1.0  # (the smallest singular value's direction)
    return u @ vt


class SplineCells(Term):
    """The spline body's elastic forces on its control points (the module docstring).

    Args:
        body: the spline body; the system's node n is the body's control point n.
    """

    name = "spline cells"

    def __init__(self, body: SplineBody) -> None:
        self.body = body
        #: (S, 27, 3) the basis gradients at each span's material centroid, 1/m (where R is taken)
        self.centroid_gradients = span_basis(body.span_centroids, body.spacing)[1]
        self._rest_k: sp.csr_matrix | None = None
        self._glsl: GlslTerm | None = None

    def describe(self) -> str:
        b = self.body
        return (f"{self.name}, E = {b.youngs_modulus:g} Pa, nu = {b.poissons_ratio:g}, "
                f"h = {b.spacing:g} m, {len(b.span_nodes)} spans")

    def deformation(self, x: np.ndarray) -> np.ndarray:
        """(S, 3, 3) each span's deformation gradient at its material's centroid."""
        u = np.asarray(x, np.float64) - self.body.rest_positions
        return np.eye(3) + np.einsum("sai,saj->sij", u[self.body.span_nodes], self.centroid_gradients)

    def _local(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The rotations (S, 3, 3) and the spans' local displacements (S, 27, 3)."""
        b = self.body
        x = np.asarray(x, np.float64)
        r = polar_rotations(self.deformation(x))
        xs, rest = x[b.span_nodes], b.rest_positions[b.span_nodes]
        dx = xs - xs[:, 13:14]
        local = np.einsum("sji,saj->sai", r, dx) - (rest - rest[:, 13:14])
        return r, local

    def add_forces(self, x: np.ndarray, v: np.ndarray, t: float, out: np.ndarray) -> None:
        r, local = self._local(x)
        forces, _ = self.body.span_forces(local)
        np.add.at(out, self.body.span_nodes, np.einsum("sij,saj->sai", r, forces))

    def energy(self, x: np.ndarray) -> float:
        return self.body.span_forces(self._local(x)[1])[1]

    def stiffness(self, x: np.ndarray) -> sp.csr_matrix:
        return self.body.assemble(polar_rotations(self.deformation(x)))

    def dt_stiffness(self, x_rest: np.ndarray, *, barrier: bool = False) -> sp.csr_matrix:
        """K at rest, the linear stiffness (each span's corotational ``R K_e R^T`` has the
        eigenvalues of its ``K_e``; assembled with different R the largest stayed at or below the
        rest value where measured)."""
        if self._rest_k is None:
            self._rest_k = self.body.assemble()
        return self._rest_k

    def dt_product(self, x_rest: np.ndarray, dx: np.ndarray, *, barrier: bool = False) -> np.ndarray:
        return -self.body.linear_forces(np.asarray(dx, np.float64))

    def frequency_terms(self, x_rest: np.ndarray, *, barrier: bool = False) -> np.ndarray:
        """(N,) each node's largest row sum of ``sum_spans |K_e|``, N/m: at least the assembled K's
        Gershgorin row sum (``|sum K_e| <= sum |K_e|``), without assembling K (whose 6,561 entries a
        span took 5.8 GB at 20k nodes)."""
        b = self.body
        rows = np.zeros((b.count, 3))
        for start in range(0, len(b.span_nodes), 256):
            spans = slice(start, min(start + 256, len(b.span_nodes)))
            sums = np.abs(b.span_matrices(spans)).sum(axis=2).reshape(-1, 27, 3)
            np.add.at(rows, b.span_nodes[spans], sums)
        return rows.max(axis=1)

    def inversions(self, x: np.ndarray, grid: NodeGrid | None) -> tuple[int, str] | None:
        """The spans with a Gauss point at det F <= 0."""
        b = self.body
        u = np.asarray(x, np.float64) - b.rest_positions
        bad = np.zeros(len(b.span_nodes), bool)
        for spans, points in b.chunks():
            g = b.point_gradients(points)
            f = np.eye(3) + np.einsum("qai,qaj->qij", u[b.span_nodes[b.point_span[points]]], g)
            bad[b.point_span[points][np.linalg.det(f) <= 0.0]] = True
        count = int(bad.sum())
        if not count:
            return 0, ""
        first = int(np.argmax(bad))
        where = b.grid.ijk[b.span_nodes[first, 13]].tolist()
        return count, f"{count} of {len(bad)} spline spans inverted (first: the span of node {where})"

    def glsl(self, grid: NodeGrid | None) -> GlslTerm:
        """The span pass and the gather (:mod:`deformgl.sim.terms.spline.glsl_form`); ValueError
        (one line) for a body whose spans are not one 3 x 3 x 3 grid of Gauss points each."""
        if self._glsl is None:
            self._glsl = spline_glsl(self.body)
        return self._glsl

    def refusal(self, backend: str) -> str | None:
        form = _GPU_NO_FORM.get(backend)
        return None if form is None else f"{self.name} have no {form} form yet (the NumPy reference runs them)"


class SplineAnchor(Term):
    """A region of the material held at its rest place by a penalty (issue 44, item 3): the energy
    ``k/2 int_region |u(x)|^2`` over the region's Gauss points, forces ``-K_p (x - X)``.

    Args:
        body: the spline body.
        points: (P, 3) the region's quadrature points at rest, m.
        weights: (P,) their weights (m^3 for a volume, m^2 for a face).
        stiffness: k, N/m^4 for a volume region, N/m^3 for a face (β E / h: Pa per m).
    """

    name = "spline anchor"

    def __init__(self, body: SplineBody, points: np.ndarray, weights: np.ndarray, stiffness: float) -> None:
        if not stiffness > 0:
            raise ValueError(f"{self.name}: stiffness must be > 0, got {stiffness}")
        nodes, values, _ = body.locate(points)
        w = np.asarray(weights, np.float64) * float(stiffness)
        rows = np.repeat(nodes, 27, axis=1).ravel()
        cols = np.tile(nodes, (1, 27)).ravel()
        scalar = sp.coo_matrix(((w[:, None, None] * values[:, :, None] * values[:, None, :]).ravel(),
                                (rows, cols)), shape=(body.count, body.count)).tocsr()
        self.body, self.stiffness_value = body, float(stiffness)
        #: (P, 3) the quadrature points, m, and (P,) their weights
        self.points, self.weights = np.asarray(points, np.float64), np.asarray(weights, np.float64)
        self._glsl: GlslTerm | None = None
        #: (3N, 3N) the penalty's constant stiffness, N/m
        self.matrix = sp.kron(scalar, sp.eye(3), format="csr")

    def describe(self) -> str:
        return f"{self.name}, k = {self.stiffness_value:g}"

    def add_forces(self, x: np.ndarray, v: np.ndarray, t: float, out: np.ndarray) -> None:
        u = (np.asarray(x, np.float64) - self.body.rest_positions).ravel()
        out -= (self.matrix @ u).reshape(-1, 3)

    def energy(self, x: np.ndarray) -> float:
        u = (np.asarray(x, np.float64) - self.body.rest_positions).ravel()
        return 0.5 * float(u @ (self.matrix @ u))

    def stiffness(self, x: np.ndarray) -> sp.csr_matrix:
        return self.matrix

    def glsl(self, grid: NodeGrid | None) -> GlslTerm:
        """The anchor's span pass and gather (:func:`~deformgl.sim.terms.spline.glsl_form.anchor_glsl`)."""
        if self._glsl is None:
            self._glsl = anchor_glsl(self.body, self.points, self.weights * self.stiffness_value)
        return self._glsl

    def refusal(self, backend: str) -> str | None:
        form = _GPU_NO_FORM.get(backend)
        return None if form is None else f"{self.name}s have no {form} form yet (the NumPy reference runs them)"


def spline_system(body: SplineBody, *, anchors: tuple[SplineAnchor, ...] = (), gravity=(0.0, -9.81, 0.0),
                  mass_damping: float = 0.0, velocity_damping: float = 0.0) -> SpringSystem:
    """The spring system of a spline body: its control points as nodes with the body's lumped
    masses, no springs, the body's :class:`SplineCells` and its ``anchors`` as the terms."""
    n = body.count
    empty = np.zeros(0)
    return SpringSystem(rest_positions=body.rest_positions.copy(), mass=body.lumped_mass.copy(),
                        fixed=np.zeros(n, bool), i=np.zeros(0, np.int64), j=np.zeros(0, np.int64),
                        rest_length=empty, stiffness=empty, damping=empty, spring_class=np.zeros(0, np.int8),
                        velocity_damping=float(velocity_damping), mass_damping=float(mass_damping),
                        gravity=np.asarray(gravity, np.float64), spacing=body.spacing, grid=body.grid,
                        extra_terms=(SplineCells(body), *anchors))
