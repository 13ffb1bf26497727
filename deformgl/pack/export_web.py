"""``deformgl export-web SCENE OUT_DIR``: what ``examples/web/`` needs to run a scene in a browser.

The scene must run on the foundation's position-Verlet pass (``sim/verlet.frag``: integrator
verlet, fragment backend, no spheres, ground, drags or convergence stop; pulls are fine; a
material's volumetric term as defines and uniforms, except its centre term (poissons_ratio >
0.25) on a grid that is not dense, whose cell-diagonal texture the page does not bind) and map a
detailed mesh (constant, curvature or auto). OUT_DIR receives, written as one
:class:`~deformgl.files.OutputSet` (all or none):

* ``shaders/``: the pack in the ``es`` profile (``deformgl export-shaders --profile es``);
* ``scene.json``: sizes, the pass's defines and uniforms, the time step, the step count, the
  camera and lights, and for each binary file its dtype and shape;
* little-endian binary files, row-major, exactly the textures and buffers deformgl uploads:
  ``node.f32`` (H, W, 4) node data, ``state_current.f32`` / ``state_previous.f32`` (H, W, 4) the
  start state (xyz, w packed normal), ``neighbours.i32`` (5, H, W, 4) (only for a compact layout
  that is not dense), ``spring_weights.f32`` (5, H, W, 4) (only for a material scene whose
  per-spring weights of ``SPRING_WEIGHTS`` are not the lattice's cell shares; those travel as the
  levels code in ``node.f32``'s alpha, ``SPRING_WEIGHT_LEVELS``), ``pulls.f32`` (steps, PULLS, 3) the pull force of each group at each step
  (N per node; N/kg on nodes with the flag FLAG_PULLS_PER_KG, a material scene's), ``texel1..3.i32`` (V, 2), ``weights``/``offset``/``offset_world``/``normal``/
  ``normal_world.f32`` (V, 3), ``curvature.f32`` (V,), ``faces.u32`` (F, 3).

docs of the layouts: docs/ARCHITECTURE.md ("Textures: channel layouts"); of the shaders:
shaders/README.md; of the page: examples/web/README.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
from pathlib import Path

import numpy as np

from deformgl.errors import InputError
from deformgl.files import OutputSet, write_atomic
from deformgl.gl.context import create_context
from deformgl.gl.es_context import read_texture
from deformgl.grid.nodes import CompactLayout
from deformgl.pack.export_shaders import PACK_VERSION, pack_contents, write_pack
from deformgl.scene.pipeline import build_scene_model, make_draw_pass, scene_lighting, scene_view
from deformgl.scene.physics import SceneBox, scene_constraints, scene_drags
from deformgl.scene.schema import load_scene
from deformgl.scene.spec import Scene
from deformgl.sim.backends.verlet_data import verlet_terms
from deformgl.sim.guards import plan_steps
from deformgl.sim.simulation import make_simulation

__all__ = ["add_parser", "export_web", "web_scene"]


def web_scene(path: Path, *, steps: int | None = None, size: tuple[int, int] | None = None,
              mapping: str | None = None) -> Scene:
    """The scene as the page runs it: overrides applied, no MSAA (the canvas has no
    ``antialias``: sample positions and resolves differ between renderers, so a frame is
    compared without), checked to run on the foundation pass with a mapped mesh."""
    scene = load_scene(path).with_overrides(steps=steps, size=size, mapping=mapping)
    scene = dataclasses.replace(scene, render=dataclasses.replace(scene.render, msaa=1))
    p = scene.physics
    if p.integrator != "verlet" or p.backend != "fragment":
        raise InputError(f"{scene.source}: physics.integrator/backend: export-web runs the foundation's "
                         f"Verlet fragment pass (verlet on fragment), not {p.integrator} on {p.backend}")
    if scene.nodes.source != "simulate" or scene.mapping.mode == "one-to-one":
        raise InputError(f"{scene.source}: mapping.mode: export-web draws a simulated, mapped detailed "
                         f"mesh (constant, curvature or auto; --mapping)")
    if scene.mapping.normal_map is not None:
        raise InputError(f"{scene.source}: mapping.normal_map: the web example draws no normal map")
    if p.converge is not None:
        raise InputError(f"{scene.source}: physics.converge: export-web runs a fixed number of steps")
    return scene


def export_web(path: Path, out: Path, *, steps: int | None = None, size: tuple[int, int] | None = None,
               mapping: str | None = None) -> list[Path]:
    """Export ``path`` for the web example into ``out``; returns the files written. A refusal (or
    any failure) leaves nothing behind: no file, and none of the folders this call created."""
    scene = web_scene(path, steps=steps, size=size, mapping=mapping)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    top = _first_missing(out)  # the outermost folder of out's path the export creates, or None
    before = _folders(out / "shaders")
    try:
        return _export(scene, out)
    except BaseException:
        _remove_new_empty_folders(out, top, before)
        raise


def _first_missing(folder: Path) -> Path | None:
    """The outermost of ``folder`` and its parents that does not exist, or None."""
    missing = None
    while not folder.exists() and folder != folder.parent:
        missing, folder = folder, folder.parent
    return missing


def _folders(top: Path) -> set[Path]:
    """``top`` and every folder under it that exists now (the export writes only under
    ``out/shaders`` and ``out`` itself, so only that subtree is walked)."""
    if not top.is_dir():
        return set()
    return {top, *(Path(d) / name for d, names, _ in os.walk(top) for name in names)}


def _remove_new_empty_folders(out: Path, top: Path | None, before: set[Path]) -> None:
    """Remove the folders the export made, deepest first, where they hold nothing: those under
    ``out/shaders`` (and it) that were not in ``before``, then ``out`` and its parents up to
    ``top`` when they were missing. A file that appeared in them (not this export's: its set
    writes all or none) stays, with its folders."""
    shaders = out / "shaders"
    if shaders.is_dir():
        for folder, _, _ in os.walk(shaders, topdown=False):  # every folder after the ones inside it
            if Path(folder) not in before:
                try:
                    os.rmdir(folder)
                except OSError:
                    pass
    if top is None:
        return
    made = out
    while True:
        try:
            os.rmdir(made)
        except OSError:
            return
        if made == top or made == made.parent:
            return
        made = made.parent


def _export(scene: Scene, out: Path) -> list[Path]:
    shaders = pack_contents(out / "shaders", "es")
    OutputSet(list(shaders) + [out / "scene.json"], "web export file")  # every path checked before the GL work
    if getattr(scene.physics.material, "model", None) == "spline":
        raise InputError(f'{scene.source}: material.model: export-web runs the lattice\'s foundation pass; a spline '
                         f"body has no web client yet")
    ctx = create_context()
    try:
        built = build_scene_model(scene)
        box = SceneBox(*built.bbox)
        if scene_constraints(scene.physics, box) is not None or scene_drags(built.grid, scene.physics, box):
            raise InputError(f"{scene.source}: physics: export-web supports no ground, spheres or drags")
        plan = plan_steps(built.system, scene.physics, scene.source)
        # the web clients read node n at texel (n % w, n / w): the compact layout, pinned (not the
        # blocked layout "auto" takes on large grids; docs/INTERCHANGE.md, shaders/README.md)
        sim = make_simulation(built.system, "verlet", "fragment", dt=plan.dt / plan.substeps, ctx=ctx, grid=built.grid,
                              loads=built.loads, layout="compact")
        try:
            if getattr(sim, "fast", None) is None:
                raise InputError(f"{scene.source}: physics: this system does not run on the foundation pass "
                                 f"(flexion springs or per-spring values): export-web cannot run it")
            arrays, info = _collect(ctx, scene, built, sim, plan)
        finally:
            sim.release()
    finally:
        ctx.release()
    targets = {name: out / name for name in arrays}
    with OutputSet([*shaders, *targets.values(), out / "scene.json"], "web export file"):  # all or none
        write_pack(shaders)
        for name, arr in arrays.items():
            data = np.ascontiguousarray(arr).astype(arr.dtype.newbyteorder("<")).tobytes()
            write_atomic(targets[name], lambda f, d=data: f.write(d))  # type: ignore[misc]
        text = json.dumps(info, indent=1) + "\n"
        write_atomic(out / "scene.json", lambda f: f.write(text.encode("utf-8")))
    return [*shaders, *targets.values(), out / "scene.json"]


def _collect(ctx, scene: Scene, built, sim, plan) -> tuple[dict[str, np.ndarray], dict]:
    fast = sim.fast
    textures = fast.textures
    layout = textures.layout
    w, h = layout.size
    draw = make_draw_pass(ctx, scene, built, layout)
    try:
        data = draw.data
        curvature = bool(draw.curvature)
    finally:
        draw.release()

    def tex(t) -> np.ndarray:
        return np.frombuffer(read_texture(t), dtype="<f4").reshape(h, w, 4)

    arrays: dict[str, np.ndarray] = {
        "node.f32": tex(textures.node), "state_current.f32": tex(textures.state[fast.current]),
        "state_previous.f32": tex(textures.state[fast.previous])}
    if textures.neighbours is not None:
        arrays["neighbours.i32"] = np.frombuffer(textures.neighbours.read(), dtype="<i4").reshape(5, h, w, 4)
    if textures.weights is not None:  # a material's calibrated lattice (SPRING_WEIGHTS)
        arrays["spring_weights.f32"] = np.frombuffer(textures.weights.read(), dtype="<f4").reshape(5, h, w, 4)
    n_pulls = fast.verlet.n_pulls
    dt = plan.dt / plan.substeps
    pulls = np.zeros((plan.steps * plan.substeps, max(n_pulls, 1), 3), np.float32)
    for k in range(len(pulls)):
        for g, load in enumerate(fast.loads):
            pulls[k, g] = np.asarray(load.force(k * dt), dtype=np.float64)
    arrays["pulls.f32"] = pulls
    grid = built.grid
    for c in range(3):
        arrays[f"texel{c + 1}.i32"] = layout.texel(grid.ijk[data.tri_nodes[:, c]]).astype("<i4")
    for name in ("weights", "offset", "offset_world", "normal", "normal_world"):
        arrays[f"{name}.f32"] = np.asarray(getattr(data, name), dtype="<f4")
    arrays["curvature.f32"] = np.asarray(data.use_curvature, dtype="<f4")
    arrays["faces.u32"] = np.asarray(built.mesh.faces, dtype="<u4")
    terms = verlet_terms(built.system, grid, loads=fast.loads)
    if isinstance(terms, str):  # (the fast path was taken, so the terms exist)
        raise InputError(f"{scene.source}: physics: {terms}")
    view, lighting = scene_view(scene, built.bbox), scene_lighting(scene)
    dense = isinstance(layout, CompactLayout) and layout.dense
    defines = {"PULLS": n_pulls, **{k: v for k, v in layout.shader_defines().items() if v}}
    if textures.weights is not None or textures.weight_levels:
        defines["SPRING_WEIGHTS"] = True
    if textures.weight_levels:  # the weights are the node texture's alpha (node.f32)
        defines["SPRING_WEIGHT_LEVELS"] = True
    # the physics terms (a material's volumetric term: its node bits travel in node.f32's G)
    if textures.hood_diagonals is not None:
        raise InputError(f"{scene.source}: material: the volumetric term's centre term (poissons_ratio > 0.25) "
                         f"on a grid that is not dense needs the hood-diagonal texture, which the web page "
                         f"does not bind: export-web cannot run it")
    defines.update({k: v for k, v in terms.extra.defines().items() if v})
    cell_uniforms = terms.extra.uniforms(())  # (no term tables: the page binds none)
    uniforms = {"u_spacing": terms.spacing, "u_k_structural": terms.k_structural, "u_k_shear": terms.k_shear,
                "u_damping": terms.damping, "u_mass_damping": terms.mass_damping, "u_gravity": list(terms.gravity),
                "u_dt": dt, **cell_uniforms,
                **{k: (list(v) if isinstance(v, tuple) else v) for k, v in layout.shader_uniforms().items()
                   if k != "u_neighbours"}}
    info = {
        "pack_version": PACK_VERSION, "scene": scene.name, "steps": int(len(pulls)),
        "texture": {"width": w, "height": h, "nodes": grid.count, "dense": dense,
                    "compact": isinstance(layout, CompactLayout)},
        "verlet": {"defines": defines, "uniforms": uniforms},
        "mapping": {"defines": {"CURVATURE": True} if curvature else {}, "vertices": len(data.weights),
                    "triangles": len(built.mesh.faces)},
        "view": {"view_projection_column_major": [float(v) for v in view.view_projection.T.ravel()],
                 "eye": [float(v) for v in view.eye]},
        "lighting": {k: np.asarray(v, dtype=np.float64).tolist() for k, v in lighting.uniforms().items()},
        "size": list(scene.render.size), "antialias": scene.render.samples > 1 or scene.render.fxaa, "background": [float(v) for v in scene.render.background],
        "files": {name: {"dtype": name.rsplit(".", 1)[1], "shape": list(arr.shape)} for name, arr in arrays.items()},
    }
    return arrays, info


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Adds ``export-web`` to a CLI's subparsers."""
    p = subparsers.add_parser(
        "export-web", help="export a scene's node grid, binding and the ES shaders for examples/web",
        description="Write what examples/web/index.html loads: the ES shader pack, the node textures, "
                    "neighbour data, bound vertex attributes and pull forces as binary files, and "
                    "scene.json describing them (see examples/web/README.md).")
    p.add_argument("scene", type=Path, help="scene file (.toml) on the foundation Verlet pass with a mapped mesh")
    p.add_argument("out", type=Path, metavar="OUT_DIR", help="output folder (created)")
    p.add_argument("--steps", type=int, default=None, help="override physics.steps (the page's fixed steps)")
    p.add_argument("--size", default=None, metavar="WxH", help="override render.size (the canvas)")
    p.add_argument("--mapping", choices=("constant", "curvature", "auto"), default=None,
                   help="override mapping.mode")
    return p


def run(args: argparse.Namespace) -> int:
    from deformgl.data import find_scene
    from deformgl.scene.spec import parse_size

    try:
        size = parse_size(args.size) if args.size else None
    except ValueError as exc:
        raise InputError(f"--size: {exc}") from None
    files = export_web(find_scene(args.scene), args.out, steps=args.steps, size=size, mapping=args.mapping)
    print(f"wrote {len(files)} files and the es shader pack to {args.out}")
    return 0
