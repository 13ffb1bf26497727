"""The one run: any :class:`~deformgl.sim.simulation.Simulation`, any backend, with its guards.

:func:`run` checks the dt against the integrator's stability limit first
(:func:`~deformgl.sim.guards.plan_steps`, the ``unstable`` policy: refuse, run anyway, or
subdivide each step into substeps), steps in chunks (the progress bar moves between them),
checks for blown-up nodes every ``check_every`` steps and once at the end, and stops early when
the run has converged (:mod:`deformgl.sim.equilibrium`): by default at equilibrium (the net force
on every free node and the kinetic energy small against the applied force and the run's peak,
checked on positions read back every ``interval`` simulated seconds), or with the paper's
displacement criterion when no node moved more than a threshold in one step (Movania & Feng
2012, section 4). Under "subdivide" a :class:`~deformgl.sim.guards.BlowUp` restarts the run
with twice the substeps (:func:`~deformgl.sim.guards.retry_with_substeps`). On the GPU backends
the blow-up checks and the displacement test are census queries
(:class:`~deformgl.sim.guards.BlowUpWatch`, :class:`~deformgl.sim.census.NodeCensus`), nothing
is read back unless a check fails; on the NumPy backend they are the same tests on the float64
arrays. Converged means the same on every backend. The CLI's scenes
(:func:`deformgl.scene.physics.simulate_scene`) and the Python API (``dg.run``) both run here;
the result is one :class:`RunResult`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from deformgl.errors import ArgumentError, InputError
from deformgl.grid.nodes import NodeGrid
from deformgl.progress import Progress
from deformgl.sim.equilibrium import ConvergeRule, DisplacementMonitor, EquilibriumMonitor
from deformgl.sim.guards import (API_WORDING, SCENE_WORDING, UNSTABLE_POLICIES, BlowUpWatch, StepPlan, StepSettings, Watch, Wording,
                                 plan_steps, retry_with_substeps)
from deformgl.sim.simulation import Simulation
from deformgl.sim.springs import SpringSystem
from deformgl.sim.scripted import Drag, Load
from deformgl.sim.terms.base import Term

__all__ = ["RunResult", "NumpyWatch", "make_watch", "residual_note", "run"]


@dataclass(frozen=True)
class RunResult:
    """What :func:`run` did.

    Attributes:
        steps: steps done, each of ``dt`` (under a plan of ``substeps`` substeps, ``substeps``
            steps per step asked for).
        converged: True/False: whether the run stopped converged (at equilibrium, by default;
            :mod:`deformgl.sim.equilibrium`); None without a convergence stop.
        substeps: substeps per step asked for that the run used (1 unless subdivided).
        dt: the step the simulation ran (s); None when not recorded.
        time: the simulation's clock at the end (s); None when not recorded.
        notes: what the plan and the restarts changed, for a log.
        convergence: the convergence stop's last measures (its ``describe()``), None without one.
        inverted_cells: the inversion census at the end (``Term.inversions`` of the system's terms;
            the cells': those whose trilinear map has a Jacobian <= 0 at a corner); None for a
            system whose terms have no elements (springs only).
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
    """``result`` with the inversion census of the final state over the system's terms that have
    elements (``Term.inversions``; one read-back of the positions; nothing for a system whose
    terms have none, e.g. springs only)."""
    system = getattr(sim, "system", None)
    counted = [t for t in getattr(system, "terms", ()) if type(t).inversions is not Term.inversions]
    if not counted:
        return result
    x = np.asarray(sim.positions(), np.float64)
    grid = getattr(system, "grid", None)
    found = [c for c in (t.inversions(x, grid) for t in counted) if c is not None]
    if not found:
        return result
    return replace(result, inverted_cells=sum(c for c, _ in found), inverted="; ".join(p for _, p in found if p))


class _NoBar:
    def update(self, done: int) -> None:
        pass


def _loop(sim, steps: int, *, ctx=None, watch=None, converge: Converge | None = None,
          progress=None, chunk: int = 25, frame_every: int = 0,
          on_frame: Callable[[int, object], None] | None = None) -> RunResult:
    """``steps`` steps of one simulation with the blow-up watch and the convergence stop (one
    attempt of :func:`run`).

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


@dataclass(frozen=True)
class _Settings:
    """The :class:`~deformgl.sim.guards.StepSettings` of a run given as arguments."""

    dt: float
    steps: int
    integrator: str
    safety: _Policy


@dataclass(frozen=True)
class _Policy:
    unstable: str


def run(sim, steps: int | None = None, *, unstable: str | None = "refuse", check_every: int = 100,
        bad_distance: float = 1000.0, limit: float | None = None,
        converge: ConvergeRule | Converge | None = None, hold_until: float = 0.0, source: object = None,
        retries: int | None = None, progress: bool = False, settings: StepSettings | None = None,
        system: SpringSystem | None = None,
        loads: tuple[Load, ...] | None = None, drags: tuple[Drag, ...] | None = None, plan: StepPlan | None = None,
        notes: list[str] | None = None, wording: Wording = API_WORDING, ctx=None, grid: NodeGrid | None = None,
        frame_every: int = 0, on_frame: Callable[[int, object], None] | None = None) -> RunResult:
    """``steps`` steps of ``sim`` with the guards and the convergence stop: the one run.

    1. ``plan``, or :func:`~deformgl.sim.guards.plan_steps`: the dt against the integrator's
       stability limit under the ``unstable`` policy;
    2. the simulation for the plan's step (``sim`` itself when its step is the plan's);
    3. the steps, with a blow-up check every ``check_every`` steps and at the end, and the
       convergence stop;
    4. under "subdivide", a :class:`~deformgl.sim.guards.BlowUp` starts again at 2. with twice the
       substeps (:func:`~deformgl.sim.guards.retry_with_substeps`).

    A run at the step ``sim`` has goes on from where it is; a subdivided one (or a restart after a
    blow-up) starts again from the rest state with the smaller step.

    Args:
        sim: a :class:`~deformgl.sim.simulation.Simulation`; one from
            a :class:`~deformgl.sim.restartable.GuardedSimulation` (``dg.Body.simulate``'s, which a
            smaller step restarts; its ``dt`` is then the substep); or ``make(dt) -> Simulation``, called once per attempt
            for a fresh simulation at the start state, which stays the caller's to release (with
            ``settings`` and ``system``).
        steps: steps asked for (default ``settings.steps``).
        unstable: a dt above the stability limit is refused ("refuse"), run anyway ("run") or split
            into substeps ("subdivide", which also restarts after a blow-up with twice the
            substeps, up to 16); None: no dt check and no restart (a blow-up raises).
        retries: restarts after a blow-up, each with twice the substeps (up to 16): None, the
            policy's (as many as the cap allows under "subdivide", none otherwise); 0 none.
        check_every: steps between blow-up checks (0: at the end only).
        bad_distance: a node farther than this many rest-box lengths from the origin has blown up.
        limit: the same as a distance in world units (replaces ``bad_distance``).
        converge: stop early once converged: a :class:`~deformgl.sim.equilibrium.ConvergeRule`
            (``dg.ConvergeRule()``: at equilibrium, the net force on every free node and the
            kinetic energy below 1 % of the applied force and of the run's peak at 3 checks 0.02 s
            apart; the loads and drags count as applied forces; a fresh monitor per attempt), the
            displacement criterion's ``(threshold, every)`` per step asked for (with k substeps,
            ``threshold / k`` every ``every * k`` substeps), or a monitor of one attempt;
            ``steps`` is the limit.
        hold_until: no convergence stop before this simulated time (s): give the time of the last
            scripted change (a load that starts or stops, a drag target's last move).
        source: the name error messages start with (default ``sim.source`` or "<simulation>").
        progress: show a progress bar on stderr.
        settings: the dt, steps, integrator and ``safety.unstable`` (a scene's ``Physics``;
            replaces ``unstable``); default: ``sim``'s and the arguments.
        system: the spring system (default ``sim.system``).
        loads, drags: the run's scripted loads and drags (default: ``sim``'s).
        plan: a plan checked already (its note is noted, as :func:`plan_steps`' would be).
        notes: receives the plan's note and each restart's as they happen, if given (the result
            carries them too).
        wording: how the messages name the dt and the policy (:data:`~deformgl.sim.guards.API_WORDING`,
            the default, or the scene keys' :data:`~deformgl.sim.guards.SCENE_WORDING`).
        ctx: the GL context of the watch and the loop (default: the simulation's ``ctx``).
        grid: names a blown-up node's grid index in the message, if given.
        frame_every, on_frame: ``on_frame(step, sim)`` at step 0 and every ``frame_every`` steps
            asked for (with substeps, every ``frame_every * substeps`` substeps, the step counted
            in steps asked for); a restart calls it again from step 0.

    Returns:
        :class:`RunResult`: the steps done (of ``result.dt``: ``substeps`` per step asked for),
        whether it converged and the last check's measures, the substeps, the step, the
        simulation's ``time`` at the end, the notes, the inversion census and the solver's stats.

    Raises:
        SimulationError: the dt is above the limit (and ``unstable`` is "refuse"), or a blow-up at
            the most substeps.
        BlowUp: a blow-up under "refuse", "run" or None.
        ArgumentError: a bad argument, or a restart a plain simulation cannot do.
    """
    make = _maker(sim, source)
    if settings is None:
        if callable(sim) and not hasattr(sim, "step"):
            raise ArgumentError("run: a maker make(dt) needs settings= (dt, steps, integrator, safety) and system=")
        if unstable is not None and unstable not in UNSTABLE_POLICIES:
            raise InputError(f"unstable must be one of {', '.join(UNSTABLE_POLICIES)}, got {unstable!r}")
        _check_counts(steps, check_every)
        settings = _Settings(float(getattr(sim, "base_dt", sim.dt)), int(steps or 0), sim.integrator,
                             _Policy(unstable or "run"))
    steps = settings.steps if steps is None else steps
    _check_counts(steps, check_every)
    if retries is not None and (isinstance(retries, bool) or not isinstance(retries, (int, np.integer)) or retries < 0):
        raise ArgumentError(f"run: retries must be None or an integer >= 0, got {retries!r}")
    system = sim.system if system is None else system
    if limit is None:
        if isinstance(bad_distance, bool) or not (isinstance(bad_distance, (int, float, np.number))
                                                  and math.isfinite(bad_distance) and bad_distance > 0):
            raise ArgumentError(f"run: bad_distance must be a finite number > 0 (rest-box lengths), "
                                f"got {bad_distance!r}")
        rest = system.rest_positions
        limit = bad_distance * float(np.max(rest.max(axis=0) - rest.min(axis=0), initial=0.0) or system.spacing)
    source = getattr(sim, "source", "<simulation>") if source is None else source
    loads = tuple(getattr(sim, "loads", ())) if loads is None else loads
    drags = tuple(getattr(sim, "drags", ())) if drags is None else drags
    if plan is None:  # (unstable None, no settings: no dt check)
        checked = not (unstable is None and isinstance(settings, _Settings))
        plan = plan_steps(system, settings, source, wording=wording) if checked else StepPlan(settings.dt, steps)
    noted: list[str] = [] if notes is None else notes
    first = len(noted)
    if plan.note:
        noted.append(plan.note)

    def attempt(p: StepPlan) -> tuple[RunResult, Simulation]:
        current = make(p.step_dt)
        gl = getattr(current, "ctx", None) if ctx is None else ctx
        stop: Converge | None
        if isinstance(converge, ConvergeRule):
            stop = converge.monitor(system, dt=p.step_dt, substeps=p.substeps, loads=loads, drags=drags,
                                    hold_until=hold_until)
        elif isinstance(converge, tuple):
            stop = DisplacementMonitor(converge[0] / p.substeps, converge[1] * p.substeps, hold_until)
        else:
            stop = converge
        watch = make_watch(gl, current, every=check_every, limit=limit, grid=grid, source=source, dt=p.step_dt,
                           wording=wording)
        hook = None if on_frame is None else (lambda done, s: on_frame(done // p.substeps, s))
        try:
            with Progress(p.step_count, "steps", enabled=progress) as bar:
                return _loop(current, p.step_count, ctx=gl, watch=watch, converge=stop, progress=bar,
                             frame_every=frame_every * p.substeps, on_frame=hook), current
        finally:
            watch.release()

    (result, used_sim), used = retry_with_substeps(plan, settings.safety.unstable, attempt, noted, wording=wording,
                                                   retries=retries)
    solver_note = getattr(used_sim, "solver_note", None)  # an implicit integrator's unconverged solves
    note = solver_note() if callable(solver_note) else None
    if note:
        noted.append(note)
    residual_note(used_sim, noted)
    stats = getattr(used_sim, "solver_stats", None)
    return replace(result, substeps=used.substeps, dt=used.step_dt, time=float(used_sim.time),
                   notes=tuple(noted[first:]), solver=stats() if callable(stats) else None)


def _check_counts(steps, check_every) -> None:
    for name, value in (("steps", steps), ("check_every", check_every)):  # (-1 steps would run none, silently)
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
            raise ArgumentError(f"run: {name} must be an integer >= 0, got {value!r}")


def _maker(sim, source: object) -> Callable[[float], Simulation]:
    """``make(dt)``: the simulation of an attempt at step ``dt``: a restartable simulation
    restarted, a caller's maker called, a plain simulation itself (no restart)."""
    if hasattr(sim, "restart") and hasattr(sim, "backend_simulation"):
        attempts = [0]

        def again(dt: float) -> Simulation:
            # the first attempt at the step sim has goes on; any other starts from the rest state
            if dt != sim.dt or (attempts[0] > 0 and sim.time > 0):
                sim.restart(dt)
            attempts[0] += 1
            return sim.backend_simulation

        return again
    if callable(sim) and not hasattr(sim, "step"):
        return sim
    used = [False]

    def same(dt: float) -> Simulation:
        if dt != sim.dt or used[0]:
            name = getattr(sim, "source", None) if source is None else source
            raise ArgumentError(f"run: {name or '<simulation>'}: a restart at a step of {dt:.4g} s needs a "
                                f"restartable simulation: deformgl.GuardedSimulation(...)")
        used[0] = True
        return sim

    return same


def residual_note(sim: Simulation, notes: list[str]) -> None:
    """Note when an iterative integrator (XPBD) ended with a large relative constraint residual
    (above :data:`deformgl.sim.xpbd.RESIDUAL_NOTE`): its solve did not converge in its iterations."""
    from deformgl.sim.xpbd import RESIDUAL_NOTE

    residual = getattr(sim, "residual", None)
    if isinstance(residual, float) and residual > RESIDUAL_NOTE:
        notes.append(f"{sim.integrator}: relative constraint residual {residual:.3g} after the last step "
                     f"(above {RESIDUAL_NOTE:g}): the solve did not converge in its iterations, so the body is "
                     f"softer than its material; raise physics.xpbd.iterations or substeps")
