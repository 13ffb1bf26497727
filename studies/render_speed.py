"""The draw paths of a mapped scene against the static mesh, and a simulate + draw frame
(docs/PERFORMANCE.md, "Drawing the heart-scale mesh"): ``python -m studies.render_speed
[--scene FILE]`` (default the shipped dragon_heart_scale.toml).

Timings include a ``ctx.finish()``; each figure is the median of several repeats."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import moderngl

from deformgl.bench.sim_speed import machine_line, timed
from deformgl.sim.backends.explicit_gpu import FragmentIntegrator
from studies.common import gl_context, parse, parser, run_main


@dataclass
class RenderRow:
    """One draw path of ``studies.render_speed``."""

    name: str
    ms: float


def bench_render(ctx: moderngl.Context, scene_path, *, size: int = 1024, samples: int = 4,
                 repeats: int = 7, frame_size: int = 512, frame_steps: int = 15):
    """Draw paths of a mapped scene against the static mesh, and a simulate+draw frame.

    Returns:
        (rows, frame_ms, info): ms/frame of each draw path at ``size``² with ``samples``x MSAA;
        {MSAA samples: ms} of ``frame_steps`` simulation steps plus one curvature-corrected draw
        at ``frame_size``², with ``samples``x MSAA and without; and a dict of scene sizes, with "budgets": the frame split per AA mode
        (:func:`studies.aa.frame_budgets`).
    """
    from deformgl.render.mapped import MappedMeshPass, StaticMeshPass, closed_front_face
    from deformgl.render.mapped_setup import get_binding, mapped_vertices
    from deformgl.scene.pipeline import RENDER_MAPPING_PASS, build_scene_model, scene_lighting, scene_view
    from deformgl.sim.normals import rest_normals
    from deformgl.render.passes import GridSurfacePass, RenderTarget
    from deformgl.scene.schema import load_scene
    from deformgl.grid.surface import grid_surface

    scene = load_scene(scene_path)
    built = build_scene_model(scene)
    sim = FragmentIntegrator(ctx, built.system, built.grid, "verlet", scene.physics.dt, loads=built.loads,
                             path="foundation")
    sim.step(50)
    surface = grid_surface(built.grid)
    binding = get_binding(built.mesh, built.grid, surface, use_cache=True, uv=None)
    node_normals = rest_normals(built.grid)
    mesh = built.mesh
    # back faces culled as [render] cull = true does, where the mesh is closed (render.mapped.closed_front_face)
    front = closed_front_face(mesh.vertices, mesh.faces)
    passes: dict[str, StaticMeshPass | GridSurfacePass | MappedMeshPass] = {
        "static mesh": StaticMeshPass(ctx, mesh.vertices, mesh.vertex_normals, mesh.faces),
        "one-to-one": GridSurfacePass(ctx, built.grid, sim.textures.layout),
    }
    for mode in ("constant", "curvature"):
        data = mapped_vertices(binding, mode, built.grid.rest_positions, node_normals)
        for mapping_pass, suffix in (("vertex", ""), ("feedback", " 2-stage"), ("fragment", " fragment")):
            passes[mode + suffix] = MappedMeshPass(ctx, built.grid, sim.textures.layout, mesh.faces, data,
                                                   mapping_pass=mapping_pass)
        if mode == "curvature" and front is not None:  # what culling the back faces saves
            passes["curvature, culled"] = MappedMeshPass(ctx, built.grid, sim.textures.layout, mesh.faces, data,
                                                         front_face=front, mapping_pass=RENDER_MAPPING_PASS)
    view = scene_view(dataclasses.replace(scene, render=dataclasses.replace(scene.render, size=(size, size))),
                      built.bbox)
    lighting = scene_lighting(scene)
    target = RenderTarget(ctx, (size, size), samples)
    rows = []
    try:
        for name, p in passes.items():
            def draw(p=p) -> None:
                target.begin((1.0, 1.0, 1.0))
                if name == "static mesh":
                    p.draw(view, lighting)
                else:
                    p.draw(sim.position_texture, view, lighting)
                ctx.finish()
            draw()
            rows.append(RenderRow(name, timed(draw, repeats) * 1e3))
        frame_ms = {}
        # the frame as `deformgl render` draws it (its mapping pass)
        curvature = passes["curvature" + {"vertex": "", "feedback": " 2-stage", "fragment": " fragment"}[RENDER_MAPPING_PASS]]
        if not isinstance(curvature, MappedMeshPass):
            raise TypeError("bench_render: the curvature pass is not a MappedMeshPass")
        for frame_samples in (samples, 0):
            small = RenderTarget(ctx, (frame_size, frame_size), frame_samples)
            try:
                def frame() -> None:
                    sim.step(frame_steps)
                    small.begin((1.0, 1.0, 1.0))
                    curvature.draw(sim.position_texture, view, lighting)
                    ctx.finish()
                frame()
                frame_ms[frame_samples] = timed(frame, repeats) * 1e3
            finally:
                small.release()
        from studies.aa import frame_budgets, reference_name

        culled = passes.get("curvature, culled")
        budgets = frame_budgets(ctx, lambda: sim.step(frame_steps),
                                lambda: curvature.draw(sim.position_texture, view, lighting), frame_size,
                                _rgb(scene.render.background), repeats,
                                culled=None if not isinstance(culled, MappedMeshPass) else
                                lambda: culled.draw(sim.position_texture, view, lighting))
    finally:
        target.release()
        for p in passes.values():
            p.release()
        sim.release()
    info = {"faces": len(mesh.faces), "vertices": len(mesh.vertices), "nodes": built.grid.count,
            "size": size, "samples": samples, "frame_size": frame_size, "frame_steps": frame_steps,
            "budgets": budgets, "reference": reference_name(ctx), "culled": front is not None,
            "mapping_pass": RENDER_MAPPING_PASS,
            "layout": "compact" if sim.block is None else "blocks of " + "x".join(map(str, sim.block))}
    return rows, frame_ms, info


def _rgb(c) -> tuple[float, float, float]:
    return float(c[0]), float(c[1]), float(c[2])


def format_render(rows: list[RenderRow], frame_ms: dict[int, float], info: dict, machine: str) -> str:
    """The render table."""
    base = rows[0].ms
    lines = [machine,
             f"{info['vertices']} vertices / {info['faces']} faces on {info['nodes']} nodes; "
             f"{info['size']}x{info['size']}, {info['samples']}x MSAA; baseline: the static mesh; "
             "mappings in the drawing vertex shader (the paper's way); 2-stage: mapped once per vertex by "
             "transform feedback, then drawn; fragment: mapped once per vertex in a fragment pass, then drawn "
             f"(the frame below: {info.get('mapping_pass', 'vertex')}, as `deformgl render` draws); culled: back faces culled ([render] cull = true"
             f"{'' if info.get('culled') else '; not offered: the mesh is not closed'})",
             f"{'draw path':>20} | {'ms/frame':>9} | {'frames/s':>8} | {'rate vs static':>14}",
             "-" * 62]
    for r in rows:
        lines.append(f"{r.name:>20} | {r.ms:>9.2f} | {1e3 / r.ms:>8.1f} | {base / r.ms:>13.2f}x")
    for samples, ms in frame_ms.items():
        msaa = f"{samples}x MSAA" if samples else "no MSAA"
        lines.append(f"frame = {info['frame_steps']} simulation steps ({info.get('layout', 'compact')}) + one curvature-corrected draw at "
                     f"{info['frame_size']}x{info['frame_size']}, {msaa}: {ms:.1f} ms = {1e3 / ms:.1f} frames/s "
                     f"(the paper's 2005 GPU: 25 frames/s)")
    if "budgets" in info:
        from studies.aa import format_budgets

        lines += format_budgets(info["budgets"], info)
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from pathlib import Path

    from deformgl.data import packaged_scene, scene_file

    p = parser("render_speed", "draw paths of a mapped scene against the static mesh, and a simulate + draw frame")
    p.add_argument("--scene", type=Path, default=None, help="the scene (default: the shipped dragon_heart_scale.toml)")
    args = parse(p, argv)
    scene = scene_file(args.scene, "--scene") if args.scene else packaged_scene("dragon_heart_scale")
    with gl_context(args) as ctx:
        rows, frame_ms, info = bench_render(ctx, scene)
        print(format_render(rows, frame_ms, info, machine_line(ctx)))
    return 0


if __name__ == "__main__":
    run_main(main)
