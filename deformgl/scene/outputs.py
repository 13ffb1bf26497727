"""One render of a scene to its files: a still PNG, an animation (MP4, GIF, WebP, PNG frames) or
a grid of panels, the exported mesh (or mesh sequence), the shader-pack inputs and the run
record (JSON), all committed together as one :class:`~deformgl.files.OutputSet` (all or none).

This is what ``deformgl render`` and :func:`deformgl.render_animation` call; the still with no
panels takes the same path as :func:`deformgl.scene.pipeline.render_to_png`.
"""

from __future__ import annotations

import dataclasses
import os
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import moderngl

from deformgl.errors import InputError
from deformgl.files import OutputSet, check_folder, write_png_atomic
from deformgl.render.gltf_morph import write_morph_glb
from deformgl.render.mapped_setup import export_mesh
from deformgl.render.video import AnimationWriter, animation_kind, check_encoder, frame_paths
from deformgl.scene.animation import FramePlan, View3, frame_plan, render_frames
from deformgl.scene.fields import check_grid_export, grid_series, mesh_series
from deformgl.scene.spline_fields import body_series, spline_mesh_series
from deformgl.scene.interchange import MESH_FORMATS, check_format, is_interchange, series_paths, write_series
from deformgl.scene.pipeline import render_still
from deformgl.scene.record import write_record
from deformgl.scene.spec import Scene

__all__ = ["Job", "check_job", "default_record_path", "render_animation", "render_job"]


@dataclass(frozen=True)
class Job:
    """What to render and where (every path checked by :meth:`outputs` before any work).

    Attributes:
        output: a .png still, or an animation: .mp4, .gif, .webp or a frame pattern DIR/%04d.png.
        plan: the frames (None: :func:`~deformgl.scene.animation.frame_plan` of the scene).
        modes, views: the panels of each frame (mapping modes by rows, camera views by columns).
        export: the deformed mesh (.ply/.obj/.glb; for several frames a pattern DIR/%04d.ply, or
            one .glb animated by morph targets), or a time series for ParaView (.pvd, .xdmf, a
            one-frame .vtu) or USD (.usd, .usda, .usdc) with its fields
            (:mod:`deformgl.scene.interchange`, :mod:`deformgl.scene.fields`).
        grid: the node grid's time series for ParaView (.pvd, .xdmf, .vtu), or None.
        pack: the shader-pack inputs (.npz; a still only).
        record: where the run record goes as JSON (None: not written).
    """

    output: Path
    plan: FramePlan | None = None
    modes: Sequence[str] | None = None
    views: Sequence[View3] | None = None
    export: Path | None = None
    pack: Path | None = None
    record: Path | None = None
    grid: Path | None = None

    def outputs(self, frames: int) -> list[Path]:
        """Every file this job writes for ``frames`` frames."""
        paths: list[Path] = []
        paths += frame_paths(self.output, frames) if animation_kind(self.output) == "frames" else [self.output]
        if is_interchange(self.export):
            assert self.export is not None
            paths += series_paths(self.export, frames)
        elif self.export is not None:
            paths += frame_paths(self.export, frames) if _is_pattern(self.export) else [self.export]
        if self.grid is not None:
            paths += series_paths(self.grid, frames)
        return paths + [p for p in (self.pack, self.record) if p is not None]


def _is_pattern(path: Path) -> bool:
    return len(re.findall(r"%0?\d*d", path.name)) == 1


def default_record_path(output: Path) -> Path:
    """Where ``--json`` writes the record: next to the output, ``NAME.json`` (a frame pattern:
    the pattern without its ``%04d``, or ``frames.json``)."""
    stem = re.sub(r"%0?\d*d", "", output.stem).strip("_-. ") or "frames"
    return output.parent / f"{stem}.json"


def check_job(scene: Scene, job: Job) -> FramePlan:
    """Refuse what cannot be written, before any work; returns the frame plan."""
    plan = job.plan if job.plan is not None else frame_plan(scene)
    kind = animation_kind(job.output)
    suffix = job.output.suffix.lower()
    if kind is None and suffix != ".png":
        raise InputError(f"{job.output}: the output must be a .png still, or an animation (.mp4, .gif, .webp, "
                         f"or a frame pattern such as frames/%04d.png)")
    if kind is None and plan.frames > 1:
        raise InputError(f"{job.output}: {plan.frames} frames need an animation output (.mp4, .gif, .webp or "
                         f"frames/%04d.png), not a single .png")
    check_encoder(job.output)
    if getattr(scene.physics.material, "model", None) == "spline":  # (what reads the lattice's mapping)
        if job.pack is not None:
            raise InputError(f'{job.pack}: --pack-inputs is not written for material.model = "spline" yet (the '
                             f"shader pack's mappings are the lattice's; the mesh is drawn through the body's field)")
        if job.modes:
            raise InputError(f'{scene.source}: --compare draws the lattice\'s mappings; material.model = "spline" '
                             f"draws the mesh through its field")
    if is_interchange(job.export):
        assert job.export is not None
        check_format(job.export, "--export-mesh", plan.frames)
    elif job.export is not None:
        if job.export.suffix.lower() not in (".ply", ".obj", ".glb"):
            raise InputError(f"{job.export}: --export-mesh must end in .ply, .obj, .glb, or a time series: "
                             f"{', '.join(MESH_FORMATS)}")
        if plan.frames > 1 and not _is_pattern(job.export) and job.export.suffix.lower() != ".glb":
            raise InputError(f"{job.export}: --export-mesh of {plan.frames} frames needs a pattern such as "
                             f"meshes/%04d.ply (one mesh per frame) or one animated .glb (morph targets)")
    if job.grid is not None:
        check_format(job.grid, "--export-grid", plan.frames, grid=True)
    series = next((p for p in (job.export, job.grid) if is_interchange(p)), None)
    if series is not None:
        if job.pack is not None:
            raise InputError(f"{job.pack}: --pack-inputs writes the inputs of one still, not with a time series "
                             f"({series})")
        if plan.frames > 1 and not (scene.nodes.source == "simulate" and plan.steps_per_frame > 0):
            raise InputError(f"{series}: the {plan.frames} frames show one node state (no simulation steps "
                             f"between them): a time series of it is one frame (--frames 1), or give the "
                             f"frames steps (--steps-per-frame N, or physics.steps of at least one per frame)")
    if job.pack is not None:
        if job.pack.suffix.lower() != ".npz":
            raise InputError(f"{job.pack}: --pack-inputs must end in .npz")
        if kind is not None or job.modes or job.views:
            raise InputError(f"{job.pack}: --pack-inputs writes the inputs of one still, not of an animation "
                             f"or a grid of panels")
    seen: dict[str, Path] = {}
    for p in job.outputs(plan.frames):
        key = os.path.realpath(p)  # (never raises, unlike Path.resolve on a symlink loop)
        if key in seen:
            raise InputError(f"{p}: named twice among the outputs (as {seen[key]} too)")
        seen[key] = p
        check_folder(p)
    return plan


def render_job(ctx: moderngl.Context, scene: Scene, job: Job, *, progress: bool = False,
               log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Render ``scene`` as ``job`` says and write every file together; returns the run record
    (with ``outputs``: the files written)."""
    plan = check_job(scene, job)
    series = is_interchange(job.export) or job.grid is not None  # the time series take the frames' path
    still = animation_kind(job.output) is None and not job.modes and not job.views and plan.frames == 1 and not series
    if series and plan.frames == 1:  # one frame: the still's run (physics.steps), not (frames - 1) x steps per frame
        plan = dataclasses.replace(plan, steps_per_frame=0)
    if still:  # the one-image path of render_to_png
        return render_still(ctx, scene, job.output, progress=progress, export=job.export, pack=job.pack,
                            record=job.record, log=log).record
    outputs = OutputSet(job.outputs(plan.frames))  # every path checked before any work
    frames = render_frames(ctx, scene, plan, modes=job.modes, views=job.views, mesh=job.export is not None,
                           nodes=series, progress=progress, log=log,
                           check_model=None if job.grid is None else check_grid_export)
    record, images, meshes = frames.record, frames.images, frames.meshes
    record["outputs"] = [str(p) for p in job.outputs(plan.frames) if p != job.record]
    with outputs:
        if animation_kind(job.output) is None:
            write_png_atomic(job.output, images[0])
        else:
            with AnimationWriter(job.output, plan.fps) as writer:
                for image in images:
                    writer.write_frame(image)
        if is_interchange(job.export):
            assert job.export is not None
            write_series(job.export, (mesh_series if getattr(frames.model, "spline", None) is None else spline_mesh_series)(frames, plan.fps))
        elif job.export is not None:
            if not meshes:
                raise RuntimeError("the render returned no mesh for --export-mesh")  # it always does
            if _is_pattern(job.export):
                for path, mesh in zip(frame_paths(job.export, len(meshes)), meshes):
                    export_mesh(path, *mesh)
            elif len(meshes) > 1:  # one animated glTF: a morph target per frame
                write_morph_glb(job.export, [(v, n) for v, n, _ in meshes], meshes[0][2], plan.fps)
            else:
                export_mesh(job.export, *meshes[0])
        if job.grid is not None:
            write_series(job.grid, (grid_series if getattr(frames.model, "spline", None) is None else body_series)(frames, plan.fps))
        if job.record is not None:
            write_record(job.record, record)
    return record


def render_animation(scene: Scene | str | Path, path: str | Path | None = None, *, frames: int | None = None,
                     fps: float | None = None, steps_per_frame: int | None = None,
                     seconds_per_frame: float | None = None, turntable: float | None = None,
                     modes: Sequence[str] | None = None, views: Sequence[View3] | None = None,
                     overrides: dict[str, Any] | None = None, ctx: moderngl.Context | None = None,
                     progress: bool = False) -> tuple[Any, dict[str, Any]]:
    """Simulate a scene once and draw its frames (the Python side of ``deformgl render
    SCENE -o out.gif --frames N``).

    Args:
        scene: a loaded :class:`~deformgl.scene.spec.Scene` or a scene file.
        path: where to write the animation (.mp4, .gif, .webp, DIR/%04d.png, or a .png still);
            None: write nothing.
        frames, fps, steps_per_frame, seconds_per_frame, turntable: as ``--frames`` ... (default:
            the scene's ``[animation]`` table, else one frame).
        modes, views: panels per frame (mapping modes by rows, (azimuth, elevation, distance)
            views by columns).
        overrides: dotted scene keys to set when ``scene`` is a file (``{"physics.dt": 1e-3}``).
        ctx: the GL context (default: one made and released here).

    Returns:
        ``(images, record)``: (F, H, W, 3) uint8 frames and the run record.
    """
    import numpy as np

    from deformgl.gl.context import create_context
    from deformgl.scene.schema import load_scene

    loaded = scene if isinstance(scene, Scene) else load_scene(scene, overrides)
    plan = frame_plan(loaded, frames=frames, fps=fps, steps_per_frame=steps_per_frame,
                      seconds_per_frame=seconds_per_frame, turntable=turntable)
    gl = create_context() if ctx is None else ctx
    try:
        result = render_frames(gl, loaded, plan, modes=modes, views=views, progress=progress)
    finally:
        if ctx is None:
            gl.release()
    if path is not None:
        out = Path(path)
        check_job(loaded, Job(out, plan, modes=modes, views=views))
        with OutputSet([out] if animation_kind(out) != "frames" else frame_paths(out, plan.frames)):
            if animation_kind(out) is None:
                write_png_atomic(out, result.images[0])
            else:
                with AnimationWriter(out, plan.fps) as writer:
                    for image in result.images:
                        writer.write_frame(image)
        result.record["outputs"] = [str(out)]
    return np.stack(result.images), result.record
