"""Animations, camera paths and comparison grids from one simulation run.

:func:`render_frames` builds a scene once, starts its simulation once and draws every frame from
the simulation's GPU state between steps (:func:`deformgl.sim.run.run` calls back every
``steps_per_frame`` steps): on the fragment backend's Verlet pass (the default) the draw passes
read the state texture directly, so no node state crosses to the CPU between frames, only the
finished image. The other integrators and backends have no packed normals in their state; their
positions are read once per frame and uploaded to the normals pass (counted in the record as
``node_readbacks``).

A frame can be a grid of panels: rows of mapping modes (the paper's comparison of one-to-one,
constant and curvature mappings on the same state, Mosegaard & Sørensen 2005, section 3) and
columns of camera views, all drawn from the same node state; modes without views stand side by
side in one row.
"""

from __future__ import annotations

import dataclasses
import time as clock
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import moderngl
import numpy as np

from deformgl.errors import InputError
from deformgl.progress import Progress
from deformgl.render.camera import View
from deformgl.render.passes import RenderTarget
from deformgl.scene.budget import check_scene
from deformgl.scene.obstacles import draw_obstacles
from deformgl.scene.pipeline import (NodeState, SceneModel, build_scene_model, check_gl_limits, check_texture_limit,
                                     draw_attachments, make_draw_pass, scene_lighting, scene_view)
from deformgl.scene.record import run_record
from deformgl.scene.physics import SceneBox, SceneRun, simulate_scene, scene_constraints
from deformgl.scene.spec import Camera, Scene

__all__ = ["FramePlan", "Frames", "View3", "compose_grid", "frame_plan", "render_frames"]

#: A camera view of the command line: (azimuth degrees, elevation degrees, distance in box diagonals).
View3 = tuple[float, float, float]
#: How a panel names its mapping mode (Mosegaard & Sørensen 2005, section 3).
MODE_LABELS = {"one-to-one": "one-to-one: the node-grid surface", "constant": "constant triangle basis",
               "curvature": "curvature-corrected basis", "auto": "auto: curvature or constant basis per vertex"}
#: Most bytes of frames an animation keeps in memory before it is written.
MAX_FRAME_BYTES = 4 << 30


@dataclass(frozen=True)
class FramePlan:
    """What to draw: ``frames`` frames at ``fps``, frame k at scene step ``k * steps_per_frame``
    (0: every frame of the state after ``physics.steps``), with the camera of each frame."""

    frames: int
    fps: float
    steps_per_frame: int
    cameras: tuple[Camera, ...]

    @property
    def steps(self) -> int:
        """Scene steps the run takes (``(frames - 1) * steps_per_frame``, or ``physics.steps``)."""
        return (self.frames - 1) * self.steps_per_frame


def _interp(keys: Sequence[tuple[float, float]], at: float, default: float) -> float:
    if not keys:
        return default
    xs, ys = zip(*keys)
    return float(np.interp(at, xs, ys))


def frame_plan(scene: Scene, *, frames: int | None = None, fps: float | None = None,
               steps_per_frame: int | None = None, seconds_per_frame: float | None = None,
               turntable: float | None = None) -> FramePlan:
    """The frames of ``scene``: its ``[animation]`` table with the given values replacing its own
    (the command line's ``--frames``, ``--fps`` ...). Without a table and without ``frames``: one
    frame, the still. ``frames`` without a step count spreads ``physics.steps`` over the frames.

    Raises:
        InputError: a value out of range, or both step counts given (naming the flag).
    """
    anim = scene.animation
    file = str(scene.source)
    if frames is not None and not 1 <= frames <= 100_000:
        raise InputError(f"--frames: must be in 1..100000, got {frames}")
    if fps is not None and not 0 < fps <= 1000:
        raise InputError(f"--fps: must be in (0, 1000], got {fps:g}")
    if steps_per_frame is not None and steps_per_frame < 0:
        raise InputError(f"--steps-per-frame: must be >= 0, got {steps_per_frame}")
    if seconds_per_frame is not None and not seconds_per_frame >= 0:
        raise InputError(f"--seconds-per-frame: must be >= 0, got {seconds_per_frame:g}")
    if steps_per_frame is not None and seconds_per_frame is not None:
        raise InputError("--steps-per-frame and --seconds-per-frame: give at most one")
    n = frames if frames is not None else (anim.frames if anim is not None else 1)
    rate = fps if fps is not None else (anim.fps if anim is not None else 24.0)
    spf, spf_s = steps_per_frame, seconds_per_frame
    if spf is None and spf_s is None and anim is not None:
        spf, spf_s = anim.steps_per_frame, anim.seconds_per_frame
    if spf is None and spf_s is not None:
        spf = int(round(spf_s / scene.physics.dt))
        if spf_s > 0 and spf < 1:
            raise InputError(f"{file}: animation.seconds_per_frame: {spf_s:g} s is less than one step of "
                             f"physics.dt ({scene.physics.dt:g} s)")
    if spf is None:  # spread the scene's run over the frames
        spf = scene.physics.steps // (n - 1) if n > 1 else 0
    if scene.nodes.source != "simulate":
        spf = 0
    spin = turntable if turntable is not None else (anim.turntable if anim is not None else 0.0)
    keys = anim.camera if anim is not None else ()
    base = scene.render.camera
    cameras = []
    for k in range(n):
        at = k / (n - 1) if n > 1 else 0.0
        az = _interp([(c.at, c.azimuth) for c in keys if c.azimuth is not None], at, base.azimuth)
        el = _interp([(c.at, c.elevation) for c in keys if c.elevation is not None], at, base.elevation)
        dist = _interp([(c.at, c.distance) for c in keys if c.distance is not None], at, base.distance)
        cameras.append(dataclasses.replace(base, azimuth=az + spin * k / n, elevation=el, distance=dist))
    return FramePlan(n, rate, spf, tuple(cameras))


def compose_grid(panels: Sequence[Sequence[np.ndarray]], labels: Sequence[Sequence[str]] | None = None,
                 *, gap: int = 4, background: tuple[int, int, int] = (255, 255, 255)) -> np.ndarray:
    """Panels (rows of equal-size uint8 (H, W, 3) images) side by side in one image, ``gap``
    pixels apart, each labelled in its top-left corner when ``labels`` are given."""
    rows, cols = len(panels), max(len(r) for r in panels)
    h, w = panels[0][0].shape[:2]
    if rows == 1 and cols == 1 and not labels:
        return panels[0][0]
    out = np.empty((rows * h + (rows - 1) * gap, cols * w + (cols - 1) * gap, 3), np.uint8)
    out[:] = background
    for r, row in enumerate(panels):
        for c, image in enumerate(row):
            out[r * (h + gap):r * (h + gap) + h, c * (w + gap):c * (w + gap) + w] = image
    if labels:
        from PIL import Image, ImageDraw

        picture = Image.fromarray(out)
        draw = ImageDraw.Draw(picture)
        for r, row_labels in enumerate(labels):
            for c, text in enumerate(row_labels):
                if text:
                    x, y = c * (w + gap) + 6, r * (h + gap) + 4
                    draw.text((x, y), text, fill=(20, 20, 20))
        out = np.asarray(picture)
    return out


class NodeSample(NamedTuple):
    """One frame's node state, read back for exported fields."""

    time_s: float            #: simulated time of the frame (s)
    x: np.ndarray            #: (N, 3) float64 positions, recentred (m)
    v: np.ndarray | None     #: (N, 3) float64 velocities (m/s); None where the nodes were not simulated
    dt: float                #: the simulation's step (s); 0 without one


@dataclass
class Frames:
    """What :func:`render_frames` produced: the frames (uint8 (H, W, 3) each), on request the
    deformed mesh of each frame (vertices (V, 3) float64 world, normals, faces) and its node
    state, and the run record (:func:`deformgl.scene.record.run_record`)."""

    images: list[np.ndarray]
    meshes: list[tuple[np.ndarray, np.ndarray, np.ndarray]] | None
    record: dict[str, Any] = field(default_factory=dict)
    #: on request (``nodes=True``), each frame's node state
    nodes: list[NodeSample] | None = None
    #: the scene's model (:class:`~deformgl.scene.pipeline.SceneModel`: mesh, grid, centre)
    model: Any = None
    #: with ``mesh=True``: the per-vertex mapping data the meshes were captured with
    #: (:class:`~deformgl.render.mapped_setup.MappedVertices` of the first detailed-mesh mode)
    mapped: Any = None


class _Drawer:
    """The draw passes of every mapping mode asked for, one render target, the lights."""

    def __init__(self, ctx: moderngl.Context, scene: Scene, built: SceneModel, layout, modes: Sequence[str],
                 log: Callable[[str], None] | None) -> None:
        self.ctx, self.scene, self.built = ctx, scene, built
        if getattr(built, "spline", None) is not None and len(modes) > 1:
            raise InputError(f'{scene.source}: modes: a spline body (material.model = "spline") is drawn through its '
                             f"field: one panel, not one per mapping mode")
        self.passes: dict[str, Any] = {}
        self.target: RenderTarget | None = None
        try:
            for mode in modes:
                variant = dataclasses.replace(scene, mapping=dataclasses.replace(scene.mapping, mode=mode))
                self.passes[mode] = make_draw_pass(ctx, variant, built, layout, log=log if not self.passes else None)
            self.target = RenderTarget(ctx, scene.render.size, scene.render.samples, fxaa=scene.render.fxaa)
        except BaseException:
            self.release()
            raise
        self.lighting = scene_lighting(scene)
        self.constraints = scene_constraints(scene.physics, SceneBox(*built.bbox))

    def draw(self, texture: moderngl.Texture, t: float, camera: Camera, mode: str,
             capture: bool) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray] | None]:
        scene, built, target = self.scene, self.built, self.target
        assert target is not None
        view = _view_of(scene, built, camera)
        draw_pass = self.passes[mode]
        target.begin(tuple(scene.render.background))  # type: ignore[arg-type]
        draw_pass.draw(texture, view, self.lighting)
        if self.constraints is not None:
            target.fbo.use()
            draw_obstacles(self.ctx, self.constraints, t, built.bbox[0], built.bbox[1], built.grid.spacing, view,
                           self.lighting)
        captured = None
        if mode != "one-to-one" and (capture or scene.attach):
            captured = draw_pass.capture(texture)
        if scene.attach and captured is not None:
            target.fbo.use()
            draw_attachments(self.ctx, scene, built, captured[0].astype(np.float64), view, self.lighting)
        return target.read_rgb(), captured

    def release(self) -> None:
        for obj in [self.target, *self.passes.values()]:
            if obj is not None:
                obj.release()
        self.passes, self.target = {}, None


def _check_modes(scene: Scene, modes: Sequence[str]) -> None:
    for mode in modes:
        scene.with_overrides(mapping=mode)  # the --mapping checks: a cloth, attachments


def _frame_camera(plan: FramePlan, k: int, view: View3 | None) -> Camera:
    """Frame k's camera, or with ``view`` that view turned as far as the turntable has."""
    camera = plan.cameras[k]
    if view is None:
        return camera
    spin = camera.azimuth - plan.cameras[0].azimuth
    return dataclasses.replace(camera, azimuth=view[0] + spin, elevation=view[1], distance=view[2])


def _view_of(scene: Scene, built: SceneModel, camera: Camera) -> View:
    """The view matrices of ``camera`` on the scene's body (refuses one that misses the body)."""
    return scene_view(dataclasses.replace(scene, render=dataclasses.replace(scene.render, camera=camera)), built.bbox)


def render_frames(ctx: moderngl.Context, scene: Scene, plan: FramePlan | None = None, *,
                  modes: Sequence[str] | None = None, views: Sequence[View3] | None = None, mesh: bool = False,
                  nodes: bool = False, progress: bool = False, log: Callable[[str], None] | None = None,
                  check_model: Callable[[Scene, SceneModel], None] | None = None) -> Frames:
    """Simulate ``scene`` once and draw the frames of ``plan`` (default :func:`frame_plan`).

    Args:
        modes: mapping modes, one row of panels each (default: the scene's ``mapping.mode``); without
            ``views``, one panel each, side by side.
        views: camera views ``(azimuth, elevation, distance)``, one column each (default: the
            frame's camera); the turntable's azimuth is added to each.
        mesh: also capture each frame's deformed detailed mesh (from the first mode that draws the
            detailed mesh).
        nodes: also read back each frame's node positions and velocities (:attr:`Frames.nodes`).
        progress: a progress bar of frames on stderr.
        log: receives the binding report and the run's notes.
        check_model: called with the scene and its model before any simulation (a refusal that
            needs the built grid).
    """
    started = clock.perf_counter()
    plan = frame_plan(scene) if plan is None else plan
    modes = list(modes) if modes else [scene.mapping.mode]
    _check_modes(scene, modes)
    mapped = [m for m in modes if m != "one-to-one"]
    if mesh and not mapped:
        raise InputError(f"{scene.source}: --export-mesh needs a mapping of the detailed mesh "
                         f"(--mapping constant, curvature or auto), not one-to-one")
    w, h = scene.render.size
    panels = len(modes) * max(len(views or ()), 1)
    if plan.frames * panels * w * h * 3 > MAX_FRAME_BYTES:
        raise InputError(f"{scene.source}: {plan.frames} frames of {panels} panel(s) of {w}x{h} would need "
                         f"{plan.frames * panels * w * h * 3 / 2**30:.1f} GiB of memory; use fewer frames or "
                         f"a smaller render.size")
    simulate = scene.nodes.source == "simulate" and plan.steps_per_frame > 0
    if simulate:  # the run the animation takes
        scene = dataclasses.replace(scene, physics=dataclasses.replace(scene.physics, steps=plan.steps))
    check_gl_limits(ctx, scene)
    check_scene(ctx, scene)
    built = build_scene_model(scene)
    check_texture_limit(scene, built.grid, int(ctx.info["GL_MAX_TEXTURE_SIZE"]))
    if check_model is not None:
        check_model(scene, built)
    for k in range(plan.frames):  # a camera that cannot see the body: refused before the run
        for view in (list(views) if views else [None]):
            _view_of(scene, built, _frame_camera(plan, k, view))
    images: list[np.ndarray | None] = [None] * plan.frames
    meshes: list[Any] = [None] * plan.frames
    states: list[Any] = [None] * plan.frames
    readbacks = [0]
    upload: list[Any] = []  # the textures and normals pass of a simulation without packed normals
    drawer: _Drawer | None = None
    drawer_mapping: Any = None  # the capture mode's per-vertex data (Frames.mapped)
    state: NodeState | None = None
    run: SceneRun | None = None
    notes: list[str] = []

    def draw_frame(k: int, texture: moderngl.Texture, t: float) -> None:
        assert drawer is not None
        grid, labels = [], []
        for mode in modes:
            row, names = [], []
            for view in (list(views) if views else [None]):
                camera = _frame_camera(plan, k, view)
                capture = mesh and meshes[k] is None and mode == mapped[0]
                image, captured = drawer.draw(texture, t, camera, mode, capture)
                if capture and captured is not None:
                    meshes[k] = (captured[0].astype(np.float64) + built.centre, captured[1], built.mesh.faces)
                row.append(image)
                names.append(", ".join(x for x in (MODE_LABELS[mode] if len(modes) > 1 else "",
                                                  f"az {camera.azimuth:g} el {camera.elevation:g}"
                                                  if views and len(views) > 1 else "") if x))
            grid.append(row)
            labels.append(names)
        if not views and len(modes) > 1:  # modes alone: side by side
            grid, labels = [[row[0] for row in grid]], [[names[0] for names in labels]]
        images[k] = compose_grid(grid, labels if panels > 1 else None)

    with Progress(plan.frames, "frames", enabled=progress) as bar:
        try:
            if simulate:
                from deformgl.mapping.node_drivers import DrivenNodes
                from deformgl.sim.backends.verlet_data import NodeTextures

                def texture_of(sim) -> moderngl.Texture:
                    if getattr(sim, "packed_normals", False):
                        return sim.position_texture  # drawn where it is: nothing is read back
                    if not upload:
                        upload.append(NodeTextures(ctx, built.grid))
                        upload.append(DrivenNodes(ctx, upload[0], built.grid))
                    readbacks[0] += 1
                    upload[1].set_positions(np.asarray(sim.positions(), np.float64))
                    return upload[1].position_texture

                from deformgl.grid.nodes import CompactLayout

                # the layout NodeTextures gives every backend's state texture by default
                node_layout = CompactLayout.for_grid(built.grid, int(ctx.info["GL_MAX_TEXTURE_SIZE"]))
                drawer = _Drawer(ctx, scene, built, node_layout, modes, log)

                def on_frame(step: int, sim) -> None:
                    k = step // plan.steps_per_frame
                    if k < plan.frames:
                        draw_frame(k, texture_of(sim), step * scene.physics.dt)
                        if nodes:
                            readbacks[0] += 2
                            states[k] = NodeSample(step * scene.physics.dt, np.asarray(sim.positions(), np.float64),
                                                   np.asarray(sim.velocities(), np.float64), float(sim.dt))
                        bar.update(k + 1)

                run = simulate_scene(ctx, scene, built.grid, built.system, built.loads, SceneBox(*built.bbox),
                                progress=False, notes=notes, keep=True, frame_every=plan.steps_per_frame,
                                on_frame=on_frame)
                if run.sim is not None:
                    run.sim.release()
                    run.sim = None
                last = max(k for k, image in enumerate(images) if image is not None)
                for k in range(last + 1, plan.frames):  # converged before the end: the state stays
                    images[k], meshes[k] = images[last], meshes[last]
                    if nodes:  # at rest: the state stays, the clock goes on
                        rest = states[last]
                        states[k] = rest._replace(time_s=k * plan.steps_per_frame * scene.physics.dt,
                                                  v=np.zeros_like(rest.x))
            else:
                state = NodeState(ctx, scene, built, progress=False, velocities=nodes)
                run = state.run
                notes = state.notes
                drawer = _Drawer(ctx, scene, built, state.layout, modes, log)
                t = run.time if run is not None else 0.0
                for k in range(plan.frames):
                    draw_frame(k, state.position_texture, t)
                    if nodes:  # (one state: several frames of it are refused by check_job)
                        states[k] = NodeSample(t, state.positions(), *state.velocities())
                    bar.update(k + 1)
        finally:
            if drawer is not None:
                if mesh:
                    drawer_mapping = drawer.passes[mapped[0]].data
                drawer.release()
            if state is not None:
                state.release()
            for obj in reversed(upload):
                obj.release()
    if log is not None:
        for note in notes:
            log(f"{scene.name}: {note}")
    record = run_record(scene, built, run, frames=plan.frames, fps=plan.fps, wall=clock.perf_counter() - started,
                        ctx=ctx)
    record["steps_per_frame"] = plan.steps_per_frame
    record["node_readbacks"] = readbacks[0]
    record["panels"] = panels
    return Frames([im for im in images if im is not None], [m for m in meshes if m is not None] if mesh else None,
                  record, states if nodes else None, built,
                  drawer_mapping if mesh else None)
