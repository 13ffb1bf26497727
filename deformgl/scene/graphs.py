"""Scene-graph files rendered by ``deformgl render`` (docs/SCENEGRAPH.md): alone, or on a
simulated body whose deformed, mapped detailed mesh drives the graph's ``attach`` transforms
(Knuth, Kohlhammer & Kuijper, section 5, on Mosegaard & Sørensen 3.3 mappings).

With a ``[body]``, the body's scene file is simulated and drawn as ``deformgl render`` draws it,
the graph's world is the body's (recentred) frame, and each ``attach`` node gets the grid of its
anchors on the deformed mesh, mapped from its children's box [0, 1] x [-0.5, 0.5] x [0, 1].
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import moderngl
import numpy as np

from deformgl.data import is_packaged
from deformgl.errors import InputError
from deformgl.files import OutputSet, write_png_atomic
from deformgl.render.camera import View
from deformgl.render.mapped_setup import export_mesh
from deformgl.render.passes import Lighting
from deformgl.render.video import AnimationWriter, animation_kind, check_encoder, frame_paths
from deformgl.scene.pipeline import SceneModel, render
from deformgl.scene.schema import load_scene
from deformgl.trilinear.attachments import TubeAttachment
from deformgl.trilinear.batches import ComposedScene
from deformgl.trilinear.cuboid import Box
from deformgl.trilinear.graphbuild import ATTACH_BOX, compose_graph, draw_composed, graph_mesh, render_graph_frames
from deformgl.trilinear.graphfile import load_graph
from deformgl.trilinear.graphspec import SceneGraph, GraphTransform
from deformgl.trilinear.grid import Trilinear
from deformgl.trilinear.renderer import TrilinearRenderer


def attach_grid(built: SceneModel, deformed: np.ndarray, t: GraphTransform, name: str = "attach") -> Trilinear:
    """The grid of an ``attach`` transform on the body's deformed detailed mesh (section 5):
    anchors at the rest mesh's vertices nearest to the path, frames from ``deformed`` (V, 3)."""
    lo, hi = built.bbox
    diag = float(np.linalg.norm(hi - lo))
    start, end = lo + (hi - lo) * np.asarray(t.start), lo + (hi - lo) * np.asarray(t.end)
    path = TubeAttachment.along(built.mesh.vertices, built.mesh.faces, start, end, count=t.anchors, radius=1.0)
    width, height = t.width * diag, t.height * diag
    box = Box(np.array([0.0, -width / 2, 0.0]), np.array([float(path.box.hi[0]), width / 2, height]))
    grid = path.anchors.grid(deformed, built.mesh.faces, box)
    return Trilinear(ATTACH_BOX, grid.points)


@dataclass
class GraphRender:
    """One render of a scene-graph file: the image and the composed roots (for export)."""

    image: np.ndarray
    scenes: list[ComposedScene]


def render_graph_file(ctx: moderngl.Context, path: str | Path, *, size: tuple[int, int] | None = None,
                      time: float = 0.0, graph: SceneGraph | None = None, mesh: bool = False,
                      ) -> tuple[GraphRender, tuple[np.ndarray, np.ndarray, np.ndarray] | None]:
    """Render the scene-graph file ``path`` (or ``graph``, its files relative to ``path``'s
    folder) at ``time`` (s); with ``mesh``, also the composed geometry captured from the GPU."""
    file = str(path)
    graph = graph if graph is not None else load_graph(path)
    base = Path(path).resolve().parent
    if graph.body is None:
        scenes = compose_graph(graph, base, time=time, file=file)
        image = draw_composed(ctx, graph, scenes, size, file=file)
        return GraphRender(image, scenes), graph_mesh(ctx, scenes) if mesh else None
    if len(graph.roots) != 1:
        raise InputError(f"{file}: graph.roots: a graph on a [body] has one root, got {len(graph.roots)}")
    body = load_scene(base / graph.body.scene)
    if body.mapping.mode == "one-to-one":
        raise InputError(f"{file}: body.scene: attachments need a detailed mesh (mapping.mode constant, "
                         f"curvature or auto), {body.source.name} uses one-to-one")
    if size is not None:
        body = body.with_overrides(size=size)
    made: list[ComposedScene] = []
    captured: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def overlay(built: SceneModel, deformed: np.ndarray, view: View, lighting: Lighting) -> None:
        scenes = compose_graph(graph, base, time=time, file=file,
                               attach=lambda name, t: attach_grid(built, deformed, t, name))
        made.extend(scenes)
        renderer = TrilinearRenderer(ctx)
        try:
            for scene in scenes:
                renderer.draw(scene, view, lighting)
        finally:
            renderer.release()
        if mesh:
            v, n, f = graph_mesh(ctx, scenes)
            captured.append((v + built.centre, n, f))

    result = render(ctx, body, overlay=overlay)
    return GraphRender(result.image, made), (captured[0] if captured else None)


#: The most frames of a graph animation (they are kept in memory until written).
MAX_GRAPH_FRAMES = 10000


def graph_output(source: Path, output: Path | None, export: Path | None, time: float | None,
                 refused: dict[str, object], frames: int | None = None) -> Path:
    """The checks of ``deformgl render GRAPH.toml`` before any work, and its PNG path: the
    ``-o`` given, else the graph's ``output`` (for a shipped graph, its name in the working folder).

    Raises:
        SceneError: the graph file is invalid (:func:`~deformgl.trilinear.graphfile.load_graph`).
        InputError: a simulation-only option in ``refused`` is set, a bad time or output suffix.
    """
    graph = load_graph(source)
    for flag, value in refused.items():
        if value is not None:
            raise InputError(f"{source}: {flag} applies to simulation scenes, not to scene-graph files "
                             f"(a graph file sets its camera in [view], its simulation in its [body] scene)")
    if time is not None and not (math.isfinite(time) and time >= 0.0):
        raise InputError(f"--time: must be a finite time >= 0 s, got {time}")
    named = Path(graph.output) if graph.output else Path(f"{source.stem}.png")
    out = output or (Path(named.name) if is_packaged(source) else source.parent / named)
    if frames is not None:
        if not 1 <= frames <= MAX_GRAPH_FRAMES:
            raise InputError(f"--frames: must be in 1..{MAX_GRAPH_FRAMES}, got {frames}")
        if graph.body is not None:
            raise InputError(f"{source}: --frames: a graph attached to a simulated [body] renders stills "
                             f"(--time T); animate a graph without one")
        if time is not None:
            raise InputError("--time: not with --frames (the frames span the graph's keyframes)")
        if animation_kind(out) is None:
            raise InputError(f"{out}: an animation must end in .mp4, .gif or .webp, or be a frame pattern "
                             f"such as frames/%04d.png")
        if export is not None:
            raise InputError(f"{export}: --export-mesh of a graph animation is not supported; export a still (--time T)")
        check_encoder(out)
        return out
    if out.suffix.lower() != ".png":
        raise InputError(f"{out}: the output must be a .png file")
    if export is not None and export.suffix.lower() not in (".ply", ".obj", ".glb"):
        raise InputError(f"{export}: --export-mesh must end in .ply, .obj or .glb")
    return out


def graph_animation(ctx: moderngl.Context, path: str | Path, out: Path, *, frames: int, fps: float = 24.0,
                    size: tuple[int, int] | None = None) -> int:
    """``deformgl render GRAPH.toml -o out.gif --frames N``: N frames spread over the graph's
    keyframes (:meth:`~deformgl.trilinear.graphspec.SceneGraph.frame_times`), through the
    animation writer, written atomically (the frames of a pattern as one output set). Returns
    the frame count."""
    path = Path(path)
    graph = load_graph(path)
    times = graph.frame_times(frames)
    images = render_graph_frames(ctx, graph, times, path.parent, size=size, file=path.name)
    with OutputSet([out] if animation_kind(out) != "frames" else frame_paths(out, len(images))):
        with AnimationWriter(out, fps) as writer:
            for image in images:
                writer.write_frame(image)
    return len(images)


def graph_to_png(ctx: moderngl.Context, path: str | Path, out: Path, *, size: tuple[int, int] | None = None,
                 time: float = 0.0, export: Path | None = None) -> np.ndarray:
    """``deformgl render GRAPH.toml``: the PNG and the optional composed mesh (``--export-mesh``)
    written as one :class:`~deformgl.files.OutputSet`, all or none."""
    outputs = OutputSet([out, export])
    rendered, mesh = render_graph_file(ctx, path, size=size, time=time, mesh=export is not None)
    with outputs:
        write_png_atomic(out, rendered.image)
        if export is not None and mesh is not None:
            export_mesh(export, *mesh)
    return rendered.image
