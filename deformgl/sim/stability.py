"""Stability limits of the five integrators: analytic bounds, exact frequency, measured limit.

Movania & Feng 2012 (section 3) compare explicit Euler, semi-implicit ("implicit") Euler,
midpoint, RK4 and Verlet; their step-size limits follow from the highest angular frequency w of
the linearised system (docs/EQUATIONS.md, "Stability"):

* semi-implicit Euler and position Verlet: ``dt <= 2/w``;
* RK4: ``dt <= 2 sqrt(2)/w`` (2.83/w; ``|R(iy)|^2 = 1 - y^6/72 + y^8/576 <= 1 <=> y^2 <= 8``);
* forward Euler (``|1 + iy| > 1``) and midpoint (``|1 + iy - y^2/2|^2 = 1 + y^4/4 > 1``): no dt
  at all without damping. With damping they have a finite limit (forward Euler with
  ``x'' = -w^2 x - g x'``, g < 2w: ``dt <= g / w^2``).

Three numbers per integrator:

1. *Gershgorin limit*: from ``w_max^2 <= max_i 2 sum_j k_ij / m_i``
   (:func:`deformgl.springs.max_angular_frequency`). Costs one pass over the springs and is
   conservative (never above the exact limit under the modal-damping model below), so it is what
   :func:`check_dt` uses for large systems.
2. *Exact limit*: from the spectrum of ``M^-1 K`` at rest (``K`` the 3N x 3N stiffness matrix,
   one block ``k u u^T`` per spring, fixed nodes removed). Dense ``eigh`` up to
   :data:`DENSE_MAX_NODES` free nodes; above, Lanczos on the sparse product (NumPy only).
3. *Measured limit*: bisection on dt of long float64 runs of :func:`deformgl.integrators.step`
   (:func:`measured_limit`).

Damping model. Each mode is the scalar test equation ``x'' = -w^2 x - g(w) x'`` with
``g(w) = alpha + beta w^2``: ``alpha = (velocity_damping + wind_drag)/m`` (mass-proportional),
``beta = c_s/k_s`` (spring damping, stiffness-proportional). That is exact (Rayleigh damping)
when the free masses are equal and ``c_s/k_s`` is the same for every spring; otherwise the limit
is the smallest over the corners of the (alpha, beta) ranges and flagged ``proportional=False``.
The one-step map of each mode is the integrator's amplification: ``R(z)`` at the eigenvalues
``z = dt lambda``, ``lambda = (-g +- sqrt(g^2 - 4 w^2))/2``, for the Runge-Kutta family
(``1 + z``, ``1 + z + z^2/2``, ``1 + z + z^2/2 + z^3/6 + z^4/24``), and the 2x2 matrix with
trace ``2 - w^2 dt^2 - g dt`` and determinant ``1 - g dt`` for semi-implicit Euler and for
Verlet (whose damping sees the backward-difference velocity, as ``integrators.py``). A mode's
limit is the smallest dt at which the spectral radius exceeds 1 (islands of stability at larger
dt are ignored); limits below 1e-3 / max(w, g) are reported as 0 (unusable).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from deformgl.sim.integrators import INTEGRATORS, initial_state, step
from deformgl.sim.springs import SpringSystem, cloth, from_grid, max_angular_frequency
from deformgl.grid.nodes import NodeGrid

__all__ = ["DENSE_MAX_NODES", "ExactFrequency", "ModalDamping", "AnalyticLimit", "DtLimit",
           "DtRefusal", "GrowthFit", "MeasuredLimit", "StabilityRow", "stiffness_product",
           "stiffness_matrix", "exact_frequency", "modal_frequencies", "modal_damping",
           "spectral_radius", "mode_limit", "analytic_limit", "gershgorin_limit", "exact_limit",
           "dt_limit", "check_dt", "require_stable_dt", "growth_rate", "measured_limit",
           "standard_systems", "stability_table", "format_stability"]

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
_FORMULA = {"verlet": "2/w", "semi-implicit": "2/w", "rk4": "2.83/w"}


# --------------------------------------------------------------------------------------------
# The linearised system: K at rest, M^-1 K spectrum
# --------------------------------------------------------------------------------------------

def _rest_directions(system: SpringSystem) -> np.ndarray:
    """(S, 3) unit vector of each spring at rest (0 for a zero-length spring, as ``forces``)."""
    d = system.rest_positions[system.i] - system.rest_positions[system.j]
    length = np.linalg.norm(d, axis=1)
    return d / np.where(length > 0, length, 1.0)[:, None]


def stiffness_product(system: SpringSystem, dx: np.ndarray) -> np.ndarray:
    """``K dx`` for displacements dx (N, 3): per spring ``k u (u . (dx_i - dx_j))`` on i, minus on j.

    K is the stiffness matrix at the rest state, where the geometric term ``k (1 - L/|d|)``
    vanishes, so each spring contributes the block ``k u u^T`` (the linearisation of Movania &
    Feng 2012 eq. 2, ``F = k (L - |d|) d/|d|``). Returns (N, 3); fixed nodes are not masked.
    """
    u = _rest_directions(system)
    p = system.stiffness * np.einsum("sk,sk->s", dx[system.i] - dx[system.j], u)
    f = p[:, None] * u
    n = system.count
    ends = np.concatenate([system.i, system.j])
    signed = np.concatenate([f, -f])
    return np.stack([np.bincount(ends, weights=signed[:, c], minlength=n) for c in range(3)],
                    axis=1)


def stiffness_matrix(system: SpringSystem) -> np.ndarray:
    """Dense (3N, 3N) stiffness matrix K at rest (blocks ``+-k u u^T``), fixed nodes included."""
    n = system.count
    u = _rest_directions(system)
    blocks = system.stiffness[:, None, None] * u[:, :, None] * u[:, None, :]   # (S, 3, 3)
    k4 = np.zeros((n, n, 3, 3))
    np.add.at(k4, (system.i, system.i), blocks)
    np.add.at(k4, (system.j, system.j), blocks)
    np.add.at(k4, (system.i, system.j), -blocks)
    np.add.at(k4, (system.j, system.i), -blocks)
    return k4.transpose(0, 2, 1, 3).reshape(3 * n, 3 * n)


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


def _mass_normalised(system: SpringSystem) -> np.ndarray:
    """Dense ``M^-1/2 K M^-1/2`` over the free degrees of freedom."""
    free, s = _free_scaling(system)
    dof = (3 * free[:, None] + np.arange(3)).ravel()
    k = stiffness_matrix(system)[np.ix_(dof, dof)]
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


def modal_frequencies(system: SpringSystem) -> tuple[np.ndarray, np.ndarray]:
    """All angular frequencies (ascending, rad/s) and mass-normalised modes (columns), dense.

    ``eigh(M^-1/2 K M^-1/2)``: the undamped linearised system ``M x'' = -K x`` has modes
    ``x = M^-1/2 q`` with ``w^2`` the eigenvalues. Only for small systems (3N x 3N dense).
    """
    lam, vec = np.linalg.eigh(_mass_normalised(system))
    return np.sqrt(np.clip(lam, 0.0, None)), vec


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
                    seed: int = 0) -> ExactFrequency:
    """Largest eigenvalue of ``M^-1 K`` at rest over the free nodes, as an angular frequency.

    Args:
        system: the spring system (its rest state; gravity and damping do not enter).
        method: "dense" (``eigh`` of ``M^-1/2 K M^-1/2``), "lanczos" (sparse products only,
            :func:`stiffness_product`) or "auto" (dense up to :data:`DENSE_MAX_NODES` free nodes).
        tol: Lanczos relative residual; ``omega**2`` is then within ``tol`` (relative) of an
            eigenvalue and never above the largest (so omega within tol/2).
        seed: Lanczos start vector.
    """
    free, s = _free_scaling(system)
    if len(free) == 0:
        return ExactFrequency(0.0, -1, -1, np.zeros((system.count, 3)), "dense", 0.0)
    if method == "auto":
        method = "dense" if len(free) <= DENSE_MAX_NODES else "lanczos"
    if method == "dense":
        lam, vec = np.linalg.eigh(_mass_normalised(system))
        return _describe(system, float(lam[-1]), vec[:, -1], "dense", 1e-12)
    if method != "lanczos":
        raise ValueError(f"exact_frequency: method {method!r}; expected auto, dense or lanczos")

    def matvec(q: np.ndarray) -> np.ndarray:
        dx = np.zeros((system.count, 3))
        dx[free] = (s * q).reshape(-1, 3)
        return s * stiffness_product(system, dx)[free].ravel()

    theta, q, rel = _lanczos_top(matvec, 3 * len(free), tol, np.random.default_rng(seed))
    return _describe(system, theta, q, "lanczos", rel)


# --------------------------------------------------------------------------------------------
# Analytic limits on the scalar test equation
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ModalDamping:
    """Damping per mode, ``g(w) = alpha + beta w^2`` (1/s) in ``x'' = -w^2 x - g x'``.

    Attributes:
        alpha: (lo, hi) of ``(velocity_damping + wind_drag) / m`` over the free nodes, 1/s.
        beta: (lo, hi) of ``c_s / k_s`` over the springs with k > 0, s.
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


def modal_damping(system: SpringSystem) -> ModalDamping:
    """The (alpha, beta) ranges of ``system`` (see :class:`ModalDamping`)."""
    free = ~system.fixed
    a = (system.velocity_damping + system.wind_drag) / system.mass[free] if free.any() \
        else np.zeros(1)
    k = system.stiffness > 0
    b = system.damping[k] / system.stiffness[k] if k.any() else np.zeros(1)
    return ModalDamping((float(a.min()), float(a.max())), (float(b.min()), float(b.max())))


def spectral_radius(integrator: str, omega: np.ndarray | float, gamma: np.ndarray | float,
                    dt: np.ndarray | float) -> np.ndarray:
    """Spectral radius of one step of ``integrator`` on ``x'' = -w^2 x - g x'`` (broadcasts).

    Runge-Kutta family: ``max |R(dt lambda)|`` over ``lambda = (-g +- sqrt(g^2 - 4 w^2)) / 2``;
    semi-implicit Euler and Verlet: the roots of ``mu^2 - (2 - w^2 dt^2 - g dt) mu + (1 - g dt)``
    (semi-implicit: the matrix ``[[1 - w^2 dt^2, dt (1 - g dt)], [-w^2 dt, 1 - g dt]]`` on
    (x, v); Verlet: ``x' = (2 - w^2 dt^2 - g dt) x - (1 - g dt) x_prev``, velocity
    ``(x - x_prev)/dt`` as ``integrators.py``).
    """
    w, g, h = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in
                                    (omega, gamma, dt)))
    if integrator in ("semi-implicit", "verlet"):
        tr = 2.0 - (w * h) ** 2 - g * h
        det = 1.0 - g * h
        root = np.sqrt(tr.astype(complex) ** 2 - 4.0 * det)
        return np.maximum(np.abs(tr + root), np.abs(tr - root)) / 2.0
    if integrator not in _RK_POLY:
        raise ValueError(f"unknown integrator {integrator!r}; expected one of "
                         f"{', '.join(INTEGRATORS)}")
    root = np.sqrt(g.astype(complex) ** 2 - 4.0 * w ** 2)
    radius = np.zeros(w.shape)
    for lam in ((-g + root) / 2.0, (-g - root) / 2.0):
        z = h * lam
        r = np.zeros(z.shape, complex)
        for c in reversed(_RK_POLY[integrator]):  # Horner
            r = r * z + c
        radius = np.maximum(radius, np.abs(r))
    return radius


def mode_limit(integrator: str, omega: np.ndarray | float,
               gamma: np.ndarray | float) -> np.ndarray:
    """Largest dt with spectral radius <= 1 for every smaller dt, per mode (vectorised).

    Scans ``y = dt max(w, g)`` geometrically on [1e-3, 20] for the first unstable point, then
    bisects to 1e-13 relative. 0: unstable already at y = 1e-3 (e.g. forward Euler and midpoint
    undamped, ``|R(iy)| > 1`` for every y > 0, set in closed form since ``|R(iy)| - 1`` is
    below roundoff at small y for midpoint); inf: stable on the whole scan (w = g = 0).
    """
    w, g = np.broadcast_arrays(np.atleast_1d(np.asarray(omega, float)),
                               np.atleast_1d(np.asarray(gamma, float)))
    scale = np.maximum(w, g)
    out = np.full(w.shape, np.inf)
    live = scale > 0
    wl, gl, sl = w[live], g[live], scale[live]
    y = np.geomspace(_Y_MIN, _Y_MAX, 2000)
    bad = spectral_radius(integrator, wl[:, None], gl[:, None], y[None, :] / sl[:, None]) \
        > 1.0 + _RADIUS_TOL
    first = np.where(bad.any(axis=1), bad.argmax(axis=1), -1)
    limit = np.full(wl.shape, np.inf)
    limit[first == 0] = 0.0
    mid = first > 0
    lo, hi = y[first[mid] - 1] / sl[mid], y[first[mid]] / sl[mid]
    for _ in range(60):
        c = 0.5 * (lo + hi)
        unstable = spectral_radius(integrator, wl[mid], gl[mid], c) > 1.0 + _RADIUS_TOL
        hi, lo = np.where(unstable, c, hi), np.where(unstable, lo, c)
    limit[mid] = lo
    if integrator in ("euler", "midpoint"):  # |R(iy)| > 1 for every y > 0 (closed form)
        limit[(gl == 0.0) & (wl > 0.0)] = 0.0
    out[live] = limit
    return out


@dataclass(frozen=True)
class AnalyticLimit:
    """The largest stable dt of an integrator for a set of modal frequencies.

    Attributes:
        integrator: one of ``INTEGRATORS``.
        dt: s; 0.0 when no dt is stable (forward Euler and midpoint undamped).
        omega: rad/s, the frequency of the mode that sets the limit.
        gamma: 1/s, that mode's damping ``g``.
        formula: "2/w", "2.83/w", "damped |R| <= 1" or "unstable for every dt (undamped)".
        proportional: False when the damping is not proportional (limit approximate).
    """

    integrator: str
    dt: float
    omega: float
    gamma: float
    formula: str
    proportional: bool = True


def _formula(integrator: str, damping: ModalDamping, dt: float) -> str:
    if dt == 0.0:
        return "unstable for every dt (undamped)" if damping.undamped else \
            "unstable for every dt (too little damping)"
    return _FORMULA[integrator] if damping.undamped else "damped |R| <= 1"


def analytic_limit(integrator: str, omegas: np.ndarray | float,
                   damping: ModalDamping = ModalDamping()) -> AnalyticLimit:
    """Smallest :func:`mode_limit` over the given modal frequencies and damping corners.

    Undamped: semi-implicit and Verlet ``2/w``, RK4 ``2 sqrt(2)/w``, Euler and midpoint 0
    (closed forms, Movania & Feng 2012 section 3; STYLE.md), w the largest of ``omegas``.
    """
    if integrator not in INTEGRATORS:
        raise ValueError(f"unknown integrator {integrator!r}")
    w = np.atleast_1d(np.asarray(omegas, float))
    best = (np.inf, 0.0, 0.0)
    for a, b in damping.corners():
        g = a + b * w ** 2
        lim = mode_limit(integrator, w, g)
        k = int(np.argmin(lim))
        if lim[k] < best[0] or (lim[k] == best[0] and w[k] > best[1]):
            best = (float(lim[k]), float(w[k]), float(g[k]))
    return AnalyticLimit(integrator, best[0], best[1], best[2],
                         _formula(integrator, damping, best[0]), damping.proportional)


def gershgorin_limit(system: SpringSystem, integrator: str) -> AnalyticLimit:
    """Limit from the Gershgorin bound ``w_max^2 <= max_i 2 sum_j k_ij / m_i``.

    Every mode lies in [0, w_G], so the limit is minimised over 257 frequencies evenly spaced on
    that interval (with damping the smallest limit need not be at the top frequency): under the
    modal damping model it is never above the exact limit.
    """
    wg = max_angular_frequency(system).omega
    return analytic_limit(integrator, np.linspace(0.0, wg, 257), modal_damping(system))


def exact_limit(system: SpringSystem, integrator: str, *,
                method: str = "auto", tol: float = 1e-10) -> tuple[AnalyticLimit, ExactFrequency]:
    """Limit from the exact spectrum: every mode when dense (one ``eigh``), the band
    [0, w_max] when Lanczos (relative residual ``tol``) and damped (conservative as
    :func:`gershgorin_limit`)."""
    damping = modal_damping(system)
    free = int((~system.fixed).sum())
    if free and (method == "dense" or (method == "auto" and free <= DENSE_MAX_NODES)):
        lam, vec = np.linalg.eigh(_mass_normalised(system))
        top = _describe(system, float(lam[-1]), vec[:, -1], "dense", 1e-12)
        omegas = np.unique(np.round(np.sqrt(np.clip(lam, 0.0, None)), 9))
    else:
        top = exact_frequency(system, method=method, tol=tol)
        omegas = np.linspace(0.0, top.omega, 257)
    if damping.undamped:
        omegas = np.array([top.omega])  # every limit is c/w: the top mode sets it
    return analytic_limit(integrator, omegas, damping), top


# --------------------------------------------------------------------------------------------
# Scene validation
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class DtLimit:
    """The largest stable dt of ``integrator`` on a system, and what sets it.

    Attributes:
        integrator: one of ``INTEGRATORS``.
        dt: s (0.0: no dt is stable).
        omega: rad/s, the frequency used (Gershgorin bound or exact).
        bound: "gershgorin" (conservative: never accepts an unstable dt), "exact" (dense) or
            "lanczos" (the exact top frequency estimated, the limit kept LANCZOS_MARGIN below).
        formula: see :class:`AnalyticLimit`.
        node: the node that sets omega (Gershgorin: largest ``2 sum k / m``; exact: the node
            moving most in the top mode).
        spring: the spring that sets it (Gershgorin: stiffest at the node; exact: most strain
            energy in the mode); -1 if none.
        stiffness: k of that spring, N/m.
        mass: m of that node, kg.
    """

    integrator: str
    dt: float
    omega: float
    bound: str
    formula: str
    node: int
    spring: int
    stiffness: float
    mass: float

    def message(self, dt: float) -> str:
        """Why ``dt`` is refused, e.g. ``dt 0.004 s is above the verlet limit 0.0031 s = 2/w,
        w = 645 rad/s set by node 17 (spring 40, k = 500 N/m, m = 0.01 kg)``."""
        where = (f"w = {self.omega:.4g} rad/s set by node {self.node} (spring {self.spring}, "
                 f"k = {self.stiffness:.4g} N/m, m = {self.mass:.4g} kg; {self.bound} bound)")
        if self.dt == 0.0:
            return (f"dt {dt:.4g} s: {self.integrator} is {self.formula}: its growth factor "
                    f"exceeds 1 at every dt; {where}. Add damping (velocity_damping or spring "
                    f"damping) or use semi-implicit, verlet or rk4")
        return (f"dt {dt:.4g} s is above the {self.integrator} limit {self.dt:.4g} s = "
                f"{self.formula}, {where}")


@dataclass(frozen=True)
class DtRefusal:
    """A refused dt: the limit it exceeds and the message for the user."""

    dt: float
    limit: DtLimit
    message: str


#: Relative residual of the Lanczos estimate that :func:`check_dt` uses on systems too big for a
#: dense solve, and the margin below its limit that a dt must keep: the estimate of w_max is a
#: Rayleigh quotient, never above it, so the limit it gives is never below the true one.
LANCZOS_TOL = 1e-4
LANCZOS_MARGIN = 1e-3


def _dt_limit(system: SpringSystem, integrator: str, bound: str) -> DtLimit:
    if bound == "gershgorin":
        lim = gershgorin_limit(system, integrator)
        fb = max_angular_frequency(system)
        omega, node, spring = fb.omega, fb.node, fb.spring
    else:
        if bound == "lanczos":
            lim, top = exact_limit(system, integrator, method="lanczos", tol=LANCZOS_TOL)
            if not top.tolerance <= LANCZOS_TOL:  # did not converge: its w may be too low
                return _dt_limit(system, integrator, "gershgorin")
            lim = dataclasses.replace(lim, dt=lim.dt * (1.0 - LANCZOS_MARGIN),
                                      formula=f"{lim.formula} less {LANCZOS_MARGIN:.1%} (w estimated)")
        else:
            lim, top = exact_limit(system, integrator)
        omega, node, spring = top.omega, top.node, top.spring
    k = float(system.stiffness[spring]) if spring >= 0 else 0.0
    m = float(system.mass[node]) if node >= 0 else 0.0
    return DtLimit(integrator, lim.dt, omega, bound, lim.formula, node, spring, k, m)


def dt_limit(system: SpringSystem, integrator: str, *, exact: bool | None = None,
             exact_up_to: int = 300) -> DtLimit:
    """The dt limit with the exact spectrum (``exact`` True, or None and at most ``exact_up_to``
    free nodes) or the Gershgorin bound."""
    if exact is None:
        exact = int((~system.fixed).sum()) <= exact_up_to
    return _dt_limit(system, integrator, "exact" if exact else "gershgorin")


def check_dt(system: SpringSystem, integrator: str, dt: float, *,
             exact_up_to: int = 300, lanczos_up_to: int = 30000) -> DtRefusal | None:
    """None when ``dt`` is stable for ``integrator`` on ``system``, else the refusal.

    The cheap Gershgorin limit is tried first; a dt at or below it is accepted (it is
    conservative). A dt above it is judged on the exact spectrum when the system has at most
    ``exact_up_to`` free nodes (dense eigen solve, ~0.3 s for 300 nodes), on a Lanczos estimate
    of its top (relative residual :data:`LANCZOS_TOL`, a dt must stay :data:`LANCZOS_MARGIN`
    below the limit; ~1 s for 20k nodes) up to ``lanczos_up_to``, else refused on the
    Gershgorin bound, whose message says so.

    Forward Euler and midpoint on an undamped system are always refused (no dt is stable: growth
    per step ``sqrt(1 + (w dt)^2)`` resp. ``sqrt(1 + (w dt)^4/4)``); with damping they get their
    damped limit, like the other three.
    """
    if not dt > 0:
        raise ValueError(f"check_dt: dt must be > 0, got {dt}")
    cheap = _dt_limit(system, integrator, "gershgorin")
    if dt <= cheap.dt:
        return None
    limit = cheap
    free = int((~system.fixed).sum())
    if free <= lanczos_up_to:
        limit = _dt_limit(system, integrator, "exact" if free <= exact_up_to else "lanczos")
        if dt <= limit.dt:
            return None
    return DtRefusal(dt, limit, limit.message(dt))


def require_stable_dt(system: SpringSystem, integrator: str, dt: float, **options: int) -> None:
    """Raise :class:`deformgl.errors.SimulationError` with the message when ``check_dt`` refuses."""
    refusal = check_dt(system, integrator, dt, **options)
    if refusal is not None:
        from deformgl.errors import SimulationError
        raise SimulationError(refusal.message)


# --------------------------------------------------------------------------------------------
# Measured limit
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class GrowthFit:
    """Growth of a run started in one mode (:func:`growth_rate`).

    Attributes:
        rate: ln of the spectral radius of the one-step map on the excited mode, estimated from
            the run (least-squares fit of ``s_{n+1} = t s_n - d s_{n-1}`` to the modal
            coordinate; radius = the largest root of ``mu^2 - t mu + d``).
        envelope_rate: slope per step of ln(window maximum of the amplitude ``sqrt(E)``),
            ``E = dx^T K dx + v^T M v`` (whole state, catches growth outside the mode).
        steps: steps run (fewer when it blew up).
        blew_up: non-finite state or a node displaced by more than 1e3 times the start.
        stable: not blown up, ``rate <= tol`` and ``envelope_rate <= envelope_tol``.
        peak: the largest amplitude ``sqrt(E)`` seen, relative to the start.
    """

    rate: float
    envelope_rate: float
    steps: int
    blew_up: bool
    stable: bool
    peak: float

    @property
    def factor(self) -> float:
        """Growth factor per step, ``exp(rate)``."""
        return math.exp(min(self.rate, 700.0))


def _energies(system: SpringSystem, dx: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``dx^T K dx + v^T M v`` over the free nodes (twice the linearised energy), per state.

    dx, v: (T, N, 3). Fixed nodes have dx = v = 0, so they add nothing.
    """
    u = _rest_directions(system)
    stretch = np.einsum("tsk,sk->ts", dx[:, system.i] - dx[:, system.j], u)
    kinetic = np.einsum("n,tnk,tnk->t", np.where(system.fixed, 0.0, system.mass), v, v)
    return stretch ** 2 @ system.stiffness + kinetic


def _recurrence_rate(s: np.ndarray) -> float:
    """ln spectral radius of a 2x2 linear one-step map from a sequence of one coordinate.

    Every component of a 2x2 linear map's orbit obeys ``s_{n+1} = t s_n - d s_{n-1}``
    (Cayley-Hamilton; t the trace, d the determinant). Samples below 1e-7 of the largest are
    dropped (roundoff); with fewer than 8 left the mode decayed (rate from the decay).
    """
    big = np.abs(s) > 1e-7 * np.abs(s).max()
    keep = big[2:] & big[1:-1] & big[:-2]
    if keep.sum() < 8:
        last = np.nonzero(big)[0].max()
        return math.log(max(abs(s[last]) / abs(s[0]), 1e-300)) / max(last, 1) if last else -1.0
    a = np.stack([s[1:-1][keep], -s[:-2][keep]], axis=1)
    (t, d), *_ = np.linalg.lstsq(a, s[2:][keep], rcond=None)
    root = np.sqrt(complex(t * t - 4.0 * d))
    return math.log(max(abs(t + root), abs(t - root)) / 2.0)


def _envelope_rate(amplitude: np.ndarray, window: int) -> float:
    """Slope per step of ln(window maxima), the first window (start transient) left out."""
    m = len(amplitude) // window
    if m < 4:
        return 0.0
    peaks = amplitude[:m * window].reshape(m, window).max(axis=1)[1:]
    centres = (np.arange(1, m) + 0.5) * window
    logs = np.log(np.maximum(peaks, 1e-300))
    return float(np.polyfit(centres, logs, 1)[0])


def growth_rate(system: SpringSystem, integrator: str, dt: float, *, steps: int = 2000,
                mode: np.ndarray | None = None, amplitude: float = 1e-6, tol: float = 1e-7,
                envelope_tol: float = 1e-3) -> GrowthFit:
    """Run ``steps`` steps of :func:`deformgl.integrators.step` from the rest state displaced
    along ``mode`` and judge growth by the spectral radius, not by an energy threshold.

    The start is one mode (default: the exact top mode) scaled so its largest node moves
    ``amplitude * spacing``, velocity 0: a pure mode makes the measurement sharp (no other
    mode's transient, linear regime since amplitude^2 ~ 1e-12). Its modal coordinate
    ``s_n = mode^T M dx_n`` follows a 2-term recurrence whose fitted roots give the one-step
    spectral radius to ~1e-10, so semi-implicit Euler's bounded oscillation of energy (shadow
    energy) reads exactly 1 below 2/w and > 1 above. ``tol`` = 1e-8 per step is far above that
    noise and below midpoint's growth at 0.05/w (7.8e-7). The envelope check over 50 windows
    guards the rest of the state: a growth factor 1.002 per step multiplies the amplitude by
    e^4 = 55 over 2000 steps, a fitted slope of 0.002 against ``envelope_tol`` = 1e-3, while a
    bounded oscillation of range ln(F) biases that slope by about ln(F) P / N^2 (period P).
    """
    if np.any(system.gravity != 0) or np.any(system.wind != 0):
        raise ValueError("growth_rate: the rest state must be an equilibrium (gravity, wind 0)")
    if mode is None:
        mode = exact_frequency(system).mode
    x0 = system.rest_positions
    weight = np.where(system.fixed, 0.0, system.mass)[:, None] * mode
    reach = amplitude * system.spacing
    state = initial_state(system, dt, x=x0 + reach * mode)
    dx = np.zeros((steps + 1,) + x0.shape)
    v = np.zeros_like(dx)
    dx[0], v[0] = state.x - x0, state.v
    n, blew_up = 0, False
    for n in range(1, steps + 1):
        state = step(system, integrator, state, dt, (n - 1) * dt)
        dx[n], v[n] = state.x - x0, state.v
        if not np.all(np.isfinite(dx[n])) or np.abs(dx[n]).max() > _BLOW_UP * reach:
            blew_up = True
            break
    last = n - 1 if blew_up else n
    amp = np.sqrt(_energies(system, dx[:last + 1], v[:last + 1]))
    amp /= amp[0]
    s = np.einsum("tnk,nk->t", dx[:last + 1], weight)
    rate = _recurrence_rate(s) if last >= 3 else math.inf
    if blew_up:  # grew by _BLOW_UP in n steps: at least that rate
        rate = max(rate, math.log(_BLOW_UP) / n)
    env = _envelope_rate(amp, max(steps // 50, 10))
    stable = (not blew_up) and rate <= tol and env <= envelope_tol
    return GrowthFit(rate, env, n, blew_up, stable, float(amp.max()))


@dataclass(frozen=True)
class MeasuredLimit:
    """Largest stable dt found by bisection (:func:`measured_limit`).

    Attributes:
        dt: s, the geometric mean of the bracket (0.0: unstable at the smallest dt tried).
        stable_dt: largest dt classified stable.
        unstable_dt: smallest dt classified unstable.
        runs: number of runs.
    """

    dt: float
    stable_dt: float
    unstable_dt: float
    runs: int


def measured_limit(system: SpringSystem, integrator: str, guess: float, *,
                   rel_precision: float = 0.002, steps: int = 2000, bracket: float = 1.015,
                   mode: np.ndarray | None = None, floor: float = 0.0) -> MeasuredLimit:
    """Bisection on dt (relative bracket width <= ``rel_precision``) of :func:`growth_rate`.

    Starts from [guess / bracket, 0.997 guess * bracket] and widens by ``bracket**2`` until the lower
    end is stable and the upper one unstable. Returns dt 0 when the lower end falls below
    ``floor`` still unstable (e.g. forward Euler undamped).
    """
    if mode is None:
        mode = exact_frequency(system).mode
    runs = 0

    def stable(dt: float) -> bool:
        nonlocal runs
        runs += 1
        return growth_rate(system, integrator, dt, steps=steps, mode=mode).stable

    lo, hi = guess / bracket, guess * bracket * 0.997  # off-centre: no run lands on guess
    while not stable(lo):
        hi, lo = lo, lo / bracket ** 2
        if lo < floor or runs > 40:
            return MeasuredLimit(0.0, 0.0, hi, runs)
    while stable(hi):
        lo, hi = hi, hi * bracket ** 2
        if runs > 40:
            return MeasuredLimit(math.inf, lo, math.inf, runs)
    while hi / lo > 1.0 + rel_precision:
        mid = math.sqrt(lo * hi)
        if stable(mid):
            lo = mid
        else:
            hi = mid
    return MeasuredLimit(math.sqrt(lo * hi), lo, hi, runs)


# --------------------------------------------------------------------------------------------
# The table
# --------------------------------------------------------------------------------------------

def standard_systems(damping_ratio: float = 0.1) -> dict[str, SpringSystem]:
    """The table's systems: a 4x4x4 block and a 10x10 cloth, spacing 0.1 m, mass 0.01 kg,
    k = 100 / 50 / 20 N/m (structural / shear / flexion), no gravity, no fixed nodes;
    undamped, and with global damping ``c = 2 zeta m w_max`` (zeta = ``damping_ratio`` on the
    top mode, w_max exact).
    """
    opts = dict(k_structural=100.0, k_shear=50.0, k_flexion=20.0, mass=0.01,
                gravity=(0.0, 0.0, 0.0))
    block = from_grid(NodeGrid(np.zeros(3), 0.1, np.ones((4, 4, 4), bool)), **opts)
    sheet = cloth(10, 10, 0.1, **opts)
    out = {}
    for name, system in (("block 4x4x4", block), ("cloth 10x10", sheet)):
        out[name] = system
        w = exact_frequency(system).omega
        c = 2.0 * damping_ratio * 0.01 * w
        damped = (from_grid(NodeGrid(np.zeros(3), 0.1, np.ones((4, 4, 4), bool)),
                            velocity_damping=c, **opts) if system is block else
                  cloth(10, 10, 0.1, velocity_damping=c, **opts))
        out[f"{name} zeta {damping_ratio:g}"] = damped
    return out


@dataclass(frozen=True)
class StabilityRow:
    """One row of :func:`stability_table` (dt in s; 0.0: no dt is stable)."""

    system: str
    integrator: str
    omega_gershgorin: float
    omega_exact: float
    gershgorin_dt: float
    exact_dt: float
    measured_dt: float
    formula: str
    note: str = ""

    @property
    def ratio(self) -> float:
        """measured / exact (nan when the exact limit is 0)."""
        return self.measured_dt / self.exact_dt if self.exact_dt > 0 else math.nan


def _row(name: str, system: SpringSystem, integrator: str, steps: int) -> StabilityRow:
    g = gershgorin_limit(system, integrator)
    e, top = exact_limit(system, integrator)
    wg = max_angular_frequency(system).omega
    if e.dt == 0.0:
        fit = growth_rate(system, integrator, 0.05 / top.omega, steps=steps, mode=top.mode)
        note = (f"at 0.05/w: growth {fit.factor:.9f}/step, "
                f"{'stable' if fit.stable else 'unstable'}")
        return StabilityRow(name, integrator, wg, top.omega, g.dt, 0.0, 0.0, e.formula, note)
    m = measured_limit(system, integrator, e.dt, steps=steps, mode=top.mode)
    return StabilityRow(name, integrator, wg, top.omega, g.dt, e.dt, m.dt, e.formula,
                        f"{m.runs} runs, stable {m.stable_dt / e.dt:.4f}, "
                        f"unstable {m.unstable_dt / e.dt:.4f} x exact")


def stability_table(systems: dict[str, SpringSystem] | None = None,
                    integrators: tuple[str, ...] = INTEGRATORS,
                    steps: int = 1000) -> list[StabilityRow]:
    """Gershgorin, exact and measured limits of every integrator on every system
    (default :func:`standard_systems`; 20 to 40 s on 2 shared cores).

    Each bisection run has ``steps`` steps: 1000 keep the table fast and still turn a growth of
    1.002 per step into a factor e^2 = 7.4 (envelope slope 0.002 > 1e-3) while the fitted
    spectral radius resolves 1e-7 per step. Forward Euler and midpoint on an undamped system
    have no limit to bisect: their row shows the growth measured at 0.05/w instead.
    """
    systems = standard_systems() if systems is None else systems
    return [_row(name, s, i, steps) for name, s in systems.items() for i in integrators]


def _fmt(dt: float) -> str:
    return "none" if dt == 0.0 else f"{dt * 1e3:.4f} ms"


def format_stability(rows: list[StabilityRow]) -> str:
    """A text table: system | integrator | Gershgorin limit | exact limit | measured |
    measured/exact | note."""
    head = ("system", "integrator", "w_G rad/s", "w rad/s", "Gershgorin", "exact", "measured",
            "meas/exact", "formula / note")
    lines = [head]
    for r in rows:
        ratio = "-" if math.isnan(r.ratio) else f"{r.ratio:.4f}"
        lines.append((r.system, r.integrator, f"{r.omega_gershgorin:.1f}",
                      f"{r.omega_exact:.1f}", _fmt(r.gershgorin_dt), _fmt(r.exact_dt),
                      _fmt(r.measured_dt), ratio, f"{r.formula}; {r.note}"))
    widths = [max(len(line[c]) for line in lines) for c in range(len(head))]
    text = [" | ".join(cell.ljust(wd) for cell, wd in zip(line, widths)).rstrip()
            for line in lines]
    text.insert(1, "-+-".join("-" * wd for wd in widths))
    return "\n".join(text)


if __name__ == "__main__":  # python -m deformgl.sim.stability
    print(format_stability(stability_table()))
