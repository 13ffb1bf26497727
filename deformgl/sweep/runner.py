"""Run a sweep's variants: on Dask distributed (a :class:`distributed.LocalCluster` of worker
processes on this machine, one thread and one EGL context each; or an existing cluster by its
scheduler address), or one after another in this process (``workers=0``).

Dask reruns a task whose worker died (the nanny restarts the worker; ``retries`` covers a task
that raised); every variant's files are committed together by the task, so a rerun leaves no half
file, and the runner removes the temporary files a killed worker left. Results are gathered by
variant name: each variant is in the table once.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from deformgl.errors import InputError
from deformgl.files import remove_stale_temporaries
from deformgl.sweep.sweepfile import SweepSpec, Variant
from deformgl.sweep.task import run_variant

__all__ = ["SweepResult", "detect_gpus", "run_sweep", "sweep_client", "sweep_scene"]


def detect_gpus() -> list[int] | None:
    """The EGL device indices to pin LocalCluster workers to when this machine has several
    NVIDIA GPUs (``nvidia-smi -L`` lists two or more: EGL lists the NVIDIA devices first), else
    None (one GPU or none: every worker uses the default device)."""
    import shutil
    import subprocess

    exe = shutil.which("nvidia-smi")
    if exe is None:
        return None
    try:
        listed = subprocess.run([exe, "-L"], capture_output=True, text=True, timeout=20).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    count = sum(1 for line in listed.splitlines() if line.startswith("GPU "))
    return list(range(count)) if count >= 2 else None


@dataclass
class SweepResult:
    """The records in variant order, where they ran, how long the sweep took (s) and how much
    of that was starting the cluster (s)."""

    records: list[dict[str, Any]]
    wall_time_s: float
    workers: int
    where: str
    startup_s: float = 0.0

    @property
    def failed(self) -> list[dict[str, Any]]:
        """The records of the variants that did not finish (with their errors)."""
        return [r for r in self.records if r.get("status") != "ok"]


def _need_dask() -> None:
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise InputError("deformgl sweep on workers needs Dask distributed (the 'sweep' extra: "
                         "pip install 'deformgl[sweep]'); --workers 0 runs the variants in this process") from None


def sweep_client(workers: int = 2, scheduler: str | None = None):
    """A Dask client: of the cluster at ``scheduler``, or of a new LocalCluster of ``workers``
    processes of one thread each (the caller closes the client and ``client.cluster``)."""
    _need_dask()
    from distributed import Client, LocalCluster

    if scheduler is not None:
        client = Client(scheduler)
    else:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                               silence_logs=40)
        client = Client(cluster)
    return client


def run_sweep(spec: SweepSpec, out: str | os.PathLike[str], *, workers: int = 2, scheduler: str | None = None,
              client=None, devices: Sequence[int] | None = None, retries: int = 2,
              on_result: Callable[[dict[str, Any]], None] | None = None, ctx=None) -> SweepResult:
    """Run every variant of ``spec`` writing into the folder ``out``; returns their records.

    Args:
        workers: worker processes of the LocalCluster (0: in this process, one after another).
        scheduler: the address of an existing Dask scheduler (``tcp://host:8786``) instead.
        client: an existing :class:`distributed.Client` (the caller's; not closed).
        devices: EGL device indices to pin the workers to: worker NAME (a LocalCluster's are 0, 1,
            ...; a worker the nanny restarts keeps its name) renders on ``devices[NAME % len]``
            through ``DEFORMGL_DEVICE`` (default for a LocalCluster: :func:`detect_gpus`; a remote
            cluster's workers keep their own ``DEFORMGL_DEVICE`` unless ``devices`` is given).
        retries: reruns of a task that raised (a worker that died is rerun by the scheduler).
        on_result: called with each record as it arrives.
        ctx: with ``workers=0``, the GL context to render in (default: one made and released here).
    """
    if workers or scheduler is not None or client is not None:
        _need_dask()  # before any work or folder
    folder = Path(out)
    if not folder.is_dir():
        try:
            folder.mkdir(parents=True)
        except OSError as exc:
            raise InputError(f"{folder}: cannot create the sweep folder: {exc.strerror or exc}") from None
    started_at, started = time.time(), time.perf_counter()
    args = [(str(spec.scene), v.overrides, str(folder), v.name, spec.outputs) for v in spec.variants]
    by_name: dict[str, dict[str, Any]] = {}

    def got(variant: Variant, record: dict[str, Any]) -> None:
        record["label"] = variant.label
        by_name[variant.name] = record
        if on_result is not None:
            on_result(record)

    if workers == 0 and client is None and scheduler is None:
        from deformgl.gl.context import create_context

        gl = create_context(None) if ctx is None else ctx
        try:
            for variant, a in zip(spec.variants, args):
                got(variant, run_variant(*a, ctx=gl))
        finally:
            if ctx is None:
                gl.release()
        where, count, startup = "this process", 0, 0.0
    else:
        own = client is None
        client = sweep_client(workers, scheduler) if own else client
        if devices is None and own and scheduler is None:
            devices = detect_gpus()
        pin = tuple(int(d) for d in devices) if devices else None
        startup = time.perf_counter() - started
        try:
            from distributed import as_completed

            futures = {client.submit(run_variant, *a, devices=pin, key=f"deformgl-{v.name}-{os.getpid()}-{started_at:.0f}",
                                     retries=retries, pure=False): v for v, a in zip(spec.variants, args)}
            for future in as_completed(futures):
                variant = futures[future]
                try:
                    got(variant, future.result())
                except Exception as exc:  # the task could not finish on any worker (KilledWorker)
                    got(variant, {"variant": variant.name, "status": "failed", "overrides": variant.overrides,
                                  "error": f"{type(exc).__name__}: {exc}"})
            count = len(client.scheduler_info()["workers"])
            where = scheduler or "LocalCluster"
        finally:
            if own:
                cluster = getattr(client, "cluster", None)
                client.close()
                if cluster is not None:
                    cluster.close()
    remove_stale_temporaries(folder, before=time.time())  # what killed workers left
    return SweepResult([by_name[v.name] for v in spec.variants], time.perf_counter() - started, count, where,
                       startup)


def sweep_scene(scene: str | os.PathLike[str], out: str | os.PathLike[str], *, product: dict[str, list[Any]] | None = None,
          variants: Sequence[dict[str, Any]] | None = None, common: dict[str, Any] | None = None,
          outputs: Sequence[str] = ("png", "record"), workers: int = 2, scheduler: str | None = None, client=None,
          devices: Sequence[int] | None = None, table: bool = True, ctx=None, on_result: Callable[[dict[str, Any]], None] | None = None) -> SweepResult:
    """A sweep from Python, without a sweep file: ``scene`` over the ``product`` of values and/or
    the ``variants`` (dicts of dotted scene keys; a ``"name"`` key names one), every variant with
    ``common`` set; run as :func:`run_sweep` runs it, and with ``table`` the CSV, JSON and
    contact sheet written into ``out``. Returns the :class:`SweepResult` (its records are dicts)."""
    import itertools

    from deformgl.sweep.sweepfile import OUTPUT_KINDS, _label

    if not all(o in OUTPUT_KINDS for o in outputs):
        raise InputError(f"outputs: must be among {', '.join(OUTPUT_KINDS)}, got {list(outputs)}")
    found: list[tuple[str | None, dict[str, Any]]] = []
    if product:
        keys = list(product)
        found += [(None, dict(zip(keys, values))) for values in itertools.product(*(product[k] for k in keys))]
    for v in variants or ():
        own = dict(v)
        found.append((own.pop("name", None), own))
    if not found:
        raise InputError("sweep: no variants (give product values or variants)")
    width = max(2, len(str(len(found) - 1)))
    from deformgl.data import find_scene  # (the CLI's lookup: a shipped scene by name)

    found_scene = find_scene(scene).resolve()
    spec = SweepSpec(found_scene, found_scene,
                     tuple(Variant(name or f"v{i:0{width}d}", _label(own), {**(common or {}), **own})
                           for i, (name, own) in enumerate(found)), tuple(outputs))
    result = run_sweep(spec, out, workers=workers, scheduler=scheduler, client=client, devices=devices, ctx=ctx,
                       on_result=on_result)
    if table:
        from deformgl.sweep.sheet import write_tables

        write_tables(result.records, Path(out), sheet="png" in outputs)
    return result
