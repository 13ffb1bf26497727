"""``python -m studies.animation_frames``: what a frame of an animation costs against a still, in one process.

Three timings of the same scene (default: the shipped dragon_motion.toml, the README's GIF), after
one warm-up render that fills the binding cache: the still at step 0 (build, bind, draw: what
every separate run pays), the still after the whole run (``(frames - 1) * steps_per_frame``
steps), and the animation of ``frames`` frames from one run (:func:`~deformgl.scene.animation.render_frames`).
The animation's cost per frame is reported as a ratio to the still, and against the frame
sequence made the old way, one still per frame each simulated from step 0, estimated from the two
stills (a run of k steps costs ``t0 + k / steps * (t_still - t0)``).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import moderngl

from deformgl.bench.sim_speed import machine_line
from deformgl.scene.animation import frame_plan, render_frames
from deformgl.scene.pipeline import render
from deformgl.scene.schema import load_scene

__all__ = ["bench_animation"]


def _timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def bench_animation(ctx: moderngl.Context, scene_path: Path) -> str:
    """The report (see the module docstring)."""
    scene = load_scene(scene_path)
    plan = frame_plan(scene)
    full = dataclasses.replace(scene, animation=None,
                               physics=dataclasses.replace(scene.physics, steps=plan.steps))
    start = dataclasses.replace(full, physics=dataclasses.replace(full.physics, steps=0))
    render(ctx, start)  # warm-up: the binding cache, the shader programs
    t0 = _timed(lambda: render(ctx, start))
    t_still = _timed(lambda: render(ctx, full))
    t_anim = _timed(lambda: render_frames(ctx, scene, plan))
    n = plan.frames
    per_frame = t_anim / n
    restart = sum(t0 + (k * plan.steps_per_frame) / max(plan.steps, 1) * (t_still - t0) for k in range(n))
    w, h = scene.render.size
    rows = [("still at step 0 (build, bind, draw)", t0, ""),
            (f"still after {plan.steps} steps", t_still, ""),
            (f"animation, {n} frames from one run", t_anim,
             f"{per_frame * 1e3:.1f} ms per frame = {per_frame / t_still:.3f} x the still"),
            (f"{n} stills, each simulated from step 0 (est.)", restart,
             f"{restart / t_anim:.1f} x the animation (in one process; a process per still adds its start-up)")]
    return "\n".join([
        machine_line(ctx),
        f"{scene_path.name}: {n} frames of {w}x{h}, {plan.steps_per_frame} steps per frame ({plan.steps} steps)",
        *(f"{label:<48}{t * 1e3:10.1f} ms   {note}".rstrip() for label, t, note in rows),
    ])


def main(argv: list[str] | None = None) -> int:
    """``python -m studies.animation_frames [--scene FILE]``."""
    from deformgl.data import packaged_scene, scene_file
    from studies.common import gl_context, parse, parser

    p = parser("animation_frames", "an N-frame animation from one run against a still and against N stills "
                                   "each simulated from step 0")
    p.add_argument("--scene", type=Path, default=None, help="the scene (default: the shipped dragon_motion.toml)")
    args = parse(p, argv)
    scene = scene_file(args.scene, "--scene") if args.scene else packaged_scene("dragon_motion")
    with gl_context(args) as ctx:
        print(bench_animation(ctx, scene))
    return 0


if __name__ == "__main__":
    from studies.common import run_main

    run_main(main)
