"""``deformgl bench``: its flags and its dispatch to the studies of :mod:`deformgl.bench` (and, for
``bench trade --workers``, to :mod:`deformgl.sweep`). Part of the command line (the ``cli`` layer):
the work is in the layers below."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from deformgl.data import scene_file as _scene_file
from deformgl.errors import DeformglError, InputError


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
    b.add_argument("what", choices=["sim", "render", "binding", "trilinear", "integrators", "trade", "mappings",
                                    "scaling", "profile", "accuracy", "animation"],
                   help="sim: fragment-pass step vs the NumPy reference, then the integrators table; render: draw paths of the "
                        "heart-scale scene vs the static mesh, and a 15-step + draw frame; binding: "
                        "binding time of 23k- and 50k-vertex meshes to a 20k-node grid; trilinear: "
                        "linear vs trilinear frames/s for the paper's three set-ups; integrators: "
                        "each integrator on each backend (fragment, feedback, numpy) on 64^2 ... 2048^2 "
                        "cloths and 20k / 131k-node volumes, against the fragment Verlet baseline; trade: error "
                        "against cost per simulated second for every integrator x dt (0.1 to 0.9 of the "
                        "stability limit) x backend on a dragged volume and a cloth on a sphere, with the "
                        "Pareto front; mappings: each mapping's error against an analytic bend and twist, and "
                        "its draw time; scaling: ms/step from 4k to 1M nodes, the fitted exponent, bytes/node; "
                        "profile: the step pass rebuilt stage by stage (own texels, neighbour lookup, 18 "
                        "neighbour fetches, spring sums), what each costs; accuracy: the calibrated lattice's static "
                        "equilibrium against converged hexahedral FEM (cantilever, compressed block, twisted bar) "
                        "at 2 to 17 nodes across, with the fitted order (needs the 'fem' extra: pip install "
                        "'deformgl[fem]'); animation: an N-frame animation from one "
                        "run against a still and against N stills each simulated from step 0 (--scene, default the "
                        "shipped dragon_motion.toml)")
    b.add_argument("--steps", type=int, default=40, help="sim: steps per timing (default 40)")
    b.add_argument("--peers", action="store_true",
                   help="sim: also run the same 18-neighbour Verlet step in Taichi (CPU), NVIDIA Warp (CPU) and Numba (CPU) "
                        "on the 20k and 131k grids (needs the 'peers' extra: pip install 'deformgl[peers]')")
    b.add_argument("--blocks", action="store_true",
                   help="sim: instead, the foundation step with several nodes per fragment (every block shape) "
                        "against the compact layout on 4k to 131k nodes and the heart scene, and the heart frame")
    b.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    b.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="trade, mappings, scaling: also write WHAT.csv and WHAT.json into DIR (trade --resolution: "
                        "resolution.*, trade --stiff: stiff.*) (and WHAT.png, "
                        "the chart, with the 'plot' extra: pip install 'deformgl[plot]')")
    b.add_argument("--resolution", action="store_true",
                   help="trade: instead, the grid-resolution study: the FEM-checked cantilever at several grid "
                        "resolutions x integrator x dt, its error against FEM split into discretisation, time "
                        "stepping and float32, against the fragment backend's cost per simulated second")
    b.add_argument("--stiff", action="store_true",
                   help="trade: instead, implicit Euler (dt 1/60 ... 1/1000 s x CG iterations) and XPBD "
                        "(iterations x substeps) against Verlet and semi-implicit Euler at their limits on a tissue "
                        "block at E = 3 kPa (5, 9 across) and 1 MPa (5 to 33 across): wall time per simulated second "
                        "and to a converged sag (every node within 0.05 h, and within 5 %% of the sag, of the "
                        "equilibrium), the error against FEM statics, implicit Euler's damping of the lowest mode and "
                        "CG iterations with the Jacobi, block-Jacobi and multigrid preconditioners; implicit Euler runs "
                        "with Jacobi and with multigrid (--out DIR: stiff.csv, "
                        "stiff.json, stiff.png); then (not with --quick) "
                        "the heart-scale scene (--scene) in 60 Hz frames per second, implicit at dt 1/60 s vs explicit")
    b.add_argument("--poisson", type=_nus, default=None, metavar="NU[,NU...]",
                   help="trade: Poisson's ratio as a workload axis: also a 6x6x6 liver block (E = 4 kPa) at each of "
                        "these ratios (0.25 to 0.499), e.g. 0.25,0.45; sim: instead of its tables, the cost per "
                        "step of the cells' volumetric term at these ratios against nu = 1/4 on the fragment backend")
    b.add_argument("--bending", action="store_true",
                   help="sim: instead of its tables, the cost per step of a cloth's bending stiffness (the plate "
                        "term) against flexion springs and a membrane on the fragment backend")
    b.add_argument("--quick", action="store_true",
                   help="trade, scaling: a smaller, faster study; binding: one timing per case instead of three")
    b.add_argument("--workers", type=int, default=0,
                   help="trade: run its workloads as tasks on a Dask LocalCluster of this many worker processes "
                        "(the 'sweep' extra; default 0: in this process)")
    b.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="trade: run its workloads on an existing Dask cluster")
    b.add_argument("--scene", type=Path, default=None,
                   help="render: the scene to draw (default: the shipped dragon_heart_scale.toml); mappings: the scene whose "
                        "mesh, camera and light are used (default: the shipped dragon_bend_constant.toml)")


def _chart(write) -> None:
    """Write a chart; without matplotlib say so on stderr (the tables and files are written)."""
    try:
        write()
    except DeformglError as exc:
        print(f"deformgl: no chart: {exc}", file=sys.stderr)


def _study(args: argparse.Namespace, ctx, note) -> None:
    """``bench trade|mappings|scaling``: the table, and with ``--out`` the CSV, JSON and chart,
    each written atomically."""
    from deformgl.bench.studies import machine_line
    from deformgl.files import OutputSet

    out = args.out
    # the study's CSV, JSON and chart: checked before the study runs, written together or not at all
    outputs = OutputSet([out / f"{args.what}.{ext}" for ext in ("csv", "json", "png")] if out else [])
    if args.what == "trade" and args.stiff:
        from deformgl.bench.implicit import format_stiff, stiff_cases, stiff_study

        from deformgl.bench.implicit import format_preconditioners, preconditioner_bodies, preconditioner_iterations

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
        print()
        print(format_preconditioners(preconditioner_iterations(preconditioner_bodies(cases, args.quick))))
        if not args.quick:  # the heart-scale scene in real time (--scene: another one)
            from deformgl.bench.implicit import format_realtime, realtime

            heart = str(args.scene) if args.scene else "dragon_heart_scale.toml"
            timing, gap, nodes = realtime(ctx, heart, progress=note)
            print()
            print(format_realtime(timing, gap, nodes, heart, machine_line(ctx)))
        return
    if args.what == "trade" and args.resolution:
        from deformgl.bench.resolution import resolution_study

        outputs = OutputSet([out / f"resolution.{ext}" for ext in ("csv", "json", "png")] if out else [])
        res = resolution_study(ctx, quick=args.quick, progress=note)
        print(res.format())
        if out is not None:
            with outputs:
                res.write_csv(out / "resolution.csv")
                res.write_json(out / "resolution.json")
                _chart(lambda: res.write_chart(out / "resolution.png"))
    elif args.what == "trade":
        from deformgl.bench.trade import trade_study

        if (args.workers or args.scheduler) and args.poisson:
            raise InputError("bench trade: --poisson runs in this process only (not with --workers or --scheduler)")
        if args.workers or args.scheduler:
            from deformgl.sweep.runner import _need_dask
            from deformgl.sweep.trade import distributed_trade

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
    elif args.what == "mappings":
        from deformgl.bench.mapping_accuracy import (DEFAULT_SCENE, format_mapping_accuracy, mapping_accuracy,
                                                     write_chart, write_csv, write_json)
        scene = _scene_file(args.scene, "--scene") if args.scene else DEFAULT_SCENE  # the shipped scene
        rows = mapping_accuracy(ctx, scene_path=scene)
        print(format_mapping_accuracy(rows, machine_line(ctx)))
        if out is not None:
            with outputs:
                write_csv(out / "mappings.csv", rows)
                write_json(out / "mappings.json", rows, machine_line(ctx))
                _chart(lambda: write_chart(out / "mappings.png", rows, machine_line(ctx)))
    else:
        from deformgl.bench.scaling import QUICK_SIZES, bench_scaling

        scaling = (bench_scaling(ctx, progress=note, sizes=QUICK_SIZES) if args.quick
                   else bench_scaling(ctx, progress=note))
        print(scaling.format())
        if out is not None:
            with outputs:
                scaling.write_csv(out / "scaling.csv")
                scaling.write_json(out / "scaling.json")
                _chart(lambda: scaling.write_chart(out / "scaling.png"))


def run(args: argparse.Namespace) -> int:
    """``deformgl bench WHAT``."""
    if args.steps < 1:
        raise InputError(f"--steps: must be >= 1, got {args.steps}")
    if args.out is not None and not args.out.is_dir():
        raise InputError(f"--out: {args.out} is not a folder")
    if args.stiff and (args.what != "trade" or args.resolution):
        raise InputError("--stiff: only for bench trade, without --resolution")
    if args.resolution and args.what != "trade":
        raise InputError(f"--resolution: only for bench trade, not bench {args.what}")
    if args.bending and (args.what != "sim" or args.poisson):
        raise InputError(f"--bending: only for bench sim, without --poisson (not bench {args.what})")
    if args.what == "accuracy":  # CPU only: no GL context
        from deformgl.bench.accuracy import run_cli

        return run_cli(args)
    from deformgl.bench.studies import bench_render, bench_sim, format_render, format_sim, machine_line
    from deformgl.gl.context import create_context

    ctx = create_context(args.device)
    try:
        if args.what in ("sim", "integrators"):
            from deformgl.bench.studies import bench_integrators, format_integrators

            if args.what == "sim" and args.bending:
                from deformgl.bench.bending_cost import bench_bending, format_bending

                print(format_bending(bench_bending(ctx, steps=args.steps), machine_line(ctx)))
                return 0
            if args.what == "sim" and args.blocks:
                from deformgl.bench.blocks import blocks_report

                print(blocks_report(ctx, steps=args.steps))
                return 0
            if args.what == "sim" and args.poisson:
                from deformgl.bench.cells_cost import bench_poisson, cg_iterations, format_cg, format_poisson

                print(format_poisson(bench_poisson(ctx, args.poisson, steps=args.steps), machine_line(ctx)))
                print()
                print(format_cg(cg_iterations(args.poisson)))
                return 0
            if args.what == "sim":
                print(format_sim(bench_sim(ctx, steps=args.steps), machine_line(ctx)), flush=True)
                print()
            note = None if args.quiet else (lambda name: print(f"[bench] {name} ...", file=sys.stderr, flush=True))
            print(format_integrators(bench_integrators(ctx, steps=min(args.steps, 20), progress=note),
                                     machine_line(ctx)))
            if args.peers:
                from deformgl.bench.studies import peers_report

                print()
                print(peers_report(ctx, steps=args.steps))
        elif args.what in ("trade", "mappings", "scaling"):
            note = None if args.quiet else (lambda name: print(f"[bench] {name} ...", file=sys.stderr, flush=True))
            _study(args, ctx, note)
        elif args.what == "animation":
            from deformgl.bench.animation import bench_animation
            from deformgl.data import packaged_scene

            scene = _scene_file(args.scene, "--scene") if args.scene else packaged_scene("dragon_motion")
            print(bench_animation(ctx, scene))
        elif args.what == "profile":
            from deformgl.bench.profile import profile_report

            print(profile_report(ctx))
        elif args.what == "trilinear":
            from deformgl.bench.trilinear import trilinear_bench_report

            print(trilinear_bench_report(ctx))
        elif args.what == "binding":
            from deformgl.bench.binding import bench_binding

            print(machine_line(ctx))
            print(bench_binding(repeats=1 if args.quick else 3))  # the shipped mesh, installed or not
        else:
            from deformgl.data import packaged_scene

            scene = _scene_file(args.scene, "--scene") if args.scene else packaged_scene("dragon_heart_scale")
            rows, frame_ms, info = bench_render(ctx, scene)
            print(format_render(rows, frame_ms, info, machine_line(ctx)))
    finally:
        ctx.release()
    return 0
