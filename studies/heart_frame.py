"""The heart scene's frame — 15 Verlet steps and one curvature-corrected draw at 512² (no MSAA)
— on the compact node layout and on the blocked layout the integrator picks by itself
(:func:`~deformgl.sim.backends.blocked.default_block`), alternating rounds
(docs/PERFORMANCE.md, "Several nodes per fragment"): ``python -m studies.heart_frame``.
:func:`heart_frame_setup` is also the frame of ``python -m studies.preconditioners``."""

from __future__ import annotations

import statistics
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import moderngl

from deformgl.bench.sim_blocks import alternate_rounds, scene_path

if TYPE_CHECKING:
    from deformgl.render.camera import View
    from deformgl.render.mapped_setup import MappedVertices
    from deformgl.render.passes import Lighting
    from deformgl.scene.pipeline import SceneModel
    from deformgl.scene.spec import Scene


@dataclass(frozen=True)
class HeartFrame:
    """What a heart frame draws, built once (CPU): the scene and its model, the curvature-corrected
    mapping's vertex data, the front faces to cull, the view and the lights."""

    scene: Scene
    built: SceneModel
    data: MappedVertices
    front: str | None
    view: View
    lighting: Lighting

    def mapped_pass(self, ctx, layout):
        """The mesh's draw pass (the mapping pass ``deformgl render`` uses) over node ``layout``."""
        from deformgl.render.mapped import MappedMeshPass
        from deformgl.scene.pipeline import RENDER_MAPPING_PASS

        return MappedMeshPass(ctx, self.built.grid, layout, self.built.mesh.faces, self.data, front_face=self.front,
                              mapping_pass=RENDER_MAPPING_PASS)


def heart_frame_setup() -> HeartFrame:
    """The heart scene's :class:`HeartFrame` (its binding from the cache)."""
    from deformgl.grid.surface import grid_surface
    from deformgl.render.mapped import closed_front_face
    from deformgl.render.mapped_setup import get_binding, mapped_vertices
    from deformgl.scene.pipeline import build_scene_model, scene_lighting, scene_view
    from deformgl.scene.schema import load_scene
    from deformgl.sim.normals import rest_normals

    scene = load_scene(scene_path())
    built = build_scene_model(scene)
    binding = get_binding(built.mesh, built.grid, grid_surface(built.grid), use_cache=True, uv=None)
    data = mapped_vertices(binding, "curvature", built.grid.rest_positions, rest_normals(built.grid))
    return HeartFrame(scene, built, data, closed_front_face(built.mesh.vertices, built.mesh.faces),
                      scene_view(scene, built.bbox), scene_lighting(scene))


def heart_frame(ctx: moderngl.Context, *, rounds: int = 7, frame_steps: int = 15, size: int = 512) -> dict:
    """``{"compact": ms per frame per round, "default": ms per frame per round, "block": the block}``
    of the heart frame (the module docstring)."""
    from deformgl.render.passes import RenderTarget
    from deformgl.sim.backends.explicit_gpu import FragmentIntegrator

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
        times = alternate_rounds({name: frame(name) for name in sims}, rounds)
        block = sims["auto"].block
    finally:
        target.release()
        if draw is not None:
            draw.release()
        for sim in sims.values():
            sim.release()
    return {"compact": [t * 1e3 for t in times["compact"]], "default": [t * 1e3 for t in times["auto"]],
            "block": block, "nodes": built.grid.count, "steps": frame_steps, "size": size}


def format_heart_frame(frame: dict, machine: str) -> str:
    """The heart frame's line: compact against the picked layout, median (range) of the rounds."""
    r = [c / o for c, o in zip(frame["compact"], frame["default"])]
    picked = "compact" if frame["block"] is None else "blocks of " + "x".join(map(str, frame["block"]))
    return "\n".join([machine,
        f"heart frame ({frame['nodes']} nodes, {frame['steps']} steps + one curvature-corrected draw at "
        f"{frame['size']}x{frame['size']}, no MSAA): compact {statistics.median(frame['compact']):.1f} ms, "
        f"default ({picked}) {statistics.median(frame['default']):.1f} ms, "
        f"{statistics.median(r):.2f}x ({min(r):.2f}-{max(r):.2f})"])


def main(argv: list[str] | None = None) -> int:
    from deformgl.bench.sim_speed import machine_line
    from studies.common import gl_context, parse, parser

    p = parser("heart_frame", "the heart scene's frame on the compact and the picked blocked layout")
    p.add_argument("--rounds", type=int, default=7, help="alternating rounds (default 7)")
    args = parse(p, argv)
    with gl_context(args) as ctx:
        print(format_heart_frame(heart_frame(ctx, rounds=args.rounds), machine_line(ctx)))
    return 0


if __name__ == "__main__":
    from studies.common import run_main

    run_main(main)
