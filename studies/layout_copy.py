"""What the blocked layout's compact copy costs the passes that read it (docs/PERFORMANCE.md,
"Several nodes per fragment"): ``python -m studies.layout_copy``.

The blocked layout (:class:`~deformgl.grid.blocks.BlockedLayout`) runs the foundation's Verlet
pass; the draw passes, the mappings and the census read node state through the compact layout
(``shaders/lib/node_texel.glsl``), from the copy ``BlockedTextures.view`` makes with
``shaders/sim/unblock.frag`` once per state it is asked for. Per grid, in alternating rounds
(:func:`~deformgl.bench.sim_blocks.alternate_rounds`): the compact and the blocked Verlet step
(ms/step; the gain is their difference), the copy (ms), and the passes it feeds: a census count
(``NodeCensus.bad``, the blow-up guard's and the convergence stop's pass) and, on the heart
scene's body, the curvature-corrected mapped draw at 512² (the frame's one draw). "steps" is the
copy over the gain per step: how many blocked steps pay for one copy.
"""

from __future__ import annotations

import statistics
from collections.abc import Callable

import moderngl

from deformgl.bench.sim_blocks import alternate_rounds
from deformgl.bench.sim_speed import block_system, fragment_verlet, stable_dt

#: The grids: a 131k-node block, the 20k-node ball, and "heart" (the heart scene's body).
GRIDS = ((64, 64, 32), "ball34", "heart")
#: The block of a grid the integrator would not pick by itself (1x2x2 measured best on the blocks).
FALLBACK_BLOCK = (1, 2, 2)


def _med(values: list[float]) -> str:
    return f"{statistics.median(values):.3f} ({min(values):.3f}-{max(values):.3f})"


def copy_rows(ctx: moderngl.Context, grids=GRIDS, *, rounds: int = 7, steps: int = 20, repeats: int = 20,
              size: int = 512) -> list[dict]:
    """One row per grid: ``{"grid", "nodes", "block", "times": {name: ms per round}}`` with names
    compact (ms/step), blocked (ms/step), copy (ms), census (ms) and, on the heart, draw (ms)."""
    from deformgl.render.passes import RenderTarget
    from deformgl.sim.backends.blocked import default_block
    from deformgl.sim.census import NodeCensus
    from studies.heart_frame import heart_frame_setup

    rows = []
    for spec in grids:
        setup = None
        if spec == "heart":
            setup = heart_frame_setup()
            system, dt, loads, grid = (setup.built.system, setup.scene.physics.dt, setup.built.loads,
                                       setup.built.grid)
        else:
            system = block_system(spec)
            dt, loads, grid = stable_dt(system, 0.2), (), system.grid
        block = default_block(grid) or FALLBACK_BLOCK
        owned: list = []
        try:
            compact = fragment_verlet(ctx, system, dt, loads=loads, layout="compact")
            owned.append(compact)
            blocked = fragment_verlet(ctx, system, dt, loads=loads, block=block)
            owned.append(blocked)
            layout = compact.textures.layout
            census = NodeCensus(ctx, count=system.count, row=layout.width)
            owned.append(census)
            view = blocked.position_texture

            def stepping(sim) -> Callable[[], None]:
                def go() -> None:
                    sim.step(steps)
                    ctx.finish()
                return go

            def copying() -> None:
                for _ in range(repeats):
                    blocked.textures.changed()
                    blocked.position_texture  # noqa: B018  (the copy pass)
                ctx.finish()

            def counting() -> None:
                for _ in range(repeats):
                    census.bad(view, 1e6)

            runs = {"compact": stepping(compact), "blocked": stepping(blocked), "copy": copying,
                    "census": counting}
            per = {"compact": steps, "blocked": steps, "copy": repeats, "census": repeats}
            if setup is not None:
                target = RenderTarget(ctx, (size, size), 0)
                owned.append(target)
                draw = setup.mapped_pass(ctx, layout)
                owned.append(draw)

                def drawing() -> None:
                    for _ in range(repeats):
                        target.begin((1.0, 1.0, 1.0))
                        draw.draw(view, setup.view, setup.lighting)
                    ctx.finish()
                runs["draw"], per["draw"] = drawing, repeats
            times = alternate_rounds(runs, rounds)
        finally:
            for thing in reversed(owned):
                thing.release()
        rows.append({"grid": spec if isinstance(spec, str) else "x".join(map(str, spec)), "nodes": system.count,
                     "block": block, "times": {k: [t / per[k] * 1e3 for t in ts] for k, ts in times.items()}})
    return rows


def format_rows(rows: list[dict], machine: str, rounds: int) -> str:
    lines = [machine, f"ms, median (range) of {rounds} alternating rounds; gain = compact - blocked step; "
             "steps = copy / gain (blocked steps that pay for one copy)"]
    for row in rows:
        t = row["times"]
        gain = [c - b for c, b in zip(t["compact"], t["blocked"])]
        pay = [c / g if g > 0 else float("inf") for c, g in zip(t["copy"], gain)]
        line = (f"{row['grid']} ({row['nodes']} nodes, blocks {'x'.join(map(str, row['block']))}): "
                f"step compact {_med(t['compact'])}, blocked {_med(t['blocked'])}, gain {_med(gain)}; "
                f"copy {_med(t['copy'])} = {statistics.median(pay):.1f} steps' gain; census {_med(t['census'])}")
        if "draw" in t:
            line += f"; mapped draw {_med(t['draw'])}"
        lines.append(line)
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from deformgl.bench.sim_speed import machine_line
    from studies.common import gl_context, parse, parser

    p = parser("layout_copy", "the blocked layout's compact copy against the step gain and the passes it feeds")
    p.add_argument("--rounds", type=int, default=7, help="alternating rounds (default 7)")
    args = parse(p, argv)
    with gl_context(args) as ctx:
        grids = ((27, 27, 27),) if args.quick else GRIDS
        print(format_rows(copy_rows(ctx, grids, rounds=args.rounds), machine_line(ctx), args.rounds))
    return 0


if __name__ == "__main__":
    from studies.common import run_main

    run_main(main)
