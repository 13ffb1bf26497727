"""A scene in real time (docs/PERFORMANCE.md, "Implicit Euler on stiff materials"): frames of
1/60 s simulated per wall second, implicit Euler at dt = 1/60 s (one step a frame, 10 and 20 CG
iterations) against the scene's own explicit integrator at its dt, on the fragment backend:
``python -m studies.realtime [--scene FILE]`` (default the shipped dragon_heart_scale.toml)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from deformgl.bench.trade_stiff import CHUNK
from deformgl import make_simulation


@dataclass(frozen=True)
class RealtimeRow:
    """One integrator on a scene: frames of 1/60 s of simulated time per wall second."""

    integrator: str
    dt: float
    steps_per_frame: int
    iterations: int
    fps: float
    residual: float | None   # implicit: the last step's relative CG residual


def realtime(ctx, scene: str = "dragon_heart_scale.toml", *, frames: int = 10,
             iterations: tuple[int, ...] = (10, 20), progress: Callable[[str], None] | None = None
             ) -> tuple[list[RealtimeRow], float, int]:
    """Implicit Euler at dt = 1/60 s (one step per 60 Hz frame) against the scene's explicit
    integrator at its dt, on the fragment backend, ``frames`` frames each (GPU time of the steps,
    after one untimed step). Returns the rows, the largest node distance in grid spacings between
    the implicit (most iterations) and explicit positions after the frames, and the node count."""
    from deformgl.data import scene_file
    from deformgl.scene.pipeline import build_scene_model
    from deformgl.scene.schema import load_scene

    spec = load_scene(scene_file(scene))
    model = build_scene_model(spec)
    physics = spec.physics
    rows: list[RealtimeRow] = []
    ends: dict[str, np.ndarray] = {}

    def timed(name: str, dt: float, per_frame: int, its: int) -> None:
        options = {"cg_iterations": its} if name == "implicit-euler" else {}
        if progress:
            progress(f"{spec.source.name}: {name} dt {dt:.3g} s x {per_frame} steps per frame"
                     + (f", {its} CG iterations" if its else ""))
        with make_simulation(model.system, name, "fragment", dt=dt, ctx=ctx, loads=model.loads, **options) as sim:
            sim.step(1)
            ctx.finish()
            start = time.perf_counter()
            sim.step(frames * per_frame - 1)
            ctx.finish()
            wall = time.perf_counter() - start
            residual = sim.residual() if name == "implicit-euler" else None  # type: ignore[attr-defined]
            ends[name] = sim.positions().astype(np.float64)
        rows.append(RealtimeRow(name, dt, per_frame, its, (frames - 1 / per_frame) / wall, residual))

    for its in iterations:
        timed("implicit-euler", CHUNK, 1, its)
    timed(physics.integrator, physics.dt, max(1, round(CHUNK / physics.dt)), 0)
    gap = float(np.max(np.linalg.norm(ends["implicit-euler"] - ends[physics.integrator], axis=1))) / model.grid.spacing
    return rows, gap, model.system.count


def format_realtime(rows: list[RealtimeRow], gap: float, nodes: int, scene: str, machine: str = "") -> str:
    lines = [f"Real time on {scene} ({nodes} nodes, fragment backend){'; ' + machine if machine else ''}: "
             "frames of 1/60 s simulated per wall second",
             f"{'integrator':<15} {'dt s':>9} {'steps/frame':>11} {'CG it':>5} {'fps':>8} {'CG residual':>11}"]
    for r in rows:
        res = "-" if r.residual is None else f"{r.residual:.2g}"
        its = str(r.iterations) if r.iterations else "-"
        lines.append(f"{r.integrator:<15} {r.dt:>9.3g} {r.steps_per_frame:>11} {its:>5} {r.fps:>8.3g} {res:>11}")
    lines.append(f"largest node distance implicit vs explicit after the frames: {gap:.3g} h")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from pathlib import Path

    from deformgl.bench.sim_speed import machine_line
    from deformgl.data import scene_file
    from studies.common import gl_context, parse, parser, progress

    p = parser("realtime", "a scene in 60 Hz frames per second, implicit Euler at dt 1/60 s against explicit")
    p.add_argument("--scene", type=Path, default=None, help="the scene (default: the shipped dragon_heart_scale.toml)")
    args = parse(p, argv)
    scene = str(scene_file(args.scene, "--scene")) if args.scene else "dragon_heart_scale.toml"
    with gl_context(args) as ctx:
        rows, gap, nodes = realtime(ctx, scene, progress=progress(args))
        print(format_realtime(rows, gap, nodes, scene, machine_line(ctx)))
    return 0


if __name__ == "__main__":
    from studies.common import run_main

    run_main(main)
