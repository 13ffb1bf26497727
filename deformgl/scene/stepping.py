"""A restartable, guarded simulation for the public API, and the guarded run of it.

:class:`GuardedSimulation` holds one :func:`deformgl.sim.simulation.make_simulation` backend
(fragment, feedback or the NumPy reference), implements the
:class:`deformgl.sim.simulation.Simulation` protocol, and can start again with a smaller step.
:func:`run` steps it with the guards of the CLI, worded for the Python API
(:data:`~deformgl.sim.guards.API_WORDING`): it is :func:`deformgl.sim.run.run_guarded`, the one
guarded run (the dt against the integrator's stability limit first, refuse, run anyway or
subdivide; the blow-up census every ``check_every`` steps and at the end; with
``unstable="subdivide"`` a restart with twice the substeps after a blow-up).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import moderngl
import numpy as np

from deformgl.errors import ArgumentError, InputError
from deformgl.grid.nodes import NodeGrid
from deformgl.scene.spec import BACKENDS, UNSTABLE_POLICIES, Safety
from deformgl.sim.equilibrium import ConvergeRule
from deformgl.sim.guards import API_WORDING
from deformgl.sim.integrators import INTEGRATORS
from deformgl.sim.run import RunResult, run_guarded
from deformgl.sim.simulation import Simulation as BackendSimulation
from deformgl.sim.simulation import SimulationSetupError
from deformgl.sim.simulation import make_simulation as make_backend
from deformgl.sim.springs import SpringSystem

__all__ = ["GuardedSimulation", "make_simulation", "run"]


class GuardedSimulation:
    """One spring system stepped by one integrator on one backend, restartable with another step:
    a :class:`deformgl.sim.simulation.Simulation` around the backend's, which :func:`run` guards.

    Attributes:
        system, integrator, backend: what runs; dt: the step it runs (s, ``dt / substeps`` after a
        subdivided :func:`run`); time: simulated seconds; ctx: the GL context (None on numpy);
        source: the name :func:`run`'s errors start with (a body sets its mesh's).
    """

    def __init__(self, system: SpringSystem, integrator: str, backend: str, *, dt: float,
                 ctx: moderngl.Context | None, grid: NodeGrid | None, **options: Any) -> None:
        if integrator not in INTEGRATORS:
            raise SimulationSetupError(f"unknown integrator {integrator!r}; expected one of {', '.join(INTEGRATORS)}")
        if backend not in BACKENDS:
            raise SimulationSetupError(f"unknown backend {backend!r}; expected one of {', '.join(BACKENDS)}")
        if not dt > 0.0:
            raise SimulationSetupError(f"dt must be > 0, got {dt}")
        if backend != "numpy" and ctx is None:
            from deformgl.gl.context import create_context

            ctx = create_context()
            self._own_ctx: moderngl.Context | None = ctx
        else:
            self._own_ctx = None
        self.system, self.integrator, self.backend, self.grid = system, integrator, backend, grid
        self.ctx, self.options, self.dt = ctx, options, float(dt)
        self.base_dt = float(dt)
        self.source = "<simulation>"
        self._inner: BackendSimulation | None = None
        self.restart(self.dt)

    def restart(self, dt: float) -> None:
        """Start again from the rest state with step ``dt``."""
        if self._inner is not None:
            self._inner.release()
            self._inner = None
        self._inner = make_backend(self.system, self.integrator, self.backend, dt=dt, ctx=self.ctx, grid=self.grid,
                                   **self.options)
        self.dt = float(dt)

    @property
    def _live(self) -> BackendSimulation:
        if self._inner is None:
            raise RuntimeError("the simulation is released")
        return self._inner

    @property
    def count(self) -> int:
        """Nodes."""
        return self.system.count

    @property
    def time(self) -> float:
        """Simulated seconds since the start."""
        return float(self._live.time)

    @property
    def bytes_per_node(self) -> float:
        """GPU bytes allocated per node (0 on numpy)."""
        return float(self._live.bytes_per_node)

    def step(self, n: int = 1) -> None:
        """``n`` steps, unguarded (see :func:`run`); nothing is read back."""
        self._live.step(n)

    def positions(self) -> np.ndarray:
        """(N, 3) node positions (one read-back on the GPU backends)."""
        return np.asarray(self._live.positions())[:, :3]

    def velocities(self) -> np.ndarray:
        """(N, 3) node velocities (one read-back on the GPU backends)."""
        return np.asarray(self._live.velocities())[:, :3]

    @property
    def residual(self) -> float | None:
        """The relative constraint residual of an iterative integrator's last step (XPBD), else None."""
        return getattr(self._live, "residual", None)

    @property
    def backend_simulation(self) -> BackendSimulation:
        """The backend simulation it runs now (replaced by a subdivided :func:`run`)."""
        return self._live

    def position_slot(self) -> tuple[moderngl.Texture, int, int, int] | None:
        """Where the positions lie on the GPU: (texture, nodes per row, slots per node, slot);
        None on the numpy backend."""
        where = self._live.position_slot()
        if where is None:
            return None
        texture, row, slots, slot = where
        return texture, int(row), int(slots), int(slot)

    def release(self) -> None:
        """Release every GL object (and the context it created); idempotent."""
        if self._inner is not None:
            self._inner.release()
            self._inner = None
        if self._own_ctx is not None:
            self._own_ctx.release()
            self._own_ctx = None

    def __enter__(self) -> GuardedSimulation:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def make_simulation(system: SpringSystem, integrator: str = "verlet", backend: str = "fragment", *, dt: float,
                    ctx: moderngl.Context | None = None, grid: NodeGrid | None = None,
                    **options: Any) -> GuardedSimulation:
    """A :class:`GuardedSimulation` of ``system`` on :func:`deformgl.sim.simulation.make_simulation`'s
    backend (``options``: constraints, drags, loads, state, t0); a GPU backend without ``ctx``
    gets a context of its own, released with it.

    Raises:
        SimulationSetupError: an unknown integrator, backend or option (an :class:`InputError`).
    """
    return GuardedSimulation(system, integrator, backend, dt=dt, ctx=ctx, grid=grid, **options)


@dataclass(frozen=True)
class _Settings:
    """The :class:`~deformgl.sim.guards.StepSettings` of one :func:`run`."""

    dt: float
    steps: int
    integrator: str
    safety: Safety = field(default_factory=Safety)


def run(sim: GuardedSimulation, steps: int, *, unstable: str = "refuse", check_every: int = 100,
        bad_distance: float = 1000.0, source: str | None = None, progress: bool = False,
        converge: ConvergeRule | None = None, hold_until: float = 0.0) -> RunResult:
    """Run ``steps`` steps of the dt ``sim`` was made with, with the CLI's guards
    (:func:`deformgl.sim.run.run_guarded`; messages name ``dt`` and ``unstable=``).

    A run at the step ``sim`` has goes on from where it is; a subdivided one (or a restart after
    a blow-up) starts again from the rest state with the smaller step, which ``sim.dt`` then is.

    Args:
        unstable: a dt above the stability limit is refused ("refuse"), run anyway ("run") or
            split into substeps ("subdivide", which also restarts after a blow-up with twice the
            substeps, up to 16).
        check_every: steps between blow-up checks (0: at the end only).
        bad_distance: a node farther than this many rest-box lengths from the origin has blown up.
        source: the name error messages start with (default: ``sim.source``).
        progress: show a progress bar on stderr.
        converge: stop early once converged: a :class:`~deformgl.sim.equilibrium.ConvergeRule`
            (``dg.ConvergeRule()``: at equilibrium, the net force on every free node and the
            kinetic energy below 1 % of the applied force and of the run's peak at 3 checks 0.02 s
            apart, against the larger of the run's peak and the springs' elastic energy; the
            simulation's loads and drags count as applied forces); ``steps`` is the limit.
        hold_until: no convergence stop before this simulated time (s): give the time of the last
            scripted change (a load that starts or stops, a drag target's last move).

    Returns:
        :class:`~deformgl.sim.run.RunResult`: the steps done (of ``result.dt``: ``substeps`` per
        step asked for), whether it converged and the last check's measures, the substeps, the
        step, ``sim.time`` at the end, the notes.

    Raises:
        SimulationError: the dt is above the limit (and ``unstable`` is "refuse"), or the run blew
            up (:class:`~deformgl.sim.guards.BlowUp`).
    """
    if unstable not in UNSTABLE_POLICIES:
        raise InputError(f"unstable must be one of {', '.join(UNSTABLE_POLICIES)}, got {unstable!r}")
    for name, value in (("steps", steps), ("check_every", check_every)):  # (-1 steps would run none, silently)
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
            raise ArgumentError(f"run: {name} must be an integer >= 0, got {value!r}")
    if not (isinstance(bad_distance, (int, float, np.number)) and math.isfinite(bad_distance) and bad_distance > 0):
        raise ArgumentError(f"run: bad_distance must be a finite number > 0 (rest-box lengths), got {bad_distance!r}")
    source = sim.source if source is None else source
    settings = _Settings(sim.base_dt, int(steps), sim.integrator, Safety(unstable, check_every, bad_distance))
    rest = sim.system.rest_positions
    limit = bad_distance * float(np.max(rest.max(axis=0) - rest.min(axis=0), initial=0.0) or sim.system.spacing)
    attempts = [0]

    def make(dt: float) -> BackendSimulation:
        # the first attempt at the step sim has goes on; any other starts from the rest state
        if dt != sim.dt or (attempts[0] > 0 and sim.time > 0):
            sim.restart(dt)
        attempts[0] += 1
        return sim.backend_simulation

    return run_guarded(sim.system, settings, make, source=source, limit=limit, check_every=check_every,
                       ctx=sim.ctx, grid=sim.grid, progress=progress, wording=API_WORDING, converge=converge,
                       loads=tuple(sim.options.get("loads", ())), drags=tuple(sim.options.get("drags", ())),
                       hold_until=hold_until)
