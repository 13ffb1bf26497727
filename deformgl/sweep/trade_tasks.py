"""``deformgl bench trade --workers N`` (or ``--scheduler ADDRESS``): the trade study's workloads
as Dask tasks, one per workload, each in a worker with its own EGL context, gathered into one
:class:`~deformgl.bench.trade.TradeReport` in the in-process order. The errors are the in-process
study's; the costs, measured with the workloads running together, compare within a run only."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime, timezone

from deformgl.bench.trade import BACKENDS, TradeReport, standard_workloads, trade_study
from deformgl.sim.integrators import EXPLICIT_INTEGRATORS
from deformgl.sweep.runner import sweep_client

__all__ = ["distributed_trade"]


def _workload_study(index: int, quick: bool, backends: tuple[str, ...],
                    fractions: tuple[float, ...] | None) -> TradeReport:
    from deformgl.sweep.task import _context

    workload = standard_workloads()[index]
    return trade_study(_context(), backends=backends, quick=quick, workloads=[workload], fractions=fractions)


def distributed_trade(*, quick: bool = False, backends: Sequence[str] = BACKENDS,
                      fractions: Sequence[float] | None = None, workers: int = 2, scheduler: str | None = None,
                      client=None) -> TradeReport:
    """The trade study with one Dask task per workload (see the module docstring); a worker
    that dies is replaced and its workload rerun."""
    own = client is None
    client = sweep_client(workers, scheduler) if own else client
    try:
        count = len(standard_workloads())
        nworkers = len(client.scheduler_info()["workers"])
        futures = [client.submit(_workload_study, i, quick, tuple(backends),
                                 None if fractions is None else tuple(fractions), retries=2, pure=False)
                   for i in range(count)]
        parts: list[TradeReport] = client.gather(futures)
    finally:
        if own:
            cluster = getattr(client, "cluster", None)
            client.close()
            if cluster is not None:
                cluster.close()
    names = [p.rows[0].workload if p.rows else p.references[0].workload for p in parts]
    rows = [r for p in parts for r in p.rows]
    rows.sort(key=lambda r: (names.index(r.workload), list(backends).index(r.backend),
                             EXPLICIT_INTEGRATORS.index(r.integrator), r.steps))
    machine = parts[0].machine + f"; {count} workloads on {nworkers} Dask workers at once"
    return TradeReport(rows, machine, datetime.now(timezone.utc).isoformat(timespec="seconds"), parts[0].sim_time,
                       [ref for p in parts for ref in p.references])
