"""``deformgl bench sim|trade``: its flags and its dispatch to :mod:`deformgl.bench` (and, for
``bench trade --workers``, to :mod:`deformgl.sweep`). Part of the command line (the ``cli`` layer):
the work is in the layers below. The studies that were ``bench`` choices are commands of the
repository's ``studies/`` folder (:data:`MOVED`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from deformgl.errors import DeformglError, InputError


#: The former ``bench`` choices and flags and the repository command that prints their tables now.
MOVED = {"render": "python -m studies.render_speed", "binding": "python -m studies.binding_speed",
         "trilinear": "python -m studies.trilinear_speed", "integrators": "python -m studies.integrator_speed",
         "mappings": "python -m studies.mapping_accuracy", "scaling": "python -m studies.scaling",
         "profile": "python -m studies.step_profile", "accuracy": "python -m studies.accuracy",
         "animation": "python -m studies.animation_frames", "--bending": "python -m studies.bending_cost",
         "--poisson": "python -m studies.cells_cost"}


def _nus(text: str) -> tuple[float, ...]:
    """``--poisson 0.25,0.45``: Poisson's ratios in [0.25, 0.499] (argparse's type)."""
    try:
        nus = tuple(float(t) for t in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected numbers separated by commas, got {text!r}") from None
    bad = [nu for nu in nus if not 0.25 <= nu <= 0.499]
    if bad:
        raise argparse.ArgumentTypeError(f"Poisson's ratio {bad[0]:g} outside [0.25, 0.499] (the lattice's range)")
    return nus


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``bench`` subcommand."""
    b = sub.add_parser("bench", help="benchmarks, printed as ratios against a baseline",
                       description="Benchmarks. Figures are ratios against a baseline measured in "
                                   "the same run, with the machine and renderer named.")
    b.add_argument("what", metavar="{sim,trade}",
                   help="sim: the fragment backend's Verlet step (compact and blocked layout) against the NumPy "
                        "reference on 4k to 131k nodes; trade: error against cost per simulated second for every "
                        "integrator x dt (0.1 to 0.9 of the stability limit) x backend on a dragged volume and a cloth "
                        "on a sphere, with the Pareto front. The studies behind docs/ACCURACY.md and "
                        "docs/PERFORMANCE.md (render, binding, trilinear, integrators, mappings, scaling, profile, "
                        "accuracy, animation) are commands of the repository's studies/ folder: python -m studies.NAME")
    b.add_argument("--steps", type=int, default=40, help="sim: steps per timing (default 40)")
    b.add_argument("--peers", action="store_true",
                   help="sim: also run the same 18-neighbour Verlet step in Taichi (CPU), NVIDIA Warp (CPU) and Numba (CPU) "
                        "on the 20k and 131k grids (needs the 'peers' extra: pip install 'deformgl[peers]')")
    b.add_argument("--blocks", action="store_true",
                   help="sim: instead, the foundation step with several nodes per fragment (every block shape) "
                        "against the compact layout on 2k to 131k nodes and the heart scene's body")
    b.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    b.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="trade: also write trade.csv, .json and, with the 'plot' extra, the chart .png into DIR "
                        "(--resolution: resolution.*, --stiff: stiff.*)")
    b.add_argument("--resolution", action="store_true",
                   help="trade: instead, the grid-resolution study: the FEM-checked cantilever at several grid "
                        "resolutions x integrator x dt, its error against FEM split into discretisation, time "
                        "stepping and float32, against the fragment backend's cost per simulated second")
    b.add_argument("--stiff", action="store_true",
                   help="trade: instead, implicit Euler (Jacobi and multigrid CG) and XPBD against Verlet and "
                        "semi-implicit Euler at their limits on a tissue block at E = 3 kPa and 1 MPa: wall time per "
                        "simulated second and to a converged sag, the error against FEM statics, implicit Euler's "
                        "damping (--out DIR: stiff.csv, .json, .png)")
    b.add_argument("--poisson", type=_nus, default=None, metavar="NU[,NU...]",
                   help="trade: Poisson's ratio as a workload axis: also a 6x6x6 liver block (E = 4 kPa) at each of "
                        "these ratios (0.25 to 0.499), e.g. 0.25,0.45")
    b.add_argument("--bending", action="store_true", help=argparse.SUPPRESS)  # moved: MOVED["--bending"]
    b.add_argument("--quick", action="store_true", help="trade: a smaller, faster study")
    b.add_argument("--workers", type=int, default=0,
                   help="trade: run its workloads as tasks on a Dask LocalCluster of this many worker processes "
                        "(the 'sweep' extra; default 0: in this process)")
    b.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="trade: run its workloads on an existing Dask cluster")


def _chart(write) -> None:
    """Write a chart; without matplotlib say so on stderr (the tables and files are written)."""
    try:
        write()
    except DeformglError as exc:
        print(f"deformgl: no chart: {exc}", file=sys.stderr)


def _trade(args: argparse.Namespace, ctx, note) -> None:
    """``bench trade``: the table, and with ``--out`` the CSV, JSON and chart,
    each written atomically."""
    from deformgl.bench.sim_speed import machine_line
    from deformgl.files import OutputSet

    out = args.out
    # the study's CSV, JSON and chart: checked before the study runs, written together or not at all
    outputs = OutputSet([out / f"trade.{ext}" for ext in ("csv", "json", "png")] if out else [])
    if args.stiff:
        from deformgl.bench.trade_stiff import format_stiff, stiff_cases, stiff_study

        outputs = OutputSet([out / f"stiff.{ext}" for ext in ("csv", "json", "png")] if out else [])
        cases = stiff_cases(args.quick)
        stiff_rows = stiff_study(ctx, quick=args.quick, progress=note, cases=cases)
        print(format_stiff(stiff_rows, machine_line(ctx), cases))
        if out is not None:
            from deformgl.bench import stiff_files

            with outputs:
                stiff_files.write_csv(out / "stiff.csv", stiff_rows)
                stiff_files.write_json(out / "stiff.json", stiff_rows, cases, machine_line(ctx))
                _chart(lambda: stiff_files.write_chart(out / "stiff.png", stiff_rows, machine_line(ctx)))
        return
    if args.resolution:
        from deformgl.bench.resolution import resolution_study

        outputs = OutputSet([out / f"resolution.{ext}" for ext in ("csv", "json", "png")] if out else [])
        res = resolution_study(ctx, quick=args.quick, progress=note)
        print(res.format())
        if out is not None:
            with outputs:
                res.write_csv(out / "resolution.csv")
                res.write_json(out / "resolution.json")
                _chart(lambda: res.write_chart(out / "resolution.png"))
    else:
        from deformgl.bench.trade import trade_study

        if args.workers or args.scheduler:
            from deformgl.sweep.runner import _need_dask
            from deformgl.sweep.trade_tasks import distributed_trade

            _need_dask()
            report = distributed_trade(quick=args.quick, workers=args.workers or 2, scheduler=args.scheduler)
        else:
            extra: dict[str, Any] = {}
            if args.poisson:  # the standard workloads and the tissue's at each nu asked for
                from deformgl.bench.trade import standard_workloads
                from deformgl.bench.trade_tissue import tissue_workloads

                extra["workloads"] = standard_workloads() + tissue_workloads(args.poisson)
            report = trade_study(ctx, quick=args.quick, progress=note, **extra)
        print(report.format())
        if out is not None:
            with outputs:
                report.write_csv(out / "trade.csv")
                report.write_json(out / "trade.json")
                _chart(lambda: report.write_chart(out / "trade.png"))


def _check(args: argparse.Namespace) -> None:
    """The flags' one-line errors, before any work; a former choice names its new command."""
    if args.what in MOVED:
        raise InputError(f"bench {args.what}: moved out of the package to the repository's studies "
                         f"(in a clone: {MOVED[args.what]}); deformgl bench runs sim and trade")
    if args.what not in ("sim", "trade"):
        raise InputError(f"bench: unknown benchmark {args.what!r} (choose sim or trade)")
    if args.steps < 1:
        raise InputError(f"--steps: must be >= 1, got {args.steps}")
    if args.out is not None and not args.out.is_dir():
        raise InputError(f"--out: {args.out} is not a folder")
    if args.stiff and (args.what != "trade" or args.resolution):
        raise InputError("--stiff: only for bench trade, without --resolution")
    if args.resolution and args.what != "trade":
        raise InputError(f"--resolution: only for bench trade, not bench {args.what}")
    if args.what == "sim" and (args.bending or args.poisson):
        flag = "--bending" if args.bending else "--poisson"
        raise InputError(f"bench sim {flag}: moved out of the package to the repository's studies "
                         f"(in a clone: {MOVED[flag]})")
    if args.bending:
        raise InputError(f"--bending: not a flag of bench {args.what}")
    if (args.workers or args.scheduler) and args.poisson:
        raise InputError("bench trade: --poisson runs in this process only (not with --workers or --scheduler)")
    if (args.peers or args.blocks) and args.what != "sim":
        raise InputError(f"--{'peers' if args.peers else 'blocks'}: only for bench sim, not bench {args.what}")


def run(args: argparse.Namespace) -> int:
    """``deformgl bench sim|trade``."""
    _check(args)
    from deformgl.bench.sim_speed import bench_sim, format_sim, machine_line
    from deformgl.gl.context import create_context

    ctx = create_context(args.device)
    note = None if args.quiet else (lambda name: print(f"[bench] {name} ...", file=sys.stderr, flush=True))
    try:
        if args.what == "trade":
            _trade(args, ctx, note)
        elif args.blocks:
            from deformgl.bench.sim_blocks import blocks_report

            print(blocks_report(ctx, steps=args.steps))
        else:
            print(format_sim(bench_sim(ctx, steps=args.steps), machine_line(ctx)), flush=True)
            if args.peers:
                from deformgl.bench.sim_speed import peers_report

                print()
                print(peers_report(ctx, steps=args.steps))
    finally:
        ctx.release()
    return 0
