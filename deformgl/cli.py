"""The ``deformgl`` command: render scenes to PNG, print GL information, run benchmarks.

Exit codes: 0 done; 1 a runtime failure (the simulation blew up, no GL context, a write failed,
an internal error); 2 a usage or input error (a bad option, scene, mesh or output path), found
before any work; 130 interrupted (SIGINT); 143 terminated (SIGTERM). Every failure is one line on
stderr, ``deformgl: error: ...``; an unexpected exception adds "rerun with --debug" and
``--debug`` shows its traceback. A run that fails or is stopped writes none of its outputs.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import time
import warnings
from pathlib import Path
from typing import Any, NoReturn

from deformgl.errors import DeformglError, DeformglWarning, InputError

#: What ``render -o`` writes, by extension (deformgl.render.video and the scene's output.path).
OUTPUT_FORMATS = "PNG (.png), GIF (.gif), WebP (.webp), MP4 (.mp4) or PNG frames (DIR/%%04d.png)"

#: The exit codes (see the module docstring and the README).
EXIT_OK, EXIT_FAILURE, EXIT_INPUT, EXIT_INTERRUPTED, EXIT_TERMINATED = 0, 1, 2, 130, 143


class _Parser(argparse.ArgumentParser):
    """argparse with its usage errors on one line (exit 2), like every other error."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_INPUT, f"deformgl: error: {_one_line(message)} (see {self.prog} --help)\n")


def _top_parser(cls: type[_Parser] = _Parser) -> tuple[argparse.ArgumentParser, Any]:
    """The ``deformgl`` parser with its global options, and its subcommands' action."""
    p = cls(
        prog="deformgl",
        description="GPU mass-spring soft bodies on a coarse grid, rendered headless to images "
                    "through OpenGL on EGL (Mesa llvmpipe without a GPU).")
    p.add_argument("--device", type=int, default=None,
                   help="EGL device index (default: $DEFORMGL_DEVICE, else EGL's default)")
    p.add_argument("--debug", action="store_true",
                   help="show the traceback of an unexpected error (a bug: please report it)")
    from deformgl import __version__

    p.add_argument("--version", action="version", version=f"deformgl {__version__}")
    return p, p.add_subparsers(dest="command", required=True, metavar="COMMAND")


def _parser() -> argparse.ArgumentParser:
    from deformgl.sim.guards import MAX_SUBSTEPS

    p, sub = _top_parser()
    from deformgl.testing import diff_cli

    diff_cli.add_parser(sub)
    from deformgl.pack import export_shaders, export_web

    export_shaders.add_parser(sub)
    export_web.add_parser(sub)
    _add_render_parser(sub, MAX_SUBSTEPS)

    from deformgl.sweep import command as sweep_cli

    sweep_cli.add_parser(sub)

    t = sub.add_parser("trilinear", help="render a trilinear scene-graph scene to PNG",
                       description="Scenes of Knuth, Kohlhammer & Kuijper's trilinear scene graph: "
                                   "tubes (figure 1: linear transforms left, trilinear right), tile "
                                   "(figure 9: a tile wrapped onto a torus), helix (many small spheres).")
    t.add_argument("scene", choices=["tubes", "tile", "helix"], help="which scene")
    t.add_argument("-o", "--output", type=Path, required=True, help="output PNG")
    t.add_argument("--size", default="960x480", metavar="WxH", help="image size (default 960x480)")
    t.add_argument("--normals", choices=["direct", "tangent"], default="direct",
                   help="normals transformed directly (smooth) or through the deformed tangent "
                        "frame (orthogonal, seams at cell borders), section 4.2")

    sub.add_parser("info", help="print the GL renderer, version and limits",
                   description="Create the headless context and print renderer, GL version, max "
                               "texture size, vertex texture units and whether RGBA32F render "
                               "targets work.")

    from deformgl.plan.planner import add_parser as add_plan_parser

    add_plan_parser(sub)

    from deformgl import cli_bench

    cli_bench.add_parser(sub)
    return p



def _add_render_parser(sub: Any, max_substeps: int) -> None:
    """``deformgl render`` and its options (light to build: :func:`_syntax_first` parses with
    them before the heavy imports)."""
    r = sub.add_parser("render", help=f"simulate a scene and write an image ({OUTPUT_FORMATS})",
                       description="Simulate a scene file (TOML) on the GPU and render it to a PNG still or an "
                                   "animation (GIF, WebP, MP4 or numbered PNG frames), or render a scene-graph "
                                   "file (one with a [graph] table, docs/SCENEGRAPH.md). "
                                   "Every output is written to a temporary file and renamed, so a failed "
                                   "run never leaves a partial image.")
    r.add_argument("scene", type=Path,
                   help="scene file (.toml), e.g. scenes/dragon.toml; a file not in the working directory "
                        "is looked up among the scenes shipped with deformgl by name (dragon.toml)")
    r.add_argument("-o", "--output", type=Path, default=None,
                   help=f"output file, by its extension: {OUTPUT_FORMATS} (default: the scene's output.path; "
                        "for a shipped scene, its file name in the working directory)")
    r.add_argument("--steps", type=int, default=None, help="override physics.steps")
    r.add_argument("--size", default=None, metavar="WxH", help="override render.size, e.g. 800x600")
    r.add_argument("--mesh", type=Path, default=None,
                   help="replace the scene's mesh (any trimesh-readable file) keeping its settings; a file not "
                        "in the working directory is looked up among the shipped meshes by name")
    r.add_argument("--mapping", choices=["one-to-one", "constant", "curvature", "auto"], default=None,
                   help="override mapping.mode: one-to-one draws the node-grid surface; constant and "
                        "curvature draw the detailed mesh through the triangle basis (Mosegaard & Sørensen 2005, eq. 6) or the "
                        "curvature-corrected basis (Mosegaard & Sørensen 2005, eq. 8); auto picks per vertex")
    r.add_argument("--integrator", choices=["euler", "semi-implicit", "midpoint", "rk4", "verlet", "implicit-euler", "xpbd"],
                   default=None,
                   help="override physics.integrator (Movania & Feng 2012): explicit Euler, semi-implicit "
                        "Euler, midpoint (RK2), classical RK4, position Verlet; implicit (backward) Euler with "
                        "conjugate gradients (no dt limit; [physics.implicit] iterations, tolerance); or xpbd "
                        "(Macklin, Müller & Chentanez 2016: no explicit dt limit; [physics.xpbd] iterations, substeps)")
    r.add_argument("--backend", choices=["fragment", "feedback", "numpy"], default=None,
                   help="override physics.backend: fragment passes on the node grid, transform feedback over "
                        "explicit neighbour lists, or the float64 NumPy reference")
    unstable = r.add_mutually_exclusive_group()
    unstable.add_argument("--allow-unstable", dest="unstable", action="store_const", const="run", default=None,
                          help="run a dt above the integrator's stability limit anyway (the default refuses it, "
                               "naming the bound and the node and spring that set it)")
    unstable.add_argument("--subdivide", dest="unstable", action="store_const", const="subdivide",
                          help="split each step into enough substeps to be below the stability limit, and "
                               f"restart a run that blows up with half the step (up to {max_substeps} substeps)")
    r.add_argument("--check-every", type=int, default=None, metavar="N",
                   help="count non-finite or far-away nodes on the GPU every N steps (default: "
                        "physics.safety.check_every, 100; 0: only at the end); a blow-up stops the run "
                        "with the step and a node, and writes no PNG")
    r.add_argument("--export-mesh", type=Path, default=None, metavar="OUT.ply|.obj|.glb|.pvd|.xdmf|.usd",
                   help="also write the deformed detailed mesh as the mapping vertex shader computed "
                        "it (captured with transform feedback); of an animation: a pattern DIR/%%04d.ply, "
                        "one .glb animated by morph targets, a ParaView time series with displacement and "
                        "velocity (.pvd of .vtu frames, or .xdmf + .h5; extra 'io'), or a USD point cache "
                        "(.usd, .usda, .usdc; extra 'usd')")
    r.add_argument("--export-grid", type=Path, default=None, metavar="OUT.pvd|.xdmf|.vtu",
                   help="also write the node grid as hexahedra per frame for ParaView: displacement and "
                        "velocity per node, volume ratio, Green strain and fill per cell (extra 'io')")
    r.add_argument("--pack-inputs", type=Path, default=None, metavar="OUT.npz",
                   help="also write the node texture and vertex attributes for the shader pack's "
                        "example program (examples/mapped_mesh_example.py)")
    r.add_argument("--time", type=float, default=None, metavar="T",
                   help="scene-graph files: the still at time T seconds of the keyframed deformations "
                        "(default 0)")
    r.add_argument("--tolerance", type=float, default=None, metavar="X",
                   help="model only what the scene requires: run it on the coarsest grid, integrator and "
                        "largest dt whose predicted relative deflection error is below X (deformgl plan; "
                        "needs a [material]); the simulated time is kept")
    r.add_argument("--load", choices=["bending", "compression", "torsion"], default="bending",
                   help="with --tolerance: which measured workload's error model applies (default bending)")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    from deformgl.scene.overrides import add_render_flags

    add_render_flags(r)  # --frames, --fps, --camera, --views, --compare, --set, --json



class _Quiet(_Parser):
    """A parser whose usage errors are left to the full parser (raised, not printed)."""

    def error(self, message: str) -> NoReturn:
        raise ValueError(message)


def _syntax_first(argv: list[str]) -> int | None:
    """``deformgl render SCENE``: the scene file's TOML read and parsed (size, encoding, nesting,
    syntax) before NumPy, moderngl and trimesh are imported, so that a syntax error is reported
    at once, with the message :func:`deformgl.scene.schema.load_scene` gives; None to go on (the
    full parser and the run report everything else)."""
    if any(a in ("-h", "--help", "--version") for a in argv):
        return None
    i = 0
    while i < len(argv) and argv[i].startswith("-"):
        i += 2 if argv[i] == "--device" else 1
    if i >= len(argv) or argv[i] != "render":
        return None
    p, sub = _top_parser(_Quiet)
    _add_render_parser(sub, 0)
    try:
        args, _ = p.parse_known_args(argv)
    except (ValueError, SystemExit):
        return None
    from deformgl.data import find_scene
    from deformgl.scene.tomltext import read_toml

    source = find_scene(args.scene)
    if not source.is_file():
        return None
    try:
        read_toml(source, str(source))
    except InputError as exc:
        _error(exc)
        return EXIT_INPUT
    return None


def _scene_file(path: Path, flag: str = "") -> Path:
    """A scene file as given, else the shipped scene of that name (:func:`deformgl.data.scene_file`)."""
    from deformgl.data import scene_file

    return scene_file(path, flag)


def _render(args: argparse.Namespace) -> int:
    from deformgl.data import is_packaged
    from deformgl.files import check_writable
    from deformgl.gl.context import create_context
    from deformgl.scene.animation import frame_plan
    from deformgl.scene.outputs import Job, check_job, default_record_path, render_job
    from deformgl.errors import SceneError
    from deformgl.scene.overrides import (blame_flag, camera_overrides, flag_keys, parse_modes, parse_set, parse_view,
                                          parse_views)
    from deformgl.scene.record import summary_line
    from deformgl.scene.schema import load_scene
    from deformgl.scene.spec import parse_size

    source = _scene_file(args.scene)
    from deformgl.trilinear.graphfile import is_graph_file

    if is_graph_file(source):
        return _render_graph(args, source)
    if args.time is not None:
        raise InputError(f"{source}: --time applies to scene-graph files (docs/SCENEGRAPH.md)")
    overrides = parse_set(args.set) | camera_overrides(parse_view(args.camera) if args.camera else None)
    try:
        scene = load_scene(source, overrides or None)
    except SceneError as exc:  # a key a flag set: the flag is at fault, not the scene file
        raise blame_flag(exc, flag_keys(args.set, args.camera)) or exc from None
    size = None
    if args.size is not None:
        try:
            size = parse_size(args.size)
        except ValueError as exc:
            raise InputError(f"--size: {exc}") from None
    from deformgl.data import find_mesh

    scene = scene.with_overrides(mesh=None if args.mesh is None else find_mesh(args.mesh), steps=args.steps, size=size, mapping=args.mapping,
                                 integrator=args.integrator, backend=args.backend, unstable=args.unstable,
                                 check_every=args.check_every)
    if args.tolerance is not None:
        from deformgl.plan.planner import planned_scene

        scene, chosen = planned_scene(scene, args.tolerance, args.load)
        if not args.quiet:
            print("\n".join(f"deformgl: plan: {line}" for line in chosen.lines()[:-1]), file=sys.stderr)
    # a shipped scene writes into the working directory, never into the installed package
    out = args.output or (Path(scene.output.path.name) if is_packaged(source) else scene.output.path)
    if (args.steps is not None and args.steps_per_frame is None and args.seconds_per_frame is None
            and scene.animation is not None and (scene.animation.steps_per_frame is not None
                                                 or scene.animation.seconds_per_frame is not None)):
        raise InputError(f"{source}: --steps: the scene's [animation] sets the steps between frames; "
                         f"give --steps-per-frame (or --seconds-per-frame) instead")
    plan = frame_plan(scene, frames=args.frames, fps=args.fps, steps_per_frame=args.steps_per_frame,
                      seconds_per_frame=args.seconds_per_frame, turntable=args.turntable)
    record = None if args.json is None else (Path(args.json) if args.json else default_record_path(out))
    job = Job(out, plan, modes=parse_modes(args.compare), views=parse_views(args.views), export=args.export_mesh,
              pack=args.pack_inputs, record=record, grid=args.export_grid)
    check_job(scene, job)
    outputs = job.outputs(plan.frames)
    # one output of each folder (frames and series spread over folders), and the first and last
    some = list({os.path.realpath(p.parent): p for p in outputs}.values()) + outputs[:1] + outputs[-3:]
    for path in some:
        check_writable(path)  # before any work: render_job checks every one again, as a set
    _clean_leftovers(some)
    ctx = create_context(args.device)
    try:
        done = render_job(ctx, scene, job, progress=not args.quiet and sys.stderr.isatty(),
                          log=None if args.quiet else (lambda line: print(line, file=sys.stderr)))
    finally:
        ctx.release()
    if not args.quiet:
        print(f"deformgl: {summary_line(done)}", file=sys.stderr)
    extra = [p for p in (args.export_mesh, args.export_grid, record) if p is not None]
    count = f"{plan.frames} frames " if plan.frames > 1 else ""
    print(f"wrote {count}{out}" + (" and " + " and ".join(map(str, extra)) if extra else ""))
    return 0


def _render_graph(args: argparse.Namespace, source: Path) -> int:
    """``deformgl render`` of a scene-graph file (a ``[graph]`` table; docs/SCENEGRAPH.md)."""
    from deformgl.files import check_writable
    from deformgl.gl.context import create_context
    from deformgl.scene.graphs import graph_animation, graph_output, graph_to_png
    from deformgl.scene.spec import parse_size

    refused = {"--steps": args.steps, "--mesh": args.mesh, "--mapping": args.mapping, "--integrator": args.integrator,
               "--backend": args.backend, "--allow-unstable/--subdivide": args.unstable,
               "--check-every": args.check_every, "--pack-inputs": args.pack_inputs, "--tolerance": args.tolerance,
               "--set": args.set, "--camera": args.camera, "--views": args.views, "--compare": args.compare,
               "--json": args.json, "--turntable": args.turntable, "--steps-per-frame": args.steps_per_frame,
               "--seconds-per-frame": args.seconds_per_frame, "--export-grid": args.export_grid}
    if args.fps is not None and args.frames is None:
        raise InputError("--fps: only with --frames for a scene-graph file")
    if args.fps is not None and not 0 < args.fps <= 1000:
        raise InputError(f"--fps: must be in (0, 1000], got {args.fps:g}")
    out = graph_output(source, args.output, args.export_mesh, args.time, refused, frames=args.frames)
    try:
        size = parse_size(args.size) if args.size is not None else None
    except ValueError as exc:
        raise InputError(f"--size: {exc}") from None
    outputs = [p for p in (out, args.export_mesh) if p is not None]
    for path in outputs:
        check_writable(path)
    _clean_leftovers(outputs)
    ctx = create_context(args.device)
    try:
        if args.frames is not None:
            count = graph_animation(ctx, source, out, frames=args.frames, fps=args.fps or 24.0, size=size)
            print(f"wrote {count} frames {out}")
            return 0
        graph_to_png(ctx, source, out, size=size, time=args.time or 0.0, export=args.export_mesh)
    finally:
        ctx.release()
    print(f"wrote {out}" + (f" and {args.export_mesh}" if args.export_mesh else ""))
    return 0


def _trilinear(args: argparse.Namespace) -> int:
    from deformgl.files import check_writable
    from deformgl.gl.context import create_context
    from deformgl.scene.spec import parse_size
    from deformgl.trilinear.scenes import write_trilinear_scene

    try:
        size = parse_size(args.size)
    except ValueError as exc:
        raise InputError(f"--size: {exc}") from None
    if args.output.suffix.lower() != ".png":
        raise InputError(f"{args.output}: the output must be a .png file")
    check_writable(args.output)
    _clean_leftovers([args.output])
    ctx = create_context(args.device)
    try:
        write_trilinear_scene(ctx, args.scene, args.output, size, normals=args.normals)
    finally:
        ctx.release()
    print(f"wrote {args.output}")
    return 0


def _info(args: argparse.Namespace) -> int:
    from deformgl.gl.context import context_info, create_context

    ctx = create_context(args.device)
    try:
        print("\n".join(context_info(ctx).lines()))
    finally:
        ctx.release()
    return 0


def _plan(args: argparse.Namespace) -> int:
    from deformgl.plan.planner import run

    return run(args, _scene_file(args.scene))


#: When this process started (what is older and left by a dead run is a leftover).
_STARTED = time.time()


def _clean_leftovers(outputs: list[Path]) -> None:
    """Remove the temporary files a killed deformgl run left in the output folders and the cache."""
    from deformgl.files import remove_stale_temporaries
    from deformgl.render.mapped_setup import cache_dir

    for folder in {p.resolve().parent for p in outputs} | {cache_dir()}:
        remove_stale_temporaries(folder, before=_STARTED)


class Terminated(BaseException):
    """SIGTERM (``timeout``, CI cancels, ``docker stop``) as an exception, so that a run unwinds:
    its output set removes its temporary files and GL objects are released."""


def _on_signal(signum: int, frame: object) -> None:
    """SIGTERM / SIGINT: record the stop (a library that swallows the exception cannot make the
    run commit its outputs, see :data:`deformgl.files.STOP`), then unwind."""
    from deformgl.files import committing, request_stop

    exc: BaseException = Terminated(signum) if signum == signal.SIGTERM else KeyboardInterrupt()
    request_stop(exc)
    if committing():  # the outputs are being renamed: let the set finish, whole (main reports the stop)
        return
    raise exc


def _one_line(text: object) -> str:
    """A message on one line: newlines (a path may hold one) and every other line break escaped."""
    return "\\n".join(str(text).splitlines()) if str(text) else ""


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    if issubclass(category, DeformglWarning):
        print(f"deformgl: warning: {_one_line(message)}", file=sys.stderr)
    else:
        print(f"deformgl: warning: {_one_line(f'{category.__name__}: {message}')}", file=sys.stderr)


def _error(text: object) -> None:
    print(f"deformgl: error: {_one_line(text)}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script; returns the exit code (:data:`EXIT_INPUT` and the
    others)."""
    code = _syntax_first(sys.argv[1:] if argv is None else list(argv))
    if code is not None:
        return code
    from deformgl.files import STOP

    STOP.clear()  # (a stop recorded by an earlier call in this process)
    handlers = {}
    for sig in (signal.SIGTERM, signal.SIGINT):
        try:
            handlers[sig] = signal.signal(sig, _on_signal)
        except ValueError:  # not the main thread: leave signals alone
            pass
    try:
        code = _main(argv)
    except KeyboardInterrupt:
        _error("interrupted")
        return EXIT_INTERRUPTED
    except Terminated:
        _error("terminated (SIGTERM)")
        return EXIT_TERMINATED
    finally:
        for sig, previous in handlers.items():
            signal.signal(sig, previous)
    if STOP:  # a signal whose exception something swallowed: the run did not commit its outputs
        stopped = STOP.pop()
        _error("terminated (SIGTERM)" if isinstance(stopped, Terminated) else "interrupted")
        return EXIT_TERMINATED if isinstance(stopped, Terminated) else EXIT_INTERRUPTED
    return code


def _main(argv: list[str] | None) -> int:
    import numpy as np

    args = _parser().parse_args(argv)  # (a usage error exits here, one line, code 2)
    from deformgl.testing import diff_cli

    from deformgl import cli_bench
    from deformgl.pack import export_shaders, export_web
    from deformgl.sweep import command as sweep_cli

    commands = {"render": _render, "trilinear": _trilinear, "info": _info, "bench": cli_bench.run, "diff": diff_cli.run,
                "plan": _plan, "export-shaders": export_shaders.run, "export-web": export_web.run,
                "sweep": sweep_cli.run}
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            # non-finite values are found and named by the checks; numpy's own warnings only
            # print noise before the one-line error
            warnings.simplefilter("ignore", RuntimeWarning)
            warnings.showwarning = _show_warning
            return commands[args.command](args)
    except InputError as exc:
        _error(exc)
        return EXIT_INPUT
    except DeformglError as exc:
        _error(exc)
        return EXIT_FAILURE
    except MemoryError:
        _error("out of memory; use a coarser grid (grid.nodes_along_longest) or a smaller render.size")
        return EXIT_FAILURE
    except OSError as exc:  # a write that failed (full disk, read-only mount) after the checks
        name = exc.filename or ""
        _error(f"{name}{': ' if name else ''}{exc.strerror or exc}")
        return EXIT_FAILURE
    except (KeyboardInterrupt, Terminated):
        raise
    except Exception as exc:
        if args.debug:
            raise
        _error(f"internal error: {type(exc).__name__}: {exc} (a bug; rerun with --debug for the traceback "
               f"and please report it)")
        return EXIT_FAILURE


if __name__ == "__main__":
    sys.exit(main())
