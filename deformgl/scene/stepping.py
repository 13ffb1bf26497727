"""Simulations of a spring system on any integrator and backend, and one guarded run loop.

:func:`make_simulation` wraps the three backends (fragment passes
:class:`~deformgl.sim.backends.fragment.FragmentIntegrator`, transform feedback
:class:`~deformgl.sim.backends.feedback.FeedbackSimulation`, the float64 NumPy reference
:func:`deformgl.sim.integrators.step`) behind one :class:`Simulation`. :func:`run` steps one with
the guards of the CLI: the dt against the integrator's stability limit first
(:func:`~deformgl.sim.guards.plan_steps`: refuse, run anyway, or subdivide), the blow-up census
every ``check_every`` steps and at the end (:class:`~deformgl.sim.guards.BlowUpWatch` through the
scene run's :func:`~deformgl.scene.run.step_watched`; the NumPy check on the numpy backend), and
with ``unstable="subdivide"`` a restart with twice the substeps after a blow-up
(:func:`~deformgl.scene.run.run_with_retries`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import moderngl
import numpy as np

from deformgl.errors import InputError
from deformgl.grid.nodes import NodeGrid
from deformgl.progress import Progress
from deformgl.scene.run import run_with_retries, step_watched
from deformgl.scene.spec import BACKENDS, UNSTABLE_POLICIES, Safety
from deformgl.sim import integrators
from deformgl.sim.guards import BlowUp, BlowUpWatch, StepPlan, bad_nodes, describe_bad_node, plan_steps
from deformgl.sim.integrators import INTEGRATORS
from deformgl.sim.springs import SpringSystem

__all__ = ["RunResult", "Simulation", "make_simulation", "run"]


class _NumpyStepper:
    """The float64 reference behind the GPU backends' interface (no GL)."""

    def __init__(self, system: SpringSystem, integrator: str, dt: float, **options: Any) -> None:
        self.system, self.integrator, self.dt, self.options = system, integrator, dt, options
        forces = {k: v for k, v in options.items() if k in ("drags", "loads")}
        self.state = integrators.initial_state(system, dt, **forces)
        self.t = 0.0
        self.count = system.count
        self.bytes_per_node = 0.0

    def step(self, n: int = 1) -> None:
        for _ in range(n):
            self.state = integrators.step(self.system, self.integrator, self.state, self.dt, self.t, **self.options)
            self.t += self.dt

    def positions(self) -> np.ndarray:
        return self.state.x.copy()

    def velocities(self) -> np.ndarray:
        return self.state.v.copy()

    def release(self) -> None:
        pass


class Simulation:
    """One spring system stepped by one integrator on one backend.

    Attributes:
        system, integrator, backend: what runs; dt: the step it runs (s, ``dt / substeps`` after a
        subdivided :func:`run`); time: simulated seconds; ctx: the GL context (None on numpy);
        source: the name :func:`run`'s errors start with (a body sets its mesh's).
    """

    def __init__(self, system: SpringSystem, integrator: str, backend: str, *, dt: float,
                 ctx: moderngl.Context | None, grid: NodeGrid | None, **options: Any) -> None:
        if integrator not in INTEGRATORS:
            raise InputError(f"integrator must be one of {', '.join(INTEGRATORS)}, got {integrator!r}")
        if backend not in BACKENDS:
            raise InputError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
        if not dt > 0.0:
            raise InputError(f"dt must be > 0, got {dt}")
        if backend == "fragment" and grid is None:
            raise InputError("the fragment backend needs the node grid of the system (grid=...)")
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
        self._inner: Any = None
        self._steps = 0
        self.restart(self.dt)

    def restart(self, dt: float) -> None:
        """Start again from the rest state with step ``dt``."""
        if self._inner is not None:
            self._inner.release()
            self._inner = None
        if self.backend == "numpy" or self.ctx is None:
            self._inner = _NumpyStepper(self.system, self.integrator, dt, **self.options)
        elif self.backend == "fragment" and self.grid is not None:
            from deformgl.sim.backends.fragment import FragmentIntegrator

            self._inner = FragmentIntegrator(self.ctx, self.system, self.grid, self.integrator, dt, **self.options)
        else:
            from deformgl.sim.backends.feedback import FeedbackSimulation

            self._inner = FeedbackSimulation(self.ctx, self.system, self.integrator, dt, **self.options)
        self.dt, self._steps = float(dt), 0

    @property
    def count(self) -> int:
        """Nodes."""
        return self.system.count

    @property
    def time(self) -> float:
        """Simulated seconds since the start."""
        return self._steps * self.dt

    @property
    def bytes_per_node(self) -> float:
        """GPU bytes allocated per node (0 on numpy)."""
        return float(getattr(self._inner, "bytes_per_node", 0.0))

    def step(self, n: int = 1) -> None:
        """``n`` steps, unguarded (see :func:`run`); nothing is read back."""
        self._inner.step(n)
        self._steps += n

    def positions(self) -> np.ndarray:
        """(N, 3) node positions (one read-back on the GPU backends)."""
        return np.asarray(self._inner.positions())[:, :3]

    def velocities(self) -> np.ndarray:
        """(N, 3) node velocities (one read-back on the GPU backends)."""
        return np.asarray(self._inner.velocities())[:, :3]

    def position_slot(self) -> tuple[moderngl.Texture, int, int, int]:
        """Where the positions lie on the GPU: (texture, nodes per row, slots per node, slot)."""
        if self.backend == "numpy":
            raise InputError("the numpy backend keeps no positions on the GPU")
        texture, row, slots, slot = self._inner.position_slot()
        return texture, int(row), int(slots), int(slot)

    def release(self) -> None:
        """Release every GL object (and the context it created); idempotent."""
        if self._inner is not None:
            self._inner.release()
            self._inner = None
        if self._own_ctx is not None:
            self._own_ctx.release()
            self._own_ctx = None

    def __enter__(self) -> Simulation:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def make_simulation(system: SpringSystem, integrator: str = "verlet", backend: str = "fragment", *, dt: float,
                    ctx: moderngl.Context | None = None, grid: NodeGrid | None = None, **options: Any) -> Simulation:
    """A :class:`Simulation` of ``system`` (``options``: constraints, drags, loads)."""
    return Simulation(system, integrator, backend, dt=dt, ctx=ctx, grid=grid, **options)


@dataclass(frozen=True)
class _Settings:
    """The :class:`~deformgl.sim.guards.StepSettings` of one :func:`run`."""

    dt: float
    steps: int
    integrator: str
    safety: Safety = field(default_factory=Safety)


@dataclass(frozen=True)
class RunResult:
    """What :func:`run` did: the steps asked for, the substeps per step it used, the simulated time,
    and notes (what the plan and restarts changed) for a log."""

    steps: int
    substeps: int
    time: float
    notes: tuple[str, ...] = ()


def run(sim: Simulation, steps: int, *, unstable: str = "refuse", check_every: int = 100,
        bad_distance: float = 1000.0, source: str | None = None, progress: bool = False) -> RunResult:
    """Run ``steps`` steps of ``sim.dt`` with the CLI's guards.

    Args:
        unstable: a dt above the stability limit is refused ("refuse"), run anyway ("run") or
            split into substeps ("subdivide", which also restarts after a blow-up with twice the
            substeps, up to 16); a subdivided run starts again from the rest state.
        check_every: steps between blow-up checks (0: at the end only).
        bad_distance: a node farther than this many rest-box lengths from the origin has blown up.
        source: the name error messages start with (default: ``sim.source``).

    Raises:
        SimulationError: the dt is above the limit (and ``unstable`` is "refuse"), or the run blew
            up (:class:`~deformgl.sim.guards.BlowUp`).
    """
    if unstable not in UNSTABLE_POLICIES:
        raise InputError(f"unstable must be one of {', '.join(UNSTABLE_POLICIES)}, got {unstable!r}")
    source = sim.source if source is None else source
    settings = _Settings(sim.base_dt, int(steps), sim.integrator, Safety(unstable, check_every, bad_distance))
    plan = plan_steps(sim.system, settings, source)
    notes: list[str] = [plan.note] if plan.note else []
    rest = sim.system.rest_positions
    limit = bad_distance * float(np.max(rest.max(axis=0) - rest.min(axis=0), initial=0.0) or sim.system.spacing)

    def attempt(p: StepPlan) -> None:
        if p.step_dt != sim.dt or (p is not plan and sim.time > 0):
            sim.restart(p.step_dt)
        with Progress(p.step_count, "steps", enabled=progress) as bar:
            if sim.backend == "numpy":
                last = None
                for n in range(p.step_count):
                    sim.step(1)
                    bar.update(n + 1)
                    if (check_every and (n + 1) % check_every == 0) or n + 1 == p.step_count:
                        x = sim.positions()
                        count = int(bad_nodes(x, limit).sum())
                        if count:
                            raise BlowUp.at(source, n + 1, p.step_dt, count, describe_bad_node(x, sim.grid, limit),
                                            limit, last)
                        last = n + 1
                return
            assert sim.ctx is not None
            watch = BlowUpWatch(sim.ctx, sim, every=check_every, limit=limit, grid=sim.grid, source=source,
                                dt=p.step_dt)
            try:
                step_watched(sim.ctx, sim, p.step_count, bar, watch)
            finally:
                watch.release()

    _, used = run_with_retries(plan, unstable, attempt, notes)
    return RunResult(int(steps), used.substeps, sim.time, tuple(notes))
