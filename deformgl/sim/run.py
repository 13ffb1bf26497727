"""The one run loop: any :class:`~deformgl.sim.simulation.Simulation`, any backend.

:func:`run` steps in chunks (the progress bar moves between them), checks for blown-up nodes
every ``watch.every`` steps and once at the end, and stops early when no node moved more than a
threshold in one step (Movania & Feng 2012, section 4), tested every ``converge[1]`` steps. On
the GPU backends the checks are census queries (:class:`~deformgl.sim.guards.BlowUpWatch`,
:class:`~deformgl.sim.census.NodeCensus`), nothing is read back unless a check fails; on the
NumPy backend they are the same tests on the float64 arrays. Converged means "every node moved
<= threshold" on every backend.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deformgl.sim.guards import BlowUpWatch, Watch

__all__ = ["RunResult", "NumpyWatch", "make_watch", "run"]


@dataclass(frozen=True)
class RunResult:
    """What :func:`run` did.

    Attributes:
        steps: steps done.
        converged: True/False; None without a convergence stop.
    """

    steps: int
    converged: bool | None


class NumpyWatch(Watch):
    """:class:`~deformgl.sim.guards.Watch` for a simulation without GPU state: the same schedule
    and message, counted on ``sim.positions()``."""

    def __init__(self, sim, *, every: int, limit: float, grid=None, source=None, dt: float | None = None) -> None:
        super().__init__(sim, every=every, limit=limit, grid=grid, source=source, dt=sim.dt if dt is None else dt)


def make_watch(ctx, sim, *, every: int, limit: float, grid=None, source=None, dt: float | None = None):
    """The blow-up watch that fits ``sim``: census queries on the GPU, NumPy otherwise."""
    dt = sim.dt if dt is None else dt
    if sim.position_slot() is None:
        return NumpyWatch(sim, every=every, limit=limit, grid=grid, source=source, dt=dt)
    return BlowUpWatch(ctx, sim, every=every, limit=limit, grid=grid, source=source, dt=dt)


class _NoBar:
    def update(self, done: int) -> None:
        pass


def run(sim, steps: int, *, ctx=None, watch=None, converge: tuple[float, int] | None = None,
        progress=None, chunk: int = 25) -> RunResult:
    """``steps`` steps of ``sim`` with the guards and the convergence stop.

    Args:
        sim: a :class:`~deformgl.sim.simulation.Simulation`.
        steps: steps to run.
        ctx: the GL context (GPU backends; default ``sim.ctx``).
        watch: a :func:`make_watch` watch, or None for no blow-up checks.
        converge: ``(threshold, every)``: stop when no node moved more than threshold in the
            step ending at a multiple of ``every``.
        progress: anything with ``update(done)`` (a :class:`~deformgl.progress.Progress`).
        chunk: most steps between progress updates on the GPU (the NumPy backend checks every
            step for non-finite positions, so it steps one at a time).

    Raises:
        BlowUp: a check counted bad nodes.
    """
    bar = _NoBar() if progress is None else progress
    gpu = sim.position_slot() is not None
    ctx = getattr(sim, "ctx", None) if ctx is None else ctx
    if not gpu:
        chunk = 1
    census = None
    if converge is not None and gpu:
        from deformgl.sim.census import NodeCensus

        _, row, slots, _ = sim.position_slot()
        census = NodeCensus(ctx, count=sim.count, row=row, slots=slots)
    try:
        done = 0
        while done < steps:
            target = min(done + chunk, steps, watch.next_stop(done, steps) if watch else steps)
            check_convergence = False
            if converge is not None:
                at = (done // converge[1] + 1) * converge[1]
                if at <= target:
                    target, check_convergence = at, True
            before = None
            if check_convergence and census is not None:  # (census: converging on the GPU)
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
            if check_convergence and converge is not None:  # (checks only when converging)
                if census is not None and before is not None:  # (both set on the GPU path)
                    now, _, _, slot = sim.position_slot()
                    still = census.moved(now, before, converge[0], slot=slot, before_slots=1) == 0
                else:
                    still = sim.last_moved <= converge[0]
                if still:
                    if watch is not None and not watch.due(done):
                        watch.check(done)
                    return RunResult(done, True)
        return RunResult(steps, None if converge is None else False)
    finally:
        if census is not None:
            census.release()
