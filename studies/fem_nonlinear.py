"""Geometrically and materially nonlinear FEM reference: a clamped cantilever sagging under its
own weight, compressible neo-Hookean, large deflection (the lattice's large-strain check).

What it computes (:func:`neo_hookean_cantilever_tip`): a box ``length x width x width`` (x the
beam axis, y up, gravity -y), clamped (all displacement components zero) at x = 0, under the dead
body force ``-rho g e_y`` per unit reference volume, in static equilibrium, for the energy density
of Bonet & Wood 2008, eq. 6.27 (*Nonlinear Continuum Mechanics for Finite Element Analysis*,
2nd ed., section 6.4.3)::

    Psi(F) = mu/2 (I1 - 3) - mu ln J + lambda/2 (ln J)^2,   I1 = tr(F^T F),  J = det F,

with ``mu = E / (2 (1 + nu))`` and ``lambda = E nu / ((1 + nu)(1 - 2 nu))``. Its first
Piola-Kirchhoff stress is ``P = mu (F - F^-T) + lambda ln J F^-T`` (the Cauchy stress of
Bonet & Wood 2008, eq. 6.28, ``sigma = mu/J (b - I) + lambda/J ln J I``, pulled back).

Discretisation: total Lagrangian, mixed displacement/pressure so that it does not lock as nu ->
1/2. The volumetric term is written with an independent field ``p`` (the Lagrange multiplier of
``ln J``, tension positive): ``Pi(u, p) = int [mu/2 (I1 - 3) - mu ln J + p ln J - p^2/(2 lambda)]
dV - int rho g . u dV``; eliminating ``p = lambda ln J`` pointwise gives back Psi exactly (a
perturbed-Lagrangian two-field form, so the continuum problem is unchanged). Taylor-Hood
hexahedra: triquadratic ``u`` (scikit-fem's ``ElementHex2``, one per component), trilinear
continuous ``p`` (``ElementHex1``), 3x3x3 Gauss points. The residual and the consistent tangent
(:class:`MixedNeoHookean`)::

    dP/dF : A_iJkL = mu d_ik d_JL + (mu - p) F^-1_Jk F^-1_Li,     dP/dp = F^-T,

are assembled by vectorised NumPy over all elements (scikit-fem supplies the mesh, the basis
functions and the quadrature). Symmetry halves the body: z in [0, width/2] with u_z = 0 on the
plane z = width/2. Newton's method on the load factor t in (0, 1] (the gravity times t) with
adaptive steps (halved when Newton fails, grown after quick convergence) and a backtracking step
that keeps ``J > 0``; each linear system (symmetric indefinite) by SciPy's SuperLU.

Measured: the displacement (u_x, u_y) of the end face's centre (x = length, the centreline, the
elastica's tip) and the area mean of u over the end face (reference area); both are returned.

Verified (``tests/test_fem_tissue.py``): the tangent is the finite-difference derivative of the
residual and the residual that of the energy; at a tiny load the tip equals the independent linear
mixed FEM of :mod:`studies.fem_tissue` (scikit-fem forms) on the same mesh to 1e-5; at
E = 500 kPa, 0.2 x 0.02 x 0.02 m, rho = 1000 kg/m^3 it is within a few per cent of the
inextensible elastica (:func:`studies.fem_tissue.elastica_tip`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from deformgl.bench.fem import require_skfem
from deformgl.errors import DeformglError

__all__ = ["MixedNeoHookean", "TipResult", "neo_hookean_cantilever_tip", "cantilever_coordinates",
           "lame", "sparse_solve"]


def lame(E: float, nu: float) -> tuple[float, float]:
    """(mu, lambda) in Pa of Young's modulus E in Pa and Poisson's ratio nu."""
    return E / (2.0 * (1.0 + nu)), E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))


def cantilever_coordinates(length: float, width: float, cells_across: int,
                           cells_along: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Node coordinates (x, y, z) in m of the half cantilever's tensor mesh: ``cells_along``
    elements along x (default: cubes, ``cells_across * length / width``), ``cells_across`` across
    y in [0, width] and ``ceil(cells_across / 2)`` across z in [0, width / 2]."""
    if cells_across < 1:
        raise ValueError(f"cells_across must be >= 1, got {cells_across}")
    along = cells_along or max(1, int(round(cells_across * length / width)))
    return (np.linspace(0.0, length, along + 1), np.linspace(0.0, width, cells_across + 1),
            np.linspace(0.0, width / 2.0, (cells_across + 1) // 2 + 1))


def sparse_solve(k: sp.spmatrix, b: np.ndarray, what: str) -> np.ndarray:
    """``k x = b`` by SuperLU (COLAMD ordering, partial pivoting) with iterative refinement (the
    saddle-point systems lose ~1e-5 relative without it) until the relative residual is below
    1e-12 (at most 4 steps); raises DeformglError when it stays above 1e-8."""
    from scipy.sparse.linalg import splu

    k = sp.csc_matrix(k)
    try:
        lu = splu(k)
    except RuntimeError:
        raise DeformglError(f"{what}: the matrix is singular") from None
    x = lu.solve(b)
    scale = max(float(np.linalg.norm(b)), 1e-300)
    for _ in range(4):
        r = b - k @ x
        if not float(np.linalg.norm(r)) / scale > 1e-12:
            break
        x += lu.solve(r)
    residual = float(np.linalg.norm(k @ x - b)) / scale
    if not residual < 1e-8:
        raise DeformglError(f"{what}: direct solve residual {residual:.1e}")
    return x


class MixedNeoHookean:
    """The two-field (u in Q2, p in Q1) neo-Hookean body on a hexahedral tensor mesh: energy,
    residual and tangent of the vector ``x = [u (3 per Q2 node, node-major), p]``.

    Args:
        xs, ys, zs: node coordinates along each axis (m).
        mu, lam: Lame constants (Pa).
        body: dead body force per reference volume (N/m^3), a 3-vector.
    """

    def __init__(self, xs: np.ndarray, ys: np.ndarray, zs: np.ndarray, mu: float, lam: float,
                 body: tuple[float, float, float]) -> None:
        require_skfem()
        from skfem import Basis, ElementHex1, ElementHex2, MeshHex  # type: ignore[import-untyped,import-not-found,unused-ignore]

        self.mesh = MeshHex.init_tensor(xs, ys, zs)
        self.ubasis = Basis(self.mesh, ElementHex2(), intorder=4)
        self.pbasis = self.ubasis.with_element(ElementHex1())
        self.mu, self.lam = float(mu), float(lam)
        self.n_u, self.n_p = 3 * self.ubasis.N, self.pbasis.N
        ub, pb = self.ubasis, self.pbasis
        self.dx = np.asarray(ub.dx)                                                    # (E, Q)
        self.grad = np.stack([np.asarray(f[0].grad) for f in ub.basis]).transpose(2, 3, 0, 1)  # (E, Q, 27, 3)
        shape = np.stack([np.asarray(f[0]) for f in ub.basis]).transpose(1, 2, 0)  # (E, Q, 27)
        self.np_ = np.stack([np.asarray(f[0]) for f in pb.basis]).transpose(1, 2, 0)  # (E, Q, 8)
        self.udofs = np.asarray(ub.element_dofs).T                                      # (E, 27)
        self.pdofs = np.asarray(pb.element_dofs).T                                      # (E, 8)
        ne = self.udofs.shape[0]
        edofs = np.concatenate([(3 * self.udofs[:, :, None] + np.arange(3)).reshape(ne, 81),
                                self.n_u + self.pdofs], axis=1)                        # (E, 89)
        self.edofs = edofs
        rows = np.repeat(edofs, 89, axis=1).ravel()
        cols = np.tile(edofs, (1, 89)).ravel()
        pattern = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(self.size, self.size))
        pattern.sum_duplicates()
        pattern.sort_indices()
        self._indptr, self._indices = pattern.indptr, pattern.indices
        # the position of each element entry in the CSR data array
        key = rows.astype(np.int64) * self.size + cols
        csr_keys = np.repeat(np.arange(self.size, dtype=np.int64), np.diff(self._indptr)) * self.size + self._indices
        self._slot = np.searchsorted(csr_keys, key)
        f = np.einsum("eq,eqa->ea", self.dx, shape)                                       # int N_a dV
        self.force = np.zeros(self.size)
        for i in range(3):
            np.add.at(self.force, 3 * self.udofs.ravel() + i, body[i] * f.ravel())
        self.doflocs = np.asarray(ub.doflocs).T                                          # (Nnodes, 3)

    @property
    def size(self) -> int:
        """Unknowns: 3 per Q2 node plus 1 per Q1 node."""
        return self.n_u + self.n_p

    def _fields(self, x: np.ndarray):
        u = x[:self.n_u].reshape(-1, 3)[self.udofs]                  # (E, 27, 3)
        pe = x[self.n_u:][self.pdofs]                                 # (E, 8)
        f = np.eye(3) + np.einsum("eai,eqaj->eqij", u, self.grad)     # F_iJ
        jac = np.linalg.det(f)
        p = np.einsum("ec,eqc->eq", pe, self.np_)
        return f, jac, p

    def energy(self, x: np.ndarray, load: float = 1.0) -> float:
        """Pi(u, p) in J (``load`` scales the body force)."""
        f, jac, p = self._fields(x)
        if np.any(jac <= 0):
            return math.inf
        lnj = np.log(jac)
        w = (self.mu / 2 * (np.einsum("eqij,eqij->eq", f, f) - 3) - self.mu * lnj + p * lnj
             - p ** 2 / (2 * self.lam))
        return float((w * self.dx).sum() - load * self.force @ x)

    def residual(self, x: np.ndarray, load: float = 1.0) -> np.ndarray:
        """dPi/dx: N for the u rows, m^3 for the p rows (nan where J <= 0)."""
        f, jac, p = self._fields(x)
        finv = np.linalg.inv(f)
        with np.errstate(invalid="ignore", divide="ignore"):
            lnj = np.log(jac)
        fit = finv.transpose(0, 1, 3, 2)
        stress = self.mu * (f - fit) + p[..., None, None] * fit                        # P_iJ
        ru = np.einsum("eqiJ,eqaJ,eq->eai", stress, self.grad, self.dx)
        rp = np.einsum("eq,eqc->ec", (lnj - p / self.lam) * self.dx, self.np_)
        r = np.zeros(self.size)
        np.add.at(r, self.edofs[:, :81].ravel(), ru.ravel())
        np.add.at(r, self.edofs[:, 81:].ravel(), rp.ravel())
        return r - load * self.force

    def tangent(self, x: np.ndarray) -> sp.csr_matrix:
        """d^2 Pi / dx^2 (symmetric, indefinite)."""
        f, _, p = self._fields(x)
        finv = np.linalg.inv(f)
        g = np.einsum("eqaJ,eqJk->eqak", self.grad, finv)             # spatial gradients
        ne, nq = self.dx.shape
        gg = np.einsum("eq,eqaJ,eqbJ->eab", self.dx * self.mu, self.grad, self.grad)
        kuu = np.einsum("eab,ik->eaibk", gg, np.eye(3))
        gf = g.reshape(ne, nq, 81)
        y = np.matmul((gf * ((self.mu - p) * self.dx)[..., None]).transpose(0, 2, 1), gf)  # (E, (a,k), (b,i))
        kuu += y.reshape(ne, 27, 3, 27, 3).transpose(0, 1, 4, 3, 2)
        kup = np.einsum("eqai,eqc,eq->eaic", g, self.np_, self.dx).reshape(ne, 81, 8)
        kpp = -np.einsum("eqc,eqd,eq->ecd", self.np_, self.np_, self.dx) / self.lam
        ke = np.zeros((ne, 89, 89))
        ke[:, :81, :81] = kuu.reshape(ne, 81, 81)
        ke[:, :81, 81:] = kup
        ke[:, 81:, :81] = kup.transpose(0, 2, 1)
        ke[:, 81:, 81:] = kpp
        data = np.bincount(self._slot, weights=ke.ravel(), minlength=len(self._indices))
        return sp.csr_matrix((data, self._indices, self._indptr), shape=(self.size, self.size))

    def face_mean(self, x: np.ndarray, axis: int, value: float) -> np.ndarray:
        """The area mean (reference area) of u over the mesh face ``x[axis] = value``, (3,)."""
        from skfem import ElementHex2, FacetBasis  # type: ignore[import-untyped,import-not-found,unused-ignore]

        fb = FacetBasis(self.mesh, ElementHex2(),
                               facets=self.mesh.facets_satisfying(lambda c: np.isclose(c[axis], value)),
                               intorder=4)
        u = x[:self.n_u].reshape(-1, 3)
        dx = np.asarray(fb.dx)
        return np.array([(np.asarray(fb.interpolate(u[:, i])) * dx).sum() for i in range(3)]) / dx.sum()

    def node(self, point: tuple[float, float, float]) -> int:
        """The Q2 node at ``point`` (m); raises ValueError when there is none."""
        d = np.linalg.norm(self.doflocs - np.asarray(point), axis=1)
        i = int(np.argmin(d))
        if d[i] > 1e-9 * max(1.0, float(np.abs(self.doflocs).max())):
            raise ValueError(f"no Q2 node at {point}")
        return i


@dataclass(frozen=True)
class TipResult:
    """Tip of the neo-Hookean cantilever: ``centre`` (u_x, u_y) in m of the end face's centre,
    ``mean`` (u_x, u_y) the end face's area mean; the mesh (elements across the width, along
    the length), unknowns, load steps, Newton iterations in all, and the solve's wall time in s."""

    centre: tuple[float, float]
    mean: tuple[float, float]
    cells_across: int
    cells_along: int
    dofs: int
    steps: int
    newton: int
    seconds: float


def _newton(body: MixedNeoHookean, free: np.ndarray, x: np.ndarray, load: float,
            max_iter: int = 12) -> tuple[np.ndarray, int] | None:
    """Newton at one load factor from ``x``; the converged state and iteration count, or None."""
    fnorm = max(float(np.linalg.norm(body.force[free])) * load, 1e-300)
    n_free_u = int(np.count_nonzero(free[:body.n_u]))
    du = math.inf
    for it in range(max_iter + 1):
        r = body.residual(x, load)
        if not np.all(np.isfinite(r)):
            return None
        r_u = float(np.linalg.norm(r[free][:n_free_u]))
        if r_u < 1e-6 * fnorm and du <= 1e-9 * float(np.abs(x[:body.n_u]).max()):
            return x, it
        if it == max_iter:
            return None
        k = body.tangent(x)[free][:, free]
        try:
            dx = sparse_solve(k, -r[free], "neo-Hookean Newton step")
        except DeformglError:
            return None
        step = 1.0
        while True:  # backtrack until J > 0 everywhere
            trial = x.copy()
            trial[free] += step * dx
            if np.all(np.isfinite(body.residual(trial, load))):
                break
            step /= 2
            if step < 0.1:
                return None
        x = trial
        du = float(np.abs(dx[:n_free_u]).max()) * step
    return None


def neo_hookean_cantilever_tip(length: float, width: float, E: float, nu: float, rho: float,
                               g: float = 9.81, cells_across: int = 2, cells_along: int | None = None,
                               *, first_step: float = 0.1) -> TipResult:
    """The clamped neo-Hookean cantilever's tip under its own weight (see the module docstring).

    Args:
        length, width: m (the section is width x width).
        E: Young's modulus in Pa; nu: Poisson's ratio (< 0.5; the mixed form does not lock).
        rho: density in kg/m^3; g: gravity in m/s^2 (along -y).
        cells_across: Q2 elements across the width; cells_along: along the length (default cubes).
        first_step: the first load increment (a fraction of the full weight).

    Raises:
        DeformglError: the load stepping stalled (the step fell below 1e-4 of the load).
    """
    start = time.perf_counter()
    xs, ys, zs = cantilever_coordinates(length, width, cells_across, cells_along)
    mu, lam = lame(E, nu)
    body = MixedNeoHookean(xs, ys, zs, mu, lam, (0.0, -rho * g, 0.0))
    held = np.zeros(body.size, bool)
    nodes = body.doflocs
    clamp = np.isclose(nodes[:, 0], 0.0)
    for i in range(3):
        held[3 * np.flatnonzero(clamp) + i] = True
    held[3 * np.flatnonzero(np.isclose(nodes[:, 2], width / 2)) + 2] = True
    free = ~held
    x = np.zeros(body.size)
    velocity = np.zeros(body.size)  # dx/dt of the last step: the predictor
    t, dt, steps, iters = 0.0, first_step, 0, 0
    while t < 1.0:
        dt = min(dt, 1.0 - t)
        got = _newton(body, free, x + dt * velocity, t + dt)
        if got is None:
            dt /= 2
            if dt < 1e-4:
                raise DeformglError(f"neo-Hookean cantilever: load stepping stalled at {t:.4f} of the weight")
            continue
        velocity = (got[0] - x) / dt
        x, n = got
        t += dt
        steps += 1
        iters += n
        if n <= 4:
            dt *= 2.0
        elif n <= 6:
            dt *= 1.4
    tip = x[:body.n_u].reshape(-1, 3)[body.node((length, width / 2, width / 2))]
    mean = body.face_mean(x, 0, length)
    return TipResult((float(tip[0]), float(tip[1])), (float(mean[0]), float(mean[1])), cells_across,
                     len(xs) - 1, int(free.sum()), steps, iters, time.perf_counter() - start)
