"""Step-size limits of the five integrators (Movania & Feng 2012, section 3): the spectral radius
of each mode's one-step map, the analytic / Gershgorin / exact limits, and :func:`check_dt`.
The model is described in :mod:`deformgl.sim.growth`."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from deformgl.sim.integrators import EXPLICIT_INTEGRATORS, IMPLICIT_INTEGRATORS, STABLE_INTEGRATORS
from deformgl.sim.spectrum import (
    DENSE_MAX_NODES, ExactFrequency, ModalDamping, _FORMULA, _RADIUS_TOL, _RK_POLY, _Y_MAX, _Y_MIN,
    _describe, _mass_normalised, exact_frequency, modal_damping)
from deformgl.sim.springs import SpringSystem, max_angular_frequency
from deformgl.sim.stages import spec
from deformgl.errors import ArgumentError




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
                         f"{', '.join(EXPLICIT_INTEGRATORS)}")
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
    if spec(integrator).limit_factor is None:  # |R(iy)| > 1 for every y > 0 (closed form)
        limit[(gl == 0.0) & (wl > 0.0)] = 0.0
    out[live] = limit
    return out


@dataclass(frozen=True)
class AnalyticLimit:
    """The largest stable dt of an integrator for a set of modal frequencies.

    Attributes:
        integrator: one of ``EXPLICIT_INTEGRATORS``.
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
    if integrator not in EXPLICIT_INTEGRATORS:
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


def gershgorin_limit(system: SpringSystem, integrator: str, *, barrier: bool = False) -> AnalyticLimit:
    """Limit from the Gershgorin bound ``w_max^2 <= max_i 2 sum_j k_ij / m_i``.

    Every mode lies in [0, w_G], so the limit is minimised over 257 frequencies evenly spaced on
    that interval (with damping the smallest limit need not be at the top frequency): under the
    modal damping model it is never above the exact limit. ``barrier``: with the cells' barrier
    envelope (:func:`~deformgl.sim.springs.max_angular_frequency`).
    """
    wg = max_angular_frequency(system, barrier=barrier).omega
    return analytic_limit(integrator, np.linspace(0.0, wg, 257), modal_damping(system, barrier=barrier))


def exact_limit(system: SpringSystem, integrator: str, *, method: str = "auto", tol: float = 1e-10,
                barrier: bool = False) -> tuple[AnalyticLimit, ExactFrequency]:
    """Limit from the exact spectrum: every mode when dense (one ``eigh``), the band
    [0, w_max] when Lanczos (relative residual ``tol``) and damped (conservative as
    :func:`gershgorin_limit`); ``barrier``: of K with the cells' barrier envelope
    (:func:`~deformgl.sim.spectrum.stiffness_product`)."""
    damping = modal_damping(system, barrier=barrier)
    free = int((~system.fixed).sum())
    if free and (method == "dense" or (method == "auto" and free <= DENSE_MAX_NODES)):
        lam, vec = np.linalg.eigh(_mass_normalised(system, barrier))
        top = _describe(system, float(lam[-1]), vec[:, -1], "dense", 1e-12)
        omegas = np.unique(np.round(np.sqrt(np.clip(lam, 0.0, None)), 9))
    else:
        top = exact_frequency(system, method=method, tol=tol, barrier=barrier)
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
        integrator: one of ``EXPLICIT_INTEGRATORS``.
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
        term: the physics term (:attr:`~deformgl.sim.springs.SpringSystem.terms`) that is the
            larger part of the node's stiffness, as its
            :meth:`~deformgl.sim.terms.Term.limit_share` words it (the cells' barrier: "the
            cells' inversion barrier, kappa_b = 2.4e+04 Pa"), else "".
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
    term: str = ""

    def message(self, dt: float) -> str:
        """Why ``dt`` is refused, e.g. ``dt 0.004 s is above the verlet limit 0.0031 s, w = 645
        rad/s at node 17 (spring 40, k = 500 N/m, m = 0.01 kg; exact bound)``; a body whose physics
        term is the larger part of the node's stiffness names it instead of the spring (the
        limit's formula: :attr:`formula`)."""
        if self.term:
            what = self.term
        else:
            what = f"spring {self.spring}, k = {self.stiffness:.4g} N/m"
        where = f"w = {self.omega:.4g} rad/s at node {self.node} ({what}, m = {self.mass:.4g} kg; {self.bound} bound)"
        if self.dt == 0.0:
            return (f"dt {dt:.4g} s: {self.integrator} is {self.formula}: its growth factor "
                    f"exceeds 1 at every dt; {where}. Add damping (velocity_damping or spring "
                    f"damping) or use semi-implicit, verlet or rk4")
        return f"dt {dt:.4g} s is above the {self.integrator} limit {self.dt:.4g} s, {where}"


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
    """The limit on ``bound``'s frequency of the stiffness the run can meet: the rest stiffness
    and, on a body with cells, their inversion barrier at full strength (``barrier=True``: a
    body pressed towards inversion meets it; docs/ACCURACY.md section 7)."""
    if bound == "gershgorin":
        lim = gershgorin_limit(system, integrator, barrier=True)
        fb = max_angular_frequency(system, barrier=True)
        omega, node, spring = fb.omega, fb.node, fb.spring
    else:
        if bound == "lanczos":
            lim, top = exact_limit(system, integrator, method="lanczos", tol=LANCZOS_TOL, barrier=True)
            if not top.tolerance <= LANCZOS_TOL:  # did not converge: its w may be too low
                return _dt_limit(system, integrator, "gershgorin")
            lim = dataclasses.replace(lim, dt=lim.dt * (1.0 - LANCZOS_MARGIN),
                                      formula=f"{lim.formula} less {LANCZOS_MARGIN:.1%} (w estimated)")
        else:
            lim, top = exact_limit(system, integrator, barrier=True)
        omega, node, spring = top.omega, top.node, top.spring
    k = float(system.stiffness[spring]) if spring >= 0 else 0.0
    m = float(system.mass[node]) if node >= 0 else 0.0
    term = ""
    if node >= 0:  # the node's Gershgorin terms: a physics term's against the springs'
        springs = 2.0 * float(system.stiffness[(system.i == node) | (system.j == node)].sum())
        term = next((w for w in (t.limit_share(system.rest_positions, node, springs) for t in system.terms) if w), "")
    return DtLimit(integrator, lim.dt, omega, bound, lim.formula, node, spring, k, m, term)


def _check_arguments(caller: str, system: object, integrator: object) -> None:
    """One-line :class:`~deformgl.errors.ArgumentError` for a system that is not a
    :class:`SpringSystem` or an integrator that is not one of ``INTEGRATORS``."""
    if not isinstance(system, SpringSystem):
        raise ArgumentError(f"{caller}: system: expected a SpringSystem (Body.system, a scene's model), "
                            f"got {type(system).__name__}")
    known = (*EXPLICIT_INTEGRATORS, *IMPLICIT_INTEGRATORS, *STABLE_INTEGRATORS)
    if integrator not in known:
        raise ArgumentError(f"{caller}: integrator: unknown {integrator!r}; expected one of {', '.join(known)}")


def dt_limit(system: SpringSystem, integrator: str, *, exact: bool | None = None,
             exact_up_to: int = 300, lanczos_up_to: int = 30000) -> DtLimit:
    """The dt limit that :func:`check_dt` enforces: of the stiffness the run can meet (the rest
    stiffness and the cells' barrier at full strength, :func:`_dt_limit`), on the exact spectrum
    (``exact`` True, or None and at most ``exact_up_to`` free nodes), its Lanczos estimate (None
    and at most ``lanczos_up_to``; less :data:`LANCZOS_MARGIN`) or the Gershgorin bound (``exact``
    False, or more free nodes). A run at any dt below it with the guard's ``unstable="refuse"``
    does not blow up (tests/test_stability_extremes.py: the hanging cantilevers driven to the
    barrier, at 0.9 of it).

    Raises:
        ArgumentError: an integrator without an explicit dt limit (implicit Euler, XPBD: their
            solve's residual is reported instead) or an unknown one, or a system that is not one.
    """
    _check_arguments("dt_limit", system, integrator)
    if integrator in IMPLICIT_INTEGRATORS or integrator in STABLE_INTEGRATORS:
        raise ArgumentError(f"dt_limit: integrator: {integrator} has no explicit dt limit (only the explicit "
                            f"integrators have one: {', '.join(EXPLICIT_INTEGRATORS)}); check_dt accepts every dt for it")
    if exact is not None:
        return _dt_limit(system, integrator, "exact" if exact else "gershgorin")
    free = int((~system.fixed).sum())
    return _dt_limit(system, integrator, "exact" if free <= exact_up_to else
                     "lanczos" if free <= lanczos_up_to else "gershgorin")


def check_dt(system: SpringSystem, integrator: str, dt: float, *,
             exact_up_to: int = 300, lanczos_up_to: int = 30000) -> DtRefusal | None:
    """None when ``dt`` is stable for ``integrator`` on ``system``, else the refusal.

    The cheap Gershgorin limit is tried first; a dt at or below it is accepted (it is
    conservative). A dt above it is judged on the exact spectrum when the system has at most
    ``exact_up_to`` free nodes (a dense eigen solve), on a Lanczos estimate of its top (relative
    residual :data:`LANCZOS_TOL`, a dt must stay :data:`LANCZOS_MARGIN` below the limit) up to
    ``lanczos_up_to``, else refused on the
    Gershgorin bound, whose message says so.

    Integrators without an explicit limit (``integrators.STABLE_INTEGRATORS``: XPBD) are never
    refused.

    Forward Euler and midpoint on an undamped system are always refused (no dt is stable: growth
    per step ``sqrt(1 + (w dt)^2)`` resp. ``sqrt(1 + (w dt)^4/4)``); with damping they get their
    damped limit, like the other three.
    """
    _check_arguments("check_dt", system, integrator)
    if isinstance(dt, bool) or not isinstance(dt, (int, float, np.number)) or not dt > 0 or not np.isfinite(dt):
        raise ArgumentError(f"check_dt: dt: must be a finite number > 0 s, got {dt!r}")
    if integrator in IMPLICIT_INTEGRATORS or integrator in STABLE_INTEGRATORS:
        return None  # no explicit limit: backward Euler's solve and XPBD's residual are reported instead
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
