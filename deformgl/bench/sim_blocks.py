"""``deformgl bench sim --blocks``: the foundation's Verlet step with several nodes per fragment
(the blocked layout, :class:`~deformgl.grid.blocks.BlockedLayout`) against the compact layout, on
the benchmark volumes (2k to 131k nodes, a sheet one node thick, the 20k-node ball) and the heart
scene's body, for every block shape the renderer's render targets allow. The steppers of a grid
are built and warmed up first, then timed in alternating rounds (:func:`alternate_rounds`); the
ratio is compact ms / blocked ms of the same round, median and range. The heart scene's frame
on each layout is ``python -m studies.heart_frame`` (repository only)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from pathlib import Path

import moderngl

from deformgl.bench.sim_speed import block_system, fragment_verlet, machine_line, stable_dt
from deformgl.grid.blocks import BLOCK_SHAPES
from deformgl.sim.backends.blocked import default_block

__all__ = ["BLOCK_GRIDS", "scene_path", "alternate_rounds", "block_rows", "blocks_report"]

#: The grids of :func:`block_rows`: full blocks of about 2k, 4k, 20k and 131k nodes, a 16k-node
#: sheet one node thick, the 20k-node ball and "heart" (the heart scene's body: scenes/dragon_heart_scale.toml).
BLOCK_GRIDS = ((13, 13, 13), (16, 16, 16), (27, 27, 27), (64, 64, 32), (128, 128, 1), "ball34", "heart")


def _system(spec):
    if spec == "heart":
        from deformgl.scene.pipeline import build_scene_model
        from deformgl.scene.schema import load_scene

        scene = load_scene(scene_path())
        built = build_scene_model(scene)  # (the body alone: no binding, unlike heart_frame_setup)
        return built.system, float(scene.physics.dt), built.loads
    system = block_system(spec)
    return system, stable_dt(system, 0.2), ()


def scene_path() -> Path:
    """The shipped heart scene, scenes/dragon_heart_scale.toml."""
    from deformgl.data import find_scene

    return Path(find_scene("dragon_heart_scale.toml"))


def alternate_rounds(runs: dict[str, Callable[[], None]], rounds: int) -> dict[str, list[float]]:
    """Seconds of each run in each round, alternating the order (after one warm-up call each)."""
    for run in runs.values():
        run()
    times: dict[str, list[float]] = {name: [] for name in runs}
    names = list(runs)
    for r in range(rounds):
        for name in (names if r % 2 == 0 else names[::-1]):
            t0 = time.perf_counter()
            runs[name]()
            times[name].append(time.perf_counter() - t0)
    return times


def block_rows(ctx: moderngl.Context, grids=BLOCK_GRIDS, *, steps: int = 40, rounds: int = 7,
               shapes=BLOCK_SHAPES) -> list[dict]:
    """One row per grid: ``{"grid", "nodes", "compact" (ms/step per round), "shapes": {shape: ms/step
    per round}, "default": the block the integrator picks or None}``."""
    targets = int(ctx.info["GL_MAX_DRAW_BUFFERS"])
    shapes = [s for s in shapes if s[0] * s[1] * s[2] <= targets]
    rows = []
    for spec in grids:
        system, dt, loads = _system(spec)
        sims = {"compact": fragment_verlet(ctx, system, dt, loads=loads, layout="compact")}
        try:
            for shape in shapes:
                sims[shape] = fragment_verlet(ctx, system, dt, loads=loads, block=shape)

            def run(sim=None) -> Callable[[], None]:
                def go() -> None:
                    sim.step(steps)
                    ctx.finish()
                return go
            times = alternate_rounds({name: run(sim) for name, sim in sims.items()}, rounds)
        finally:
            for sim in sims.values():
                sim.release()
        ms = {name: [t / steps * 1e3 for t in ts] for name, ts in times.items()}
        rows.append({"grid": spec if isinstance(spec, str) else "x".join(map(str, spec)), "nodes": system.count,
                     "compact": ms.pop("compact"), "shapes": ms, "default": default_block(system.grid)})
    return rows


def _ratio(compact: list[float], other: list[float]) -> str:
    r = [c / o for c, o in zip(compact, other)]
    return f"{statistics.median(r):.2f}x ({min(r):.2f}-{max(r):.2f})"


def _shape(shape) -> str:
    return "x".join(map(str, shape))


def blocks_report(ctx: moderngl.Context, *, steps: int = 40, rounds: int = 7, grids=BLOCK_GRIDS) -> str:
    """The ``bench sim --blocks`` report (module docstring)."""
    lines = [machine_line(ctx), f"foundation Verlet step, compact layout against blocks of nodes per fragment "
             f"(x by y by z); {rounds} alternating rounds of {steps} steps; ms/step median; ratio = compact ms / "
             "blocked ms of the same round, median (range); * = the block the integrator picks by itself"]
    for row in block_rows(ctx, grids, steps=steps, rounds=rounds):
        lines.append(f"{row['grid']} ({row['nodes']} nodes): compact {statistics.median(row['compact']):.3f} ms/step")
        for shape, ms in row["shapes"].items():
            mark = " *" if shape == row["default"] else ""
            lines.append(f"  {_shape(shape):>5}: {statistics.median(ms):.3f} ms/step, "
                         f"{_ratio(row['compact'], ms)}{mark}")
    return "\n".join(lines)
