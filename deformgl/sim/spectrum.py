"""The linearised spring system at rest: the stiffness matrix ``K``, the spectrum of ``M^-1 K``
(dense ``eigh`` or Lanczos) and the modal damping model; the stability analysis of
:mod:`deformgl.sim.limits` and :mod:`deformgl.sim.growth` (Movania & Feng 2012, section 3) build on it."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from deformgl.sim.springs import SpringSystem
from deformgl.sim.stages import SPECS


#: Largest number of free nodes whose spectrum is computed densely (3N x 3N ``eigh``).
DENSE_MAX_NODES = 1500
#: Spectral radius above which a mode counts as unstable in the analytic limits (roundoff).
_RADIUS_TOL = 1e-12
#: Analytic limits are searched on dt * max(w, g) in [_Y_MIN, _Y_MAX].
_Y_MIN, _Y_MAX = 1e-3, 20.0
#: A run whose largest node displacement exceeds this many times the start amplitude has blown
#: up: 1e-6 * 1e3 = 1e-3 spacings is still linear, while a stable semi-implicit Euler run only
#: reaches ``1/sqrt(1 - (w dt)^2/4)`` times the start (more than 1e3 only within 5e-7 of 2/w).
_BLOW_UP = 1e3
_RK_POLY = {"euler": (1.0, 1.0), "midpoint": (1.0, 1.0, 0.5),
            "rk4": (1.0, 1.0, 0.5, 1.0 / 6.0, 1.0 / 24.0)}
#: The undamped limit of each integrator stable without damping, as messages write it
#: ("2/w", "2.83/w"; from the limit factors of :data:`deformgl.sim.stages.SPECS`).
_FORMULA: dict[str, str] = {name: s.limit_formula for name, s in SPECS.items()
                            if s.limit_formula is not None}



# --------------------------------------------------------------------------------------------
# The linearised system: K at rest, M^-1 K spectrum
# --------------------------------------------------------------------------------------------

def _rest_directions(system: SpringSystem) -> np.ndarray:
    """(S, 3) unit vector of each spring at rest (0 for a zero-length spring, as ``forces``)."""
    d = system.rest_positions[system.i] - system.rest_positions[system.j]
    length = np.linalg.norm(d, axis=1)
    return d / np.where(length > 0, length, 1.0)[:, None]


def stiffness_product(system: SpringSystem, dx: np.ndarray, *, barrier: bool = False) -> np.ndarray:
    """``K dx`` for displacements dx (N, 3): per spring ``k u (u . (dx_i - dx_j))`` on i, minus on j.

    K is the stiffness matrix at the rest state, where the geometric term ``k (1 - L/|d|)``
    vanishes, so each spring contributes the block ``k u u^T`` (the linearisation of Movania &
    Feng 2012 eq. 2, ``F = k (L - |d|) d/|d|``), and each physics term its
    :meth:`~deformgl.sim.terms.Term.dt_product`: with ``barrier`` what the term stiffens to in a
    run (the cells' inversion barrier where it is strongest,
    :func:`deformgl.sim.terms.volume.energy.barrier_envelope_product`; inactive at rest), the stiffness the
    explicit dt bound must cover. Returns (N, 3); fixed nodes are not masked.
    """
    u = _rest_directions(system)
    p = system.stiffness * np.einsum("sk,sk->s", dx[system.i] - dx[system.j], u)
    f = p[:, None] * u
    n = system.count
    ends = np.concatenate([system.i, system.j])
    signed = np.concatenate([f, -f])
    out = np.stack([np.bincount(ends, weights=signed[:, c], minlength=n) for c in range(3)], axis=1)
    out = out.astype(np.float64, copy=False)  # (a system without springs: bincount of nothing is int)
    for term in system.terms:
        out += term.dt_product(system.rest_positions, dx, barrier=barrier)
    return out


def stiffness_matrix(system: SpringSystem, *, barrier: bool = False) -> np.ndarray:
    """Dense (3N, 3N) stiffness matrix K at rest (blocks ``+-k u u^T``, and each of
    ``system.terms`` its :meth:`~deformgl.sim.terms.Term.dt_stiffness`, ``barrier`` as
    :func:`stiffness_product`), fixed nodes included."""
    n = system.count
    u = _rest_directions(system)
    blocks = system.stiffness[:, None, None] * u[:, :, None] * u[:, None, :]   # (S, 3, 3)
    k4 = np.zeros((n, n, 3, 3))
    np.add.at(k4, (system.i, system.i), blocks)
    np.add.at(k4, (system.j, system.j), blocks)
    np.add.at(k4, (system.i, system.j), -blocks)
    np.add.at(k4, (system.j, system.i), -blocks)
    k = k4.transpose(0, 2, 1, 3).reshape(3 * n, 3 * n)
    for term in system.terms:
        k += term.dt_stiffness(system.rest_positions, barrier=barrier).toarray()
    return k


def _free_scaling(system: SpringSystem) -> tuple[np.ndarray, np.ndarray]:
    """Free node numbers and ``m^-1/2`` per free degree of freedom (3 per node)."""
    free = np.nonzero(~system.fixed)[0]
    return free, np.repeat(1.0 / np.sqrt(system.mass[free]), 3)


@dataclass(frozen=True, eq=False)
class ExactFrequency:
    """The highest angular frequency of the linearised undamped system at rest.

    Attributes:
        omega: rad/s, ``sqrt(lambda_max(M^-1 K))`` over the free nodes.
        node: the free node that moves most in that mode (-1 without free nodes).
        spring: the spring storing most strain energy ``k (u . (x_i - x_j))^2`` in the mode.
        mode: (N, 3) displacement of the mode, largest node displacement 1, zero at fixed nodes.
        method: "dense" (``numpy.linalg.eigh``) or "lanczos".
        tolerance: bound on the relative error of ``omega**2`` ("dense": roundoff, 1e-12;
            "lanczos": the relative residual ``|A y - theta y| / theta`` reached, and
            ``theta <= lambda_max`` always, a Rayleigh quotient).
    """

    omega: float
    node: int
    spring: int
    mode: np.ndarray
    method: str
    tolerance: float


def _mass_normalised(system: SpringSystem, barrier: bool = False) -> np.ndarray:
    """Dense ``M^-1/2 K M^-1/2`` over the free degrees of freedom (``barrier``: :func:`stiffness_product`)."""
    free, s = _free_scaling(system)
    dof = (3 * free[:, None] + np.arange(3)).ravel()
    k = stiffness_matrix(system, barrier=barrier)[np.ix_(dof, dof)]
    return s[:, None] * k * s[None, :]


def _to_mode(system: SpringSystem, q: np.ndarray) -> np.ndarray:
    """Physical displacement (N, 3) of a mass-normalised free vector q, max node norm 1."""
    free, s = _free_scaling(system)
    mode = np.zeros((system.count, 3))
    mode[free] = (s * q).reshape(-1, 3)
    peak = np.linalg.norm(mode, axis=1).max()
    return mode / peak if peak > 0 else mode


def _describe(system: SpringSystem, omega2: float, q: np.ndarray, method: str,
              tol: float) -> ExactFrequency:
    mode = _to_mode(system, q)
    node = int(np.argmax(np.linalg.norm(mode, axis=1)))
    u = _rest_directions(system)
    energy = system.stiffness * np.einsum("sk,sk->s", mode[system.i] - mode[system.j], u) ** 2
    spring = int(np.argmax(energy)) if system.spring_count else -1
    return ExactFrequency(math.sqrt(max(omega2, 0.0)), node, spring, mode, method, tol)


def _lanczos_top(matvec, n: int, tol: float, rng: np.random.Generator, *,
                 block: int = 80, restarts: int = 50) -> tuple[float, np.ndarray, float]:
    """Largest eigenvalue of a symmetric positive semidefinite operator by restarted Lanczos.

    Full reorthogonalisation (twice, classical Gram-Schmidt) inside a block of ``block``
    vectors; after each block the method restarts from the top Ritz vector. Stops when the
    residual ``|A y - theta y| = beta_k |s_k|`` is at most ``tol * theta``.
    Returns (theta, y, relative residual).
    """
    q = rng.standard_normal(n)
    q /= np.linalg.norm(q)
    theta, rel = 0.0, np.inf
    m = min(block, n)
    for _ in range(restarts):
        basis = np.zeros((m, n))
        alpha, beta = np.zeros(m), np.zeros(m)
        basis[0] = q
        for k in range(m):
            w = matvec(basis[k])
            alpha[k] = w @ basis[k]
            for _ in range(2):
                w -= basis[:k + 1].T @ (basis[:k + 1] @ w)
            beta[k] = np.linalg.norm(w)
            t = np.diag(alpha[:k + 1]) + np.diag(beta[:k], 1) + np.diag(beta[:k], -1)
            vals, vecs = np.linalg.eigh(t)
            theta, s = vals[-1], vecs[:, -1]
            rel = beta[k] * abs(s[-1]) / max(theta, np.finfo(float).tiny)
            if rel <= tol or beta[k] <= 1e-14 * max(abs(theta), 1.0) or k + 1 == m:
                break
            basis[k + 1] = w / beta[k]
        q = s @ basis[:k + 1]
        q /= np.linalg.norm(q)
        if rel <= tol or beta[k] <= 1e-14 * max(abs(theta), 1.0):
            break
    return float(theta), q, float(rel)


def exact_frequency(system: SpringSystem, *, method: str = "auto", tol: float = 1e-10,
                    seed: int = 0, barrier: bool = False) -> ExactFrequency:
    """Largest eigenvalue of ``M^-1 K`` at rest over the free nodes, as an angular frequency.

    Args:
        system: the spring system (its rest state; gravity and damping do not enter).
        method: "dense" (``eigh`` of ``M^-1/2 K M^-1/2``), "lanczos" (sparse products only,
            :func:`stiffness_product`) or "auto" (dense up to :data:`DENSE_MAX_NODES` free nodes).
        tol: Lanczos relative residual; ``omega**2`` is then within ``tol`` (relative) of an
            eigenvalue and never above the largest (so omega within tol/2).
        seed: Lanczos start vector.
        barrier: K with the cells' barrier envelope (:func:`stiffness_product`).
    """
    free, s = _free_scaling(system)
    if len(free) == 0:
        return ExactFrequency(0.0, -1, -1, np.zeros((system.count, 3)), "dense", 0.0)
    if method == "auto":
        method = "dense" if len(free) <= DENSE_MAX_NODES else "lanczos"
    if method == "dense":
        lam, vec = np.linalg.eigh(_mass_normalised(system, barrier))
        return _describe(system, float(lam[-1]), vec[:, -1], "dense", 1e-12)
    if method != "lanczos":
        raise ValueError(f"exact_frequency: method {method!r}; expected auto, dense or lanczos")

    def matvec(q: np.ndarray) -> np.ndarray:
        dx = np.zeros((system.count, 3))
        dx[free] = (s * q).reshape(-1, 3)
        return s * stiffness_product(system, dx, barrier=barrier)[free].ravel()

    theta, q, rel = _lanczos_top(matvec, 3 * len(free), tol, np.random.default_rng(seed))
    return _describe(system, theta, q, "lanczos", rel)


# --------------------------------------------------------------------------------------------
# Analytic limits on the scalar test equation
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ModalDamping:
    """Damping per mode, ``g(w) = alpha + beta w^2`` (1/s) in ``x'' = -w^2 x - g x'``.

    Attributes:
        alpha: (lo, hi) of ``(velocity_damping + wind_drag) / m + mass_damping`` over the free nodes, 1/s.
        beta: (lo, hi) of ``c_s / k_s`` over the springs with k > 0, s (lo 0 when the cells'
            volumetric term, which is not damped, adds stiffness).
        proportional: True when both ranges are single values (Rayleigh damping: the modes of
            the undamped system stay uncoupled and the limits are exact).
    """

    alpha: tuple[float, float] = (0.0, 0.0)
    beta: tuple[float, float] = (0.0, 0.0)

    @property
    def proportional(self) -> bool:
        return self.alpha[0] == self.alpha[1] and self.beta[0] == self.beta[1]

    @property
    def undamped(self) -> bool:
        return max(self.alpha[1], self.beta[1]) == 0.0

    def corners(self) -> list[tuple[float, float]]:
        """The distinct (alpha, beta) combinations the limits are minimised over."""
        return sorted({(a, b) for a in self.alpha for b in self.beta})


def modal_damping(system: SpringSystem, *, barrier: bool = False) -> ModalDamping:
    """The (alpha, beta) ranges of ``system`` (see :class:`ModalDamping`); ``barrier``: of the
    stiffness with the terms' envelopes (:func:`stiffness_product`), which beta does not damp."""
    free = ~system.fixed
    a = ((system.velocity_damping + system.wind_drag) / system.mass[free] + system.mass_damping
         if free.any() else np.zeros(1))
    k = system.stiffness > 0
    b = system.damping[k] / system.stiffness[k] if k.any() else np.zeros(1)
    if any(t.frequency_terms(system.rest_positions, barrier=barrier).any() for t in system.terms):
        b = np.append(b, 0.0)  # the physics terms' stiffness, which Rayleigh beta does not damp
    return ModalDamping((float(a.min()), float(a.max())), (float(b.min()), float(b.max())))
