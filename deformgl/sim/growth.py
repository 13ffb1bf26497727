"""Stability limits of the five integrators: analytic bounds, exact frequency, measured limit;
this module measures them and prints the table (``python -m deformgl.sim.growth``).

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
   (:func:`deformgl.sim.springs.max_angular_frequency`). Costs one pass over the springs and is
   conservative (never above the exact limit under the modal-damping model below), so it is what
   :func:`~deformgl.sim.limits.check_dt` uses for large systems.
2. *Exact limit*: from the spectrum of ``M^-1 K`` at rest (``K`` the 3N x 3N stiffness matrix,
   one block ``k u u^T`` per spring, fixed nodes removed). Dense ``eigh`` up to
   :data:`~deformgl.sim.spectrum.DENSE_MAX_NODES` free nodes; above, Lanczos on the sparse product (NumPy only).
3. *Measured limit*: bisection on dt of long float64 runs of :func:`deformgl.sim.integrators.step`
   (:func:`measured_limit`).

Damping model. Each mode is the scalar test equation ``x'' = -w^2 x - g(w) x'`` with
``g(w) = alpha + beta w^2``: ``alpha = (velocity_damping + wind_drag)/m + mass_damping`` (mass-proportional),
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

The analysis is split by what it does: :mod:`deformgl.sim.spectrum` (the linearised system, its
spectrum and the damping model), :mod:`deformgl.sim.limits` (the limits and the dt check) and
this module (the growth rate of long float64 runs, the measured limit by bisection and the
stability table of the standard systems).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from deformgl.grid.nodes import NodeGrid
from deformgl.sim.integrators import EXPLICIT_INTEGRATORS, initial_state, step
from deformgl.sim.limits import exact_limit, gershgorin_limit
from deformgl.sim.spectrum import _BLOW_UP, _rest_directions, exact_frequency
from deformgl.sim.springs import SpringSystem, cloth, from_grid, max_angular_frequency




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
    terms = sum((np.array([float(np.einsum("nk,nk->", d, term.dt_product(system.rest_positions, d))) for d in dx])
                 for term in system.terms), np.zeros(len(dx)))
    return stretch ** 2 @ system.stiffness + kinetic + terms


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
    """Run ``steps`` steps of :func:`deformgl.sim.integrators.step` from the rest state displaced
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
    opts: dict[str, Any] = dict(k_structural=100.0, k_shear=50.0, k_flexion=20.0, mass=0.01,
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
                    integrators: tuple[str, ...] = EXPLICIT_INTEGRATORS,
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


if __name__ == "__main__":  # python -m deformgl.sim.growth: the table of docs/PERFORMANCE.md
    print(format_stability(stability_table()))
