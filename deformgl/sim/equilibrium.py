"""When a run has converged: the equilibrium stop, and the paper's displacement stop.

A :class:`ConvergeRule` (a scene's ``[physics.converge]``, the API's ``dg.run(converge=...)``)
says what "converged" means; :meth:`ConvergeRule.monitor` makes the monitor that the one run loop
(:func:`deformgl.sim.run.run`) asks at every check.

``criterion = "equilibrium"`` (the default) is physical: it means the same at every dt,
integrator (implicit Euler and XPBD included), backend and grid resolution. Every ``interval``
seconds of simulated time (``every`` steps, when given) the positions are read back, and with
the last three samples ``x_{k-2}, x_{k-1}, x_k`` (``T`` apart)

* the mean velocity over the last interval ``v_k = (x_k - x_{k-1}) / T`` and the mean
  acceleration ``a_k = (v_k - v_{k-1}) / T`` give each free node's net force ``m_i a_k`` (Newton's
  second law: the momentum change over the interval is the time-averaged net force, contact and
  damping included), and the **force ratio** is the largest net force on a free node over the
  largest applied force on one (``m |g|``, plus its loads' and drags' magnitudes; with none, the
  largest net force measured so far in the run);
* the **energy ratio** is the kinetic energy ``1/2 sum m v_k^2`` over the largest of the run
  so far, or over the springs' elastic energy ``sum 1/2 k (|d| - L)^2`` where that is larger
  (a run that goes on from an equilibrium has no peak of its own to measure against, but its
  stored energy is the scale of its motion);

and the run has converged when both are below ``tolerance`` at ``checks`` consecutive checks, and
no scripted change is still to come (``hold_until``: the last keyframe of a drag or a moving
sphere, the start, end of ramp or stop of a pull: a body at rest before a pull starts is not
done).
Differences over a whole interval, not one step, keep the measure above float32's rounding of the
GPU state (a single step's difference is rounding noise at small dt); on the float32 fragment
backend a 21-node cantilever's noise floor is a force ratio of 2e-4 to 2e-3 at dt 1e-4 to 1e-5 s
(docs/ACCURACY.md, "When a run has converged"). The default ``tolerance`` 0.01 is the one that
stops that cantilever within 0.25 % of its 1 s sag with every integrator that runs it at dt 1e-4
and 1e-5 s (XPBD at 1e-5 s in float64: in float32 its corrections fall below the resolution of
the positions and it never settles, which the stop reports; tests/test_equilibrium.py).

``criterion = "displacement"`` is the paper's per-step test (Movania & Feng 2012, section 4): no
node moved more than ``threshold`` grid spacings in the step ending at a multiple of ``every``
steps, counted on the GPU by an occlusion query (:class:`~deformgl.sim.census.NodeCensus`). It
depends on dt: a smaller step moves less and stops sooner.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from deformgl.sim.simulation import Simulation
from deformgl.sim.springs import SpringSystem
from deformgl.sim.scripted import Drag, Load

__all__ = ["CRITERIA", "DEFAULT_CHECKS", "DEFAULT_INTERVAL", "DEFAULT_TOLERANCE", "ConvergeRule",
           "DisplacementMonitor", "EquilibriumMonitor"]

CRITERIA = ("equilibrium", "displacement")
#: force and energy ratio below which a check counts (meets the cantilever's 1 % test, above)
DEFAULT_TOLERANCE = 0.01
#: simulated seconds between checks (differences over it stay above float32 rounding)
DEFAULT_INTERVAL = 0.02
#: consecutive checks below the tolerance (one alone can fall on an oscillation's turning point)
DEFAULT_CHECKS = 3
#: the displacement criterion's threshold in grid spacings per step, and its steps between checks
DEFAULT_THRESHOLD = 0.001
DEFAULT_DISPLACEMENT_EVERY = 10


@dataclass(frozen=True)
class ConvergeRule:
    """What "converged" means for a run.

    Attributes:
        criterion: "equilibrium" (force and energy ratios, the default) or "displacement" (the
            paper's per-step displacement).
        tolerance: equilibrium: the ratio both measures must be below (dimensionless, > 0).
        interval: equilibrium: simulated seconds between checks (> 0), unless ``every`` is given.
        every: steps between checks (per step asked for); None: equilibrium from ``interval``,
            displacement :data:`DEFAULT_DISPLACEMENT_EVERY`.
        checks: equilibrium: consecutive checks below ``tolerance`` (>= 1).
        threshold: displacement: grid spacings a node may move in one step (> 0).
    """

    criterion: str = "equilibrium"
    tolerance: float = DEFAULT_TOLERANCE
    interval: float = DEFAULT_INTERVAL
    every: int | None = None
    checks: int = DEFAULT_CHECKS
    threshold: float = DEFAULT_THRESHOLD

    def __post_init__(self) -> None:
        if self.criterion not in CRITERIA:
            raise ValueError(f"converge criterion must be one of {', '.join(CRITERIA)}, got {self.criterion!r}")
        for key in ("tolerance", "interval", "threshold"):
            value = getattr(self, key)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"converge {key} must be a finite number > 0, got {value}")
        if self.every is not None and self.every < 1:
            raise ValueError(f"converge every must be >= 1 step, got {self.every}")
        if self.checks < 1:
            raise ValueError(f"converge checks must be >= 1, got {self.checks}")

    def check_steps(self, dt: float, substeps: int = 1) -> int:
        """Steps of ``dt`` between checks: ``every`` steps asked for (each ``substeps`` steps of
        ``dt``), or the whole steps asked for nearest to ``interval`` (at least one)."""
        if self.every is not None:
            return self.every * substeps
        if self.criterion == "displacement":
            return DEFAULT_DISPLACEMENT_EVERY * substeps
        return max(1, round(self.interval / (dt * substeps))) * substeps

    def monitor(self, system: SpringSystem, *, dt: float, substeps: int = 1, loads: tuple[Load, ...] = (),
                drags: tuple[Drag, ...] = (), hold_until: float = 0.0) -> EquilibriumMonitor | DisplacementMonitor:
        """A fresh monitor for a run of ``system`` at step ``dt`` (``substeps`` per step asked
        for: the displacement threshold per substep is ``threshold / substeps``); no stop before
        the simulated time ``hold_until`` (s: the last scripted change)."""
        every = self.check_steps(dt, substeps)
        if self.criterion == "displacement":
            return DisplacementMonitor(self.threshold * system.spacing / substeps, every, hold_until)
        return EquilibriumMonitor(system, every=every, tolerance=self.tolerance, checks=self.checks,
                                  loads=loads, drags=drags, hold_until=hold_until)


@dataclass
class DisplacementMonitor:
    """The paper's stop: no node moved more than ``threshold`` (world units) in the step ending
    at a multiple of ``every`` steps. The run loop counts it (a GPU census of the last step)."""

    threshold: float
    every: int
    hold_until: float = 0.0
    snapshot: bool = field(default=True, init=False)  # the loop keeps the positions before the last step

    def describe(self) -> str:
        return f"displacement criterion: at most {self.threshold:.3g} in one step of dt (a substep where subdivided)"


@dataclass
class EquilibriumMonitor:
    """The equilibrium stop of a :class:`ConvergeRule` for one run: :meth:`start` with the start
    state, then :meth:`observe` every ``every`` steps; ``force_ratio`` and ``energy_ratio`` hold
    the last check's measures (nan before there are enough samples)."""

    system: SpringSystem
    every: int
    tolerance: float = DEFAULT_TOLERANCE
    checks: int = DEFAULT_CHECKS
    loads: tuple[Load, ...] = ()
    drags: tuple[Drag, ...] = ()
    hold_until: float = 0.0
    snapshot: bool = field(default=False, init=False)
    force_ratio: float = field(default=math.nan, init=False)
    energy_ratio: float = field(default=math.nan, init=False)
    below: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        self._free = ~np.asarray(self.system.fixed)
        self._mass = np.asarray(self.system.mass, np.float64)
        self._samples: list[tuple[np.ndarray, float]] = []
        self._peak_energy = 0.0
        self._peak_force = 0.0

    def start(self, sim: Simulation) -> None:
        """The first sample: the start state."""
        self._samples = [(np.asarray(sim.positions(), np.float64), float(sim.time))]

    def applied_force(self, x: np.ndarray, t: float) -> float:
        """The largest applied force on a free node at time t (N)."""
        f = self._mass * float(np.linalg.norm(self.system.gravity))
        for load in self.loads:
            f[load.nodes] += np.linalg.norm(load.node_forces(t, self._mass), axis=1)
        for drag in self.drags:
            f = f.copy()
            f[drag.node] += drag.stiffness * float(np.linalg.norm(np.asarray(drag.target(t), float) - x[drag.node]))
        return float(np.max(f[self._free], initial=0.0))

    def elastic_energy(self, x: np.ndarray) -> float:
        """The springs' elastic energy ``sum 1/2 k (|x_i - x_j| - L)^2`` at positions x (J), and the
        terms' (:meth:`deformgl.sim.terms.Term.energy`)."""
        s = self.system
        stretch = np.linalg.norm(x[s.i] - x[s.j], axis=1) - s.rest_length
        energy = 0.5 * float(np.sum(s.stiffness * stretch * stretch))
        return energy + sum(term.energy(x) for term in s.terms)

    def observe(self, sim: Simulation) -> bool:
        """A check: read the positions, update the measures; True when converged."""
        x = np.asarray(sim.positions(), np.float64)
        t = float(sim.time)
        self._samples = [*self._samples[-2:], (x, t)]
        (x1, t1), (x2, t2) = self._samples[-2], self._samples[-1]
        v2 = (x2 - x1)[self._free] / (t2 - t1)
        m = self._mass[self._free]
        energy = 0.5 * float(np.sum(m * np.einsum("nk,nk->n", v2, v2)))
        self._peak_energy = max(self._peak_energy, energy)
        applied = self.applied_force(x, t)
        scale = self._peak_energy
        if energy >= self.tolerance * scale:  # (the spring energy only where the peak alone fails)
            scale = max(scale, self.elastic_energy(x))
        self.energy_ratio = energy / scale if scale > 0 else 0.0
        if len(self._samples) < 3:
            self.force_ratio = math.nan
        else:
            x0, t0 = self._samples[0]
            v1 = (x1 - x0)[self._free] / (t1 - t0)
            a = (v2 - v1) / (0.5 * (t2 - t0))
            net = m * np.linalg.norm(a, axis=1)
            largest = float(np.max(net, initial=0.0))
            self._peak_force = max(self._peak_force, largest)
            scale = applied or self._peak_force
            self.force_ratio = largest / scale if scale > 0 else 0.0
        if not (math.isfinite(self.force_ratio) and math.isfinite(self.energy_ratio)):
            self.below = 0
            return False
        ok = self.force_ratio < self.tolerance and self.energy_ratio < self.tolerance
        # only checks whose three samples all follow the last scripted change count
        self.below = self.below + 1 if ok and self._samples[0][1] >= self.hold_until else 0
        return self.below >= self.checks

    def describe(self) -> str:
        """The last check's measures, for a log line."""
        if math.isnan(self.force_ratio):
            return f"equilibrium not measured yet (fewer than three position samples, one every {self.every} steps)"
        if self._samples[0][1] < self.hold_until:
            return (f"waiting for the last scripted change at t = {self.hold_until:g} s (net force "
                    f"{self.force_ratio:.2g} of the applied, kinetic energy {self.energy_ratio:.2g} of its scale)")
        return (f"net force {self.force_ratio:.2g} of the applied, kinetic energy {self.energy_ratio:.2g} of "
                f"its scale (tolerance {self.tolerance:g}, {self.below} of {self.checks} checks below)")
