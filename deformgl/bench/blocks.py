"""``deformgl bench sim --blocks``: the foundation's Verlet step with several nodes per fragment
(the blocked layout, :class:`~deformgl.grid.blocks.BlockedLayout`) against the compact layout,
in the same process.

1. **The step** (:func:`block_rows`): every block shape of :data:`~deformgl.grid.blocks.BLOCK_SHAPES`
   that fits the renderer's render targets, and the compact layout, on the benchmark volumes (2k,
   4k, 20k, 131k nodes in full blocks, a sheet one node thick, the 20k-node ball) and the heart
   scene's body (the calibrated
   lattice with the volumetric term at nu = 0.45, per-spring levels codes, on a voxelized shape).
   All steppers of a grid are built and warmed up first, then ``rounds`` rounds time ``steps``
   steps of each in turn, the order reversed every other round, so load from other processes hits
   all alike. The ratio is compact ms / blocked ms of the same round; the report gives the median
   and the range over the rounds.
2. **The heart frame** (:func:`heart_frame`): the heart scene's 15 steps and one curvature-
   corrected draw at 512² (``bench render``'s frame, no MSAA), on the compact layout and on the
   layout the integrator picks by itself (:func:`~deformgl.sim.backends.blocked.default_block`).
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import moderngl

from deformgl.bench.studies import block_system, fragment_verlet, machine_line, stable_dt
from deformgl.grid.blocks import BLOCK_SHAPES
from deformgl.sim.backends.blocked import default_block

__all__ = ["BLOCK_GRIDS", "block_rows", "heart_frame", "blocks_report"]

#: The grids of :func:`block_rows`: full blocks of about 2k, 4k, 20k and 131k nodes, a 16k-node
#: sheet one node thick, the 20k-node ball and "heart" (the heart scene's body: scenes/dragon_heart_scale.toml).
BLOCK_GRIDS = ((13, 13, 13), (16, 16, 16), (27, 27, 27), (64, 64, 32), (128, 128, 1), "ball34", "heart")


def _system(spec):
    if spec == "heart":
        from deformgl.bench.multigrid import _scene_path
        from deformgl.scene.pipeline import build_scene_model
        from deformgl.scene.schema import load_scene

        scene = load_scene(_scene_path())
        built = build_scene_model(scene)  # (the body alone: no binding, unlike heart_frame_setup)
        return built.system, float(scene.physics.dt), built.loads
    system = block_system(spec)
    return system, stable_dt(system, 0.2), ()


def _rounds(runs: dict[str, Callable[[], None]], rounds: int) -> dict[str, list[float]]:
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
            times = _rounds({name: run(sim) for name, sim in sims.items()}, rounds)
        finally:
            for sim in sims.values():
                sim.release()
        ms = {name: [t / steps * 1e3 for t in ts] for name, ts in times.items()}
        rows.append({"grid": spec if isinstance(spec, str) else "x".join(map(str, spec)), "nodes": system.count,
                     "compact": ms.pop("compact"), "shapes": ms, "default": default_block(system.grid)})
    return rows


def heart_frame(ctx: moderngl.Context, *, rounds: int = 7, frame_steps: int = 15, size: int = 512) -> dict:
    """``{"compact": ms per frame per round, "default": ms per frame per round, "block": the block}``
    of the heart frame (module docstring)."""
    from deformgl.bench.multigrid import heart_frame_setup
    from deformgl.render.passes import RenderTarget
    from deformgl.sim.backends.fragment import FragmentIntegrator

    setup = heart_frame_setup()
    built = setup.built
    sims: dict[str, FragmentIntegrator] = {}
    target = RenderTarget(ctx, (size, size), 0)
    draw = None
    try:
        for layout in ("compact", "auto"):
            sims[layout] = FragmentIntegrator(ctx, built.system, built.grid, "verlet", setup.scene.physics.dt,
                                              loads=built.loads, layout=layout)
        # one draw pass: both read the compact layout (the blocked one through its compact view)
        draw = setup.mapped_pass(ctx, sims["compact"].textures.layout)

        def frame(name: str) -> Callable[[], None]:
            def go() -> None:
                sims[name].step(frame_steps)
                target.begin((1.0, 1.0, 1.0))
                draw.draw(sims[name].position_texture, setup.view, setup.lighting)
                ctx.finish()
            return go
        times = _rounds({name: frame(name) for name in sims}, rounds)
        block = sims["auto"].block
    finally:
        target.release()
        if draw is not None:
            draw.release()
        for sim in sims.values():
            sim.release()
    return {"compact": [t * 1e3 for t in times["compact"]], "default": [t * 1e3 for t in times["auto"]],
            "block": block, "nodes": built.grid.count, "steps": frame_steps, "size": size}


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
    frame = heart_frame(ctx, rounds=rounds)
    picked = "compact" if frame["block"] is None else f"blocks of {_shape(frame['block'])}"
    lines.append(f"heart frame ({frame['nodes']} nodes, {frame['steps']} steps + one curvature-corrected draw at "
                 f"{frame['size']}x{frame['size']}, no MSAA): compact {statistics.median(frame['compact']):.1f} ms, "
                 f"default ({picked}) {statistics.median(frame['default']):.1f} ms, "
                 f"{_ratio(frame['compact'], frame['default'])}")
    return "\n".join(lines)
