"""``deformgl sweep SWEEP.toml``: the command's parser and its run (wired by :mod:`deformgl.cli`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from deformgl.errors import InputError

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    """Add ``sweep`` to the subcommands."""
    s = sub.add_parser(
        "sweep", help="run a scene over a set or product of overrides on Dask workers",
        description="Run a scene over the variants of a sweep file (any scene keys, as a [product] and/or "
                    "[[variant]] tables), each rendered and measured, on Dask distributed: a LocalCluster of "
                    "worker processes here (one EGL context each), or an existing cluster (--scheduler). "
                    "Writes NAME.png / .json / .ply per variant, sweep.csv, sweep.json and the contact sheet "
                    "sweep.png. A variant that fails is a row with its error; a worker that dies is replaced "
                    "and its task rerun.")
    s.add_argument("sweep", type=Path, help="sweep file (.toml)")
    s.add_argument("-o", "--out", type=Path, default=None,
                   help="output folder (default: SWEEP_NAME in the working directory)")
    s.add_argument("--workers", type=int, default=2,
                   help="worker processes of the LocalCluster (default 2; 0: run in this process, no Dask)")
    s.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="use an existing Dask cluster, e.g. tcp://10.0.0.5:8786, instead of a LocalCluster")
    s.add_argument("--devices", default=None, metavar="I,J,...",
                   help="EGL devices to pin the workers to (DEFORMGL_DEVICE; worker i gets the (i mod n)-th), e.g. "
                        "0,1,2,3 (default: every NVIDIA GPU when nvidia-smi lists several)")
    s.add_argument("--baseline", action="store_true",
                   help="first run every variant in this process, then on the workers, and print the ratio")
    s.add_argument("--no-sheet", action="store_true", help="no contact sheet")
    s.add_argument("--quiet", action="store_true", help="no line per finished variant")


def run(args: argparse.Namespace) -> int:
    from deformgl.sweep.runner import run_sweep
    from deformgl.sweep.sheet import write_tables
    from deformgl.sweep.sweepfile import load_sweep

    spec = load_sweep(args.sweep)
    if args.workers < 0:
        raise InputError(f"--workers: must be >= 0, got {args.workers}")
    devices = None
    if args.devices:
        try:
            devices = [int(d) for d in args.devices.split(",")]
        except ValueError:
            raise InputError(f"--devices: expected GPU indices such as 0,1; got {args.devices!r}") from None
    out = args.out or Path(args.sweep.stem)
    total = len(spec.variants)

    def note(record) -> None:
        if not args.quiet:
            done = f"{record.get('wall_time_s', 0) or 0:.2f} s" if record.get("status") == "ok" else record.get("error")
            print(f"[sweep] {record['variant']} ({record.get('label', '')}): {record.get('status')}: {done}",
                  file=sys.stderr, flush=True)

    serial = None
    if args.baseline:
        serial = run_sweep(spec, out / "baseline", workers=0, on_result=note)
    result = run_sweep(spec, out, workers=args.workers, scheduler=args.scheduler, devices=devices, on_result=note)
    paths = write_tables(result.records, out, sheet=not args.no_sheet)
    ok = total - len(result.failed)
    print(f"deformgl: sweep of {total} variants on {result.where} ({result.workers or 1} worker"
          f"{'s' if result.workers != 1 else ''}): {ok} ok, {len(result.failed)} failed, "
          f"{result.wall_time_s:.2f} s wall", file=sys.stderr)
    if serial is not None:
        running = result.wall_time_s - result.startup_s
        print(f"baseline: {total} variants in this process {serial.wall_time_s:.2f} s; on {result.workers} "
              f"workers {result.wall_time_s:.2f} s ({result.startup_s:.2f} s of it starting the cluster); speed-up "
              f"{serial.wall_time_s / result.wall_time_s:.2f}x, {serial.wall_time_s / running:.2f}x without the "
              f"start-up")
    print("wrote " + ", ".join(map(str, paths)))
    return 0
