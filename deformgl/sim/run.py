"""The one run loop: any :class:`~deformgl.sim.simulation.Simulation`, any backend.

:func:`run` steps in chunks (the progress bar moves between them), checks for blown-up nodes
every ``watch.every`` steps and once at the end, and stops early when the run has converged
(:mod:`deformgl.sim.equilibrium`): by default at equilibrium (the net force on every free node
and the kinetic energy small against the applied force and the run's peak, checked on positions
read back every ``interval`` simulated seconds), or with the paper's displacement criterion
when no node moved more than a threshold in one step (Movania & Feng 2012, section 4). On the
GPU backends the blow-up checks and the displacement test are census queries
(:class:`~deformgl.sim.guards.BlowUpWatch`, :class:`~deformgl.sim.census.NodeCensus`), nothing
is read back unless a check fails; on the NumPy backend they are the same tests on the float64
arrays. Converged means the same on every backend.

:func:`run_guarded` is the whole guarded run on top of it, the one the CLI's scenes and the Python
API (:func:`deformgl.run`) both use: the dt against the integrator's stability limit first
(:func:`~deformgl.sim.guards.plan_steps`: refuse, run anyway, or subdivide), a simulation built
for the plan's step, :func:`run` with the blow-up watch and the convergence stop, and under the
"subdivide" policy a restart with twice the substeps after a :class:`~deformgl.sim.guards.BlowUp`
(:func:`run_with_retries`). Both return the one :class:`RunResult`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TypeVar

import numpy as np

from deformgl.errors import SimulationError
from deformgl.grid.nodes import NodeGrid
from deformgl.progress import Progress
from deformgl.sim.equilibrium import ConvergeRule, DisplacementMonitor, EquilibriumMonitor
from deformgl.sim.guards import (SCENE_WORDING, BlowUp, BlowUpWatch, StepPlan, StepSettings, Watch, Wording,
                                 plan_steps)
from deformgl.sim.simulation import Simulation
from deformgl.sim.springs import Drag, Load, SpringSystem
from deformgl.sim.volume import describe_inverted

__all__ = ["RunResult", "NumpyWatch", "make_watch", "residual_note", "run", "run_guarded", "run_with_retries"]

T = TypeVar("T")


@dataclass(frozen=True)
class RunResult:
    """What :func:`run` or :func:`run_guarded` did.

    Attributes:
        steps: steps done, each of ``dt`` (under a plan of ``substeps`` substeps, ``substeps``
            steps per step asked for).
        converged: True/False: whether the run stopped converged (at equilibrium, by default;
            :mod:`deformgl.sim.equilibrium`); None without a convergence stop.
        substeps: substeps per step asked for that the run used (1 unless subdivided).
        dt: the step the simulation ran (s); None when not recorded (:func:`run` leaves it to
            its caller).
        time: the simulation's clock at the end (s); None when not recorded.
        notes: what the plan and the restarts changed, for a log.
        convergence: the convergence stop's last measures (its ``describe()``), None without one.
        inverted_cells: the inversion census at the end (:func:`deformgl.sim.volume.describe_inverted`):
            cells whose trilinear map has a Jacobian <= 0 at a corner; None for a system without
            cells (springs only).
        inverted: the census's phrase naming the first inverted cell, "" when there is none.
        solver: an implicit integrator's linear solves (its ``solver_stats()``: iterations mean
            and most per step, last and worst relative residual, steps that missed the
            tolerance), None for the others: the solver's convergence, apart from ``converged``.
    """

    steps: int
    converged: bool | None
    substeps: int = 1
    dt: float | None = None
    time: float | None = None
    notes: tuple[str, ...] = ()
    convergence: str | None = None
    inverted_cells: int | None = None
    inverted: str = ""
    solver: dict | None = None


#: what :func:`run` takes as its convergence stop: a monitor, or ``(threshold, every)`` of the
#: displacement criterion
Converge = EquilibriumMonitor | DisplacementMonitor | tuple[float, int]


class NumpyWatch(Watch):
    """:class:`~deformgl.sim.guards.Watch` for a simulation without GPU state: the same schedule
    and message, counted on ``sim.positions()``."""

    def __init__(self, sim, *, every: int, limit: float, grid=None, source=None, dt: float | None = None,
                 wording: Wording = SCENE_WORDING) -> None:
        super().__init__(sim, every=every, limit=limit, grid=grid, source=source, dt=sim.dt if dt is None else dt,
                         wording=wording)


def make_watch(ctx, sim, *, every: int, limit: float, grid=None, source=None, dt: float | None = None,
               wording: Wording = SCENE_WORDING) -> Watch:
    """The blow-up watch that fits ``sim``: census queries on the GPU, NumPy otherwise;
    ``wording``: how its :class:`~deformgl.sim.guards.BlowUp` advice names the settings."""
    dt = sim.dt if dt is None else dt
    if sim.position_slot() is None:
        return NumpyWatch(sim, every=every, limit=limit, grid=grid, source=source, dt=dt, wording=wording)
    return BlowUpWatch(ctx, sim, every=every, limit=limit, grid=grid, source=source, dt=dt, wording=wording)


def _census(sim, result: RunResult) -> RunResult:
    """``result`` with the inversion census of the final state (one read-back of the positions;
    nothing for a system without cells)."""
    system = getattr(sim, "system", None)
    cells = getattr(system, "cells", None)
    if cells is None:
        return result
    grid = getattr(system, "grid", None)
    count, phrase = describe_inverted(cells, np.asarray(sim.positions(), np.float64),
                                      None if grid is None else grid.ijk)
    return replace(result, inverted_cells=count, inverted=phrase)


class _NoBar:
    def update(self, done: int) -> None:
        pass


def run(sim, steps: int, *, ctx=None, watch=None, converge: Converge | None = None,
        progress=None, chunk: int = 25, frame_every: int = 0,
        on_frame: Callable[[int, object], None] | None = None) -> RunResult:
    """``steps`` steps of ``sim`` with the guards and the convergence stop.

    Args:
        sim: a :class:`~deformgl.sim.simulation.Simulation`.
        steps: steps to run.
        ctx: the GL context (GPU backends; default ``sim.ctx``).
        watch: a :func:`make_watch` watch, or None for no blow-up checks.
        converge: the convergence stop: an :class:`~deformgl.sim.equilibrium.EquilibriumMonitor`
            (checked every ``converge.every`` steps), or a
            :class:`~deformgl.sim.equilibrium.DisplacementMonitor` or ``(threshold, every)``: stop
            when no node moved more than threshold in the step ending at a multiple of ``every``.
        progress: anything with ``update(done)`` (a :class:`~deformgl.progress.Progress`).
        chunk: most steps between progress updates on the GPU (the NumPy backend checks every
            step for non-finite positions, so it steps one at a time).
        frame_every, on_frame: ``on_frame(done, sim)`` at the start (done 0) and after every
            ``frame_every`` steps (an animation draws a frame from the simulation's GPU state
            there; nothing is read back by the loop).

    Raises:
        BlowUp: a check counted bad nodes.
    """
    bar = _NoBar() if progress is None else progress
    gpu = sim.position_slot() is not None
    ctx = getattr(sim, "ctx", None) if ctx is None else ctx
    if not gpu:
        chunk = 1
    stop = DisplacementMonitor(*converge) if isinstance(converge, tuple) else converge
    census = None
    if isinstance(stop, DisplacementMonitor) and gpu:
        from deformgl.sim.census import NodeCensus

        _, row, slots, _ = sim.position_slot()
        census = NodeCensus(ctx, count=sim.count, row=row, slots=slots)
    framing = on_frame is not None and frame_every > 0
    try:
        done = 0
        if isinstance(stop, EquilibriumMonitor):
            stop.start(sim)
        if on_frame is not None:
            on_frame(0, sim)
        while done < steps:
            target = min(done + chunk, steps, watch.next_stop(done, steps) if watch else steps)
            if framing:
                target = min(target, (done // frame_every + 1) * frame_every)
            check_convergence = False
            if stop is not None:
                at = (done // stop.every + 1) * stop.every
                if at <= target:
                    target, check_convergence = at, True
            before = None
            if check_convergence and census is not None:  # (census: the displacement test on the GPU)
                if target - done > 1:
                    sim.step(target - done - 1)
                texture, _, _, slot = sim.position_slot()
                before = census.snapshot(texture, slot=slot)
                sim.step(1)
            else:
                sim.step(target - done)
            if gpu:
                ctx.finish()
            done = target
            bar.update(done)
            blown = not gpu and not np.isfinite(sim.last_moved)
            if watch is not None and (watch.due(done) or done == steps or blown):
                watch.check(done)
            if framing and on_frame is not None and done % frame_every == 0:
                on_frame(done, sim)
            if check_convergence and stop is not None:  # (checks only when converging)
                if isinstance(stop, EquilibriumMonitor):
                    still = stop.observe(sim)
                elif census is not None and before is not None:  # (both set on the GPU path)
                    now, _, _, slot = sim.position_slot()
                    still = census.moved(now, before, stop.threshold, slot=slot, before_slots=1) == 0
                else:
                    still = sim.last_moved <= stop.threshold
                if still and sim.time < stop.hold_until:  # a scripted change is still to come
                    still = False
                if still:
                    if watch is not None and not watch.due(done):
                        watch.check(done)
                    return _census(sim, RunResult(done, True, convergence=stop.describe()))
        return _census(sim, RunResult(steps, None if stop is None else False,
                                      convergence=None if stop is None else stop.describe()))
    finally:
        if census is not None:
            census.release()


def run_with_retries(plan: StepPlan, policy: str, attempt: Callable[[StepPlan], T],
                     notes: list[str], *, wording: Wording = SCENE_WORDING) -> tuple[T, StepPlan]:
    """``attempt(plan)``; with the "subdivide" policy a :class:`~deformgl.sim.guards.BlowUp`
    restarts it with twice the substeps (up to :data:`~deformgl.sim.guards.MAX_SUBSTEPS`), each
    restart noted in ``notes``. Returns what the last attempt returned and its plan.

    Raises:
        BlowUp: under any other policy.
        SimulationError: a blow-up at :data:`~deformgl.sim.guards.MAX_SUBSTEPS` substeps.
    """
    while True:
        try:
            return attempt(plan), plan
        except BlowUp as exc:
            if policy != "subdivide":
                raise
            finer = plan.halved()
            if finer is None:
                raise SimulationError(f"{exc} (still at {plan.substeps} substeps per step, the most "
                                      f"{wording.subdivide} uses)") from None
            notes.append(f"{exc}; {finer.note}")
            plan = finer


def run_guarded(system: SpringSystem, settings: StepSettings, make: Callable[[float], Simulation], *,
                source: object, limit: float, check_every: int, ctx=None, grid: NodeGrid | None = None,
                converge: ConvergeRule | tuple[float, int] | None = None, loads: tuple[Load, ...] = (),
                drags: tuple[Drag, ...] = (), hold_until: float = 0.0, progress: bool = False,
                plan: StepPlan | None = None,
                notes: list[str] | None = None, wording: Wording = SCENE_WORDING, frame_every: int = 0,
                on_frame: Callable[[int, object], None] | None = None) -> RunResult:
    """The guarded run of ``settings.steps`` steps of ``settings.dt`` of ``system``.

    1. ``plan``, or :func:`~deformgl.sim.guards.plan_steps` of ``settings`` (refuses a dt above
       the integrator's limit unless ``settings.safety.unstable`` is "run" or "subdivide");
    2. ``make(plan.step_dt)``: the simulation to run at that step;
    3. :func:`run` of ``plan.step_count`` steps with a :func:`make_watch` watch every
       ``check_every`` steps (and at the end) and the convergence stop;
    4. under "subdivide", a :class:`~deformgl.sim.guards.BlowUp` starts again at 2. with twice the
       substeps (:func:`run_with_retries`).

    Args:
        make: ``make(dt) -> Simulation``, called once per attempt, at the start state (a retry
            needs a fresh one). What it returns stays the caller's: ``run_guarded`` releases none
            of them (``make`` may release the previous one, and the caller the last).
        source: the name messages start with (a scene file, ``"<arrays>"``).
        limit: a node farther than this from the origin (world units) counts as blown up.
        check_every: steps between blow-up checks (0: at the end only).
        ctx: the GL context of the watch and the loop (default: the simulation's ``ctx``).
        grid: names a blown-up node's grid index in the message, if given.
        converge: the convergence stop: a :class:`~deformgl.sim.equilibrium.ConvergeRule` (a
            fresh monitor per attempt, at the attempt's step and substeps), or the displacement
            criterion's ``(threshold, every)`` per step asked for: stop when no node moved more than
            ``threshold`` in a step ending at a multiple of ``every`` steps (Movania & Feng 2012,
            section 4); with substeps, ``threshold / substeps`` per substep every
            ``every * substeps`` substeps.
        loads, drags: the run's scripted loads and drags (the equilibrium stop counts their
            forces among the applied ones).
        hold_until: no convergence stop before this simulated time (s): the last scripted change.
        progress: show a progress bar on stderr.
        plan: a plan checked already (its note is noted, as :func:`plan_steps`' would be).
        notes: receives the plan's note and each restart's as they happen, if given (the result
            carries them too).
        wording: how the messages name the dt and the policy
            (:data:`~deformgl.sim.guards.SCENE_WORDING` or :data:`~deformgl.sim.guards.API_WORDING`).
        frame_every, on_frame: ``on_frame(step, sim)`` at step 0 and every ``frame_every`` steps
            asked for (:func:`run`; with substeps, every ``frame_every * substeps`` substeps, the
            step counted in steps asked for); a restart calls it again from step 0.

    Returns:
        :class:`RunResult`: steps done (of ``dt``), converged, the substeps used, the step ``dt``,
        the simulation's ``time`` at the end and the notes.

    Raises:
        SimulationError: the dt is refused, or a blow-up at the most substeps.
        BlowUp: a blow-up under "refuse" or "run".
    """
    plan = plan_steps(system, settings, source, wording=wording) if plan is None else plan
    noted: list[str] = [] if notes is None else notes
    first = len(noted)
    if plan.note:
        noted.append(plan.note)

    def attempt(p: StepPlan) -> tuple[RunResult, Simulation]:
        sim = make(p.step_dt)
        gl = getattr(sim, "ctx", None) if ctx is None else ctx
        stop: Converge | None = None
        if isinstance(converge, ConvergeRule):
            stop = converge.monitor(system, dt=p.step_dt, substeps=p.substeps, loads=loads, drags=drags,
                                    hold_until=hold_until)
        elif converge is not None:
            stop = DisplacementMonitor(converge[0] / p.substeps, converge[1] * p.substeps, hold_until)
        watch = make_watch(gl, sim, every=check_every, limit=limit, grid=grid, source=source, dt=p.step_dt,
                           wording=wording)
        hook = None if on_frame is None else (lambda done, s: on_frame(done // p.substeps, s))
        try:
            with Progress(p.step_count, "steps", enabled=progress) as bar:
                return run(sim, p.step_count, ctx=gl, watch=watch, converge=stop, progress=bar,
                           frame_every=frame_every * p.substeps, on_frame=hook), sim
        finally:
            watch.release()

    (result, sim), used = run_with_retries(plan, settings.safety.unstable, attempt, noted, wording=wording)
    solver_note = getattr(sim, "solver_note", None)  # an implicit integrator's unconverged solves
    note = solver_note() if callable(solver_note) else None
    if note:
        noted.append(note)
    residual_note(sim, noted)
    stats = getattr(sim, "solver_stats", None)
    return replace(result, substeps=used.substeps, dt=used.step_dt, time=float(sim.time), notes=tuple(noted[first:]),
                   solver=stats() if callable(stats) else None)


def residual_note(sim: Simulation, notes: list[str]) -> None:
    """Note when an iterative integrator (XPBD) ended with a large relative constraint residual
    (above :data:`deformgl.sim.xpbd.RESIDUAL_NOTE`): its solve did not converge in its iterations."""
    from deformgl.sim.xpbd import RESIDUAL_NOTE

    residual = getattr(sim, "residual", None)
    if isinstance(residual, float) and residual > RESIDUAL_NOTE:
        notes.append(f"{sim.integrator}: relative constraint residual {residual:.3g} after the last step "
                     f"(above {RESIDUAL_NOTE:g}): the solve did not converge in its iterations, so the body is "
                     f"softer than its material; raise physics.xpbd.iterations or substeps")
