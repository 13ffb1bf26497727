"""A :class:`~deformgl.trilinear.graphspec.SceneGraph` made into runtime nodes
(:mod:`deformgl.trilinear.graph_nodes`), composed (section 4.1) and drawn, as stills, as frames at given
times (keyframed deformations), or exported as one deformed mesh captured from the GPU.

Each node spec referenced by several parents is built once per inherited colour and shared; an
``array`` becomes one translation node per instance over its (shared) children; a grid over
``box = "content"`` spans the bounding box of its children's content in its input space.
"""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import moderngl
import numpy as np

from deformgl.errors import DeformglError, InputError, SceneError
from deformgl.grid.meshio import load_mesh
from deformgl.render.camera import View, frame_box
from deformgl.render.passes import Lighting, RenderTarget
from deformgl.trilinear.batches import ComposedScene
from deformgl.trilinear.cuboid import CORNERS, Box, apply_coefficients
from deformgl.trilinear.deformations import tangent_affine
from deformgl.trilinear.graphspec import NodeSpec, SceneGraph, GraphTransform
from deformgl.trilinear.grid import Trilinear
from deformgl.trilinear.latticefile import read_lattice
from deformgl.trilinear.graph_nodes import DEFAULT_COLOUR, Geometry, GeometryNode, GroupNode, Node, TransformNode
from deformgl.trilinear.renderer import TrilinearRenderer
from deformgl.trilinear.scenegraph import compose_scene
from deformgl.trilinear.shapes import hall_tile, tube, uv_sphere

LIGHT = Lighting(direction=(0.3, 0.8, 0.6), ambient=0.25)

#: ``attach(node name, transform) -> Trilinear`` over the box [0, 1] x [-0.5, 0.5] x [0, 1]:
#: what the scene layer gives for ``attach`` transforms (anchors on the simulated body).
AttachResolver = Callable[[str, GraphTransform], Trilinear]

#: The local box of an ``attach`` node's children.
ATTACH_BOX = Box(np.array([0.0, -0.5, 0.0]), np.array([1.0, 0.5, 1.0]))


def _corners_of(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    return lo + CORNERS * (hi - lo)


class _Builder:
    def __init__(self, graph: SceneGraph, base: Path, file: str, attach: AttachResolver | None) -> None:
        self.g, self.base, self.file, self.attach = graph, base, file, attach
        self.geometries: dict[str, Geometry] = {}
        self.transforms: dict[str, object] = {}
        self.bounds_cache: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self.built: dict[tuple[str, tuple | None], Node] = {}

    def fail(self, key: str, msg: str) -> SceneError:
        return SceneError(" ".join(f"{self.file}: {key}: {msg}".split()))

    def geometry(self, name: str) -> Geometry:
        if name not in self.geometries:
            m = self.g.meshes[name]
            if m.file is not None:
                try:
                    mesh = load_mesh(self.base / m.file)
                    geo = Geometry.from_trimesh(mesh, name)
                except DeformglError as e:
                    raise self.fail(f"meshes.{name}.file", str(e)) from None
            else:
                p = m.params
                if m.shape == "tube":
                    geo = tube(p["length"], p["radius"], sections=int(p["sections"]), rings=int(p["rings"]), name=name)
                elif m.shape == "sphere":
                    geo = uv_sphere(p["radius"], int(p["segments"]), int(p["rings"]), name)
                else:
                    geo = hall_tile(resolution=int(p["resolution"]), name=name)
            self.geometries[name] = geo
        return self.geometries[name]

    # ---- bounds of content in a node's output space -----------------------------------------------
    def bounds(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        if name not in self.bounds_cache:
            node = self.g.nodes[name]
            if node.mesh is not None:
                box = self.geometry(node.mesh).box
                out = (box.lo, box.hi)
            else:
                if not node.children:
                    raise self.fail(f"nodes.{name}", "has no content (no mesh below it)")
                inner = self.content(name)
                out = self.image_bounds(name, node.transform, inner)
            self.bounds_cache[name] = out
        return self.bounds_cache[name]

    def content(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        children = self.g.nodes[name].children
        if not children:  # (a transform over box = "content" with nothing under it)
            raise self.fail(f"nodes.{name}", "has no content (no mesh below it) for its box to span")
        los, his = zip(*(self.bounds(c) for c in children))
        return np.min(los, axis=0), np.max(his, axis=0)

    def image_bounds(self, name: str, t: GraphTransform | None, inner: tuple[np.ndarray, np.ndarray]):
        if t is None:
            return inner
        if t.kind == "array":
            pts = np.concatenate([_corners_of(*inner) @ m[:3, :3].T + m[:3, 3] for m in self.instances(name, t)])
        else:
            made = self.transform(name, t)
            if isinstance(made, Trilinear):
                return made.image_bounds()
            pts = _corners_of(*inner) @ made[:3, :3].T + made[:3, 3]
        return pts.min(0), pts.max(0)

    # ---- transforms -------------------------------------------------------------------------------
    def box(self, name: str, t: GraphTransform) -> Box:
        if t.box is not None:
            return Box(np.array(t.box[0]), np.array(t.box[1]))
        return Box.of_points(np.array(self.content(name)))

    def transform(self, name: str, t: GraphTransform):
        """A 4x4 matrix or a Trilinear for a non-array transform (cached per node)."""
        if name in self.transforms:
            return self.transforms[name]
        key = f"nodes.{name}.{t.kind}"
        made: object
        try:
            if t.kind == "trs":
                made = t.trs_matrix()
            elif t.kind == "matrix":
                made = np.asarray(t.matrix, dtype=np.float64)
            elif t.kind in ("cuboid", "coefficients"):
                corners = t.corners if t.kind == "cuboid" else apply_coefficients(np.asarray(t.coefficients), CORNERS)
                made = Trilinear.from_corners(self.box(name, t), np.asarray(corners))
            elif t.kind == "grid" and t.file is not None:
                box = self.box(name, t)
                try:  # checked whole before any GL work (latticefile: dtype, shape, finite, extent)
                    points = read_lattice(self.base / t.file, box, repr(t.file))
                except InputError as e:
                    raise self.fail(f"{key}.file", str(e)) from None
                made = Trilinear(box, points)
            elif t.kind == "grid":
                assert t.deformation is not None
                f = self.g.deformations[t.deformation].function()
                made = Trilinear.from_function(f, self.box(name, t), t.cells, name=t.deformation)
            elif t.kind == "attach":
                if self.attach is None:
                    raise self.fail(key, "needs the simulated body (render the file with deformgl render)")
                made = self.attach(name, t)
            else:
                raise self.fail(key, f"not a single transform: {t.kind}")
        except SceneError:
            raise  # (already "file: key: what"; wrapping it again would repeat the prefix)
        except InputError as e:
            raise self.fail(key, str(e)) from None
        self.transforms[name] = made
        return made

    def instances(self, name: str, t: GraphTransform) -> list[np.ndarray]:
        """The 4x4 placements of an array's instances, x fastest-outer (i, then j, then k)."""
        f = self.g.deformations[t.tangent_of].function() if t.tangent_of is not None else None
        out = []
        step, offset = np.asarray(t.step), np.asarray(t.offset)
        for i in range(t.count[0]):
            for j in range(t.count[1]):
                for k in range(t.count[2]):
                    move = np.identity(4)
                    move[:3, 3] = offset + np.array([i, j, k]) * step
                    if f is not None:
                        move = tangent_affine(f, move[:3, 3] + np.asarray(t.tangent_at)) @ move
                    out.append(move)
        return out

    # ---- runtime nodes -----------------------------------------------------------------------------
    def node(self, name: str, colour: tuple | None) -> Node:
        spec: NodeSpec = self.g.nodes[name]
        colour = spec.colour or colour
        key = (name, colour)
        if key in self.built:
            return self.built[key]
        t = spec.transform
        made: Node
        if spec.mesh is not None:
            made = GeometryNode(self.geometry(spec.mesh), colour=colour or DEFAULT_COLOUR, normals=spec.normals,
                                name=name)
        elif t is not None and t.kind == "array":
            made = GroupNode(normals=spec.normals, name=name)
            for n, place in enumerate(self.instances(name, t)):
                c = t.colours[(n // (t.count[1] * t.count[2]) + n // t.count[2] % t.count[1] + n % t.count[2])
                              % len(t.colours)] if t.colours else colour
                made.add(TransformNode(place, [self.node(child, c) for child in spec.children]))
        else:
            children = [self.node(child, colour) for child in spec.children]
            if t is None:
                made = GroupNode(children, normals=spec.normals, name=name)
            else:
                made = TransformNode(self.transform(name, t), children, normals=spec.normals, name=name)
        self.built[key] = made
        return made


def build_graph(graph: SceneGraph, base: str | Path = ".", *, time: float = 0.0, file: str = "<graph>",
                attach: AttachResolver | None = None) -> list[Node]:
    """The runtime root nodes of ``graph`` at ``time`` (s); mesh and lattice files are relative to
    ``base``; ``file`` names the graph in errors.

    Raises:
        SceneError: a mesh or lattice file that cannot be read, a grid that does not fit its box.
    """
    still = graph.at(time).check()
    builder = _Builder(still, Path(base), file, attach)
    # the builder recurses once per level (a few frames each): room for the graph's depth
    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 8 * still.depth + 1000))
    try:
        return [builder.node(r, None) for r in still.roots]
    finally:
        sys.setrecursionlimit(limit)


def compose_graph(graph: SceneGraph, base: str | Path = ".", *, time: float = 0.0, file: str = "<graph>",
                  normals: str | None = None, attach: AttachResolver | None = None) -> list[ComposedScene]:
    """:func:`build_graph`, then :func:`~deformgl.trilinear.scenegraph.compose_scene` per root;
    ``normals`` overrides the roots' normal mode."""
    roots = build_graph(graph, base, time=time, file=file, attach=attach)
    if normals is not None:
        for root in roots:
            root.normals = normals
    return [compose_scene(root) for root in roots]


# ---- drawing -------------------------------------------------------------------------------------
def scene_view(scene: ComposedScene | list[ComposedScene], size: tuple[int, int], *, azimuth: float = 20.0,
               elevation: float = 35.0, distance: float = 1.25) -> View:
    """A perspective camera framing one or several composed scenes."""
    scenes = scene if isinstance(scene, list) else [scene]
    los, his = zip(*(s.bounds() for s in scenes))
    lo, hi = np.min(los, axis=0), np.max(his, axis=0)
    aspect = size[0] / size[1]
    # the field of view is vertical: step back for images taller than wide
    return frame_box(lo, hi, projection="perspective", azimuth=azimuth, elevation=elevation, fov=35.0,
                     distance=distance * max(1.0, 1.0 / aspect), target=np.full(3, 0.5), aspect=aspect)


def render_composed(ctx: moderngl.Context, scenes: list[ComposedScene], size: tuple[int, int], *,
                    samples: int = 4, view: View | None = None,
                    background: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> list[np.ndarray]:
    """Render composed scenes with one shared camera; returns (H, W, 3) uint8 images."""
    view = view or scene_view(scenes, size)
    target = RenderTarget(ctx, size, samples)
    renderer = TrilinearRenderer(ctx)
    try:
        images = []
        for scene in scenes:
            target.begin(background)
            renderer.draw(scene, view, LIGHT)
            images.append(target.read_rgb())
        return images
    finally:
        renderer.release()
        target.release()


def _check_size(size: tuple[int, int]) -> tuple[int, int]:
    w, h = (int(v) for v in size)
    if w < 16 or h < 16:
        raise InputError(f"image size {w}x{h} is too small (at least 16x16)")
    return w, h


#: A root whose image has fewer pixels than this differing from the background (by more than
#: :data:`DRAWN_LEVEL` of 255 on a channel) drew nothing visible: refused, not written blank.
MIN_DRAWN_PIXELS = 8
DRAWN_LEVEL = 8


def check_drawn(image: np.ndarray, background: tuple[float, float, float], file: str, key: str) -> np.ndarray:
    """``image`` (H, W, 3) uint8, or a SceneError when it is blank: fewer than
    :data:`MIN_DRAWN_PIXELS` pixels differ from ``background`` (a scene whose content is
    smaller than a pixel in the frame, collapsed by its transforms or dwarfed by a far lattice
    point, or drawn in the background's colour), or from the colour of most of its corners (one
    colour: the camera inside the content; the framing is the grids' lattices, and a mesh
    reaching far beyond its grid's box is not in them). A blank image is never written silently."""
    rgb = image[..., :3].astype(np.float64)
    bg = np.round(np.asarray(background) * 255.0)
    drawn = int((np.abs(rgb - bg).max(-1) > DRAWN_LEVEL).sum())
    if drawn < MIN_DRAWN_PIXELS:
        raise SceneError(f"{file}: {key}: the image is blank ({drawn} of {image.shape[0] * image.shape[1]} pixels "
                         f"differ from the background): its content covers less than a pixel, collapsed or "
                         f"outstretched by its transforms (a lattice point far away?), or is the background's "
                         f"colour; check the transforms, or render larger (--size)")
    corners = [tuple(rgb[y, x]) for y in (0, -1) for x in (0, -1)]
    common = np.array(max(set(corners), key=corners.count))
    varied = int((np.abs(rgb - common).max(-1) > DRAWN_LEVEL).sum())
    if varied < MIN_DRAWN_PIXELS:
        raise SceneError(f"{file}: {key}: the image is one colour ({varied} pixels differ from its corners): the "
                         f"camera is inside the content, which reaches beyond the frame (a mesh far outside a "
                         f"grid's box?); check the transforms and boxes")
    return image


#: Content farther from the origin than this many of its own diagonals is drawn recentred.
FAR_DIAGONALS = 100.0


def recentred(scenes: list[ComposedScene]) -> list[ComposedScene]:
    """``scenes`` moved (float64, on copies) so that their bounds' centre is the origin, when it
    is more than :data:`FAR_DIAGONALS` diagonals away: drawn in float32, content far from the
    origin loses its shape to rounding (a unit sphere translated to 1e6 drew nothing), and a
    camera framing it sees the same image of the moved copy. Nearer content is returned as is."""
    los, his = zip(*(s.bounds() for s in scenes))
    lo, hi = np.min(los, axis=0), np.max(his, axis=0)
    centre = (lo + hi) / 2
    if np.abs(centre).max() <= FAR_DIAGONALS * max(float(np.linalg.norm(hi - lo)), 1e-300):
        return scenes
    moved = []
    for scene in scenes:
        batches = []
        for b in scene.batches:
            affine = None
            if b.affine is not None:
                affine = b.affine.copy()
                affine[:, :, 3] -= centre
            batches.append(dataclasses.replace(b, affine=affine, grids=[g - centre for g in b.grids],
                                               corners=None if b.corners is None else b.corners - centre))
        moved.append(ComposedScene(batches))
    return moved


def draw_composed(ctx: moderngl.Context, graph: SceneGraph, scenes: list[ComposedScene],
                  size: tuple[int, int] | None = None, *, file: str = "<graph>") -> np.ndarray:
    """One image of composed roots with the graph's view: one root fills it, two are drawn side
    by side (left, right) with one camera. ``file`` names the graph in errors.

    Raises:
        SceneError: a root's image is blank (:func:`check_drawn`).
    """
    v = graph.view
    w, h = _check_size(size or v.size)
    scenes = recentred(scenes)
    if len(scenes) == 2:
        half = (w // 2, h)
        view = scene_view(scenes, half, azimuth=v.azimuth, elevation=v.elevation, distance=v.distance)
        left, right = render_composed(ctx, scenes, half, samples=v.samples, view=view, background=v.background)
        for i, image in enumerate((left, right)):
            check_drawn(image, v.background, file, f"graph.roots[{i}] ({graph.roots[i]!r})")
        if w % 2:
            right = np.concatenate([right, right[:, -1:]], axis=1)
        return np.concatenate([left, right], axis=1)
    view = scene_view(scenes[0], (w, h), azimuth=v.azimuth, elevation=v.elevation, distance=v.distance)
    image = render_composed(ctx, scenes, (w, h), samples=v.samples, view=view, background=v.background)[0]
    return check_drawn(image, v.background, file, f"graph.roots[0] ({graph.roots[0]!r})")


def render_graph(ctx: moderngl.Context, graph: SceneGraph, base: str | Path = ".", *,
                 size: tuple[int, int] | None = None, time: float = 0.0, normals: str | None = None,
                 file: str = "<graph>") -> np.ndarray:
    """Render a scene graph at ``time`` (s) to an (H, W, 3) uint8 image (``size`` overrides the
    graph's view size; ``normals`` the roots' normal mode)."""
    _check_size(size or graph.view.size)
    scenes = compose_graph(graph, base, time=time, file=file, normals=normals)
    return draw_composed(ctx, graph, scenes, size, file=file)


def render_graph_frames(ctx: moderngl.Context, graph: SceneGraph, times: Sequence[float], base: str | Path = ".", *,
                        size: tuple[int, int] | None = None, file: str = "<graph>") -> list[np.ndarray]:
    """Frames of an animated graph at ``times`` (s): one (H, W, 3) uint8 image each, the graph
    composed anew at every time (keyframed deformations interpolated, section 4.1 on the CPU)."""
    return [render_graph(ctx, graph, base, size=size, time=float(t), file=file) for t in times]


def graph_mesh(ctx: moderngl.Context, scenes: list[ComposedScene]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The composed, deformed geometry of every leaf of ``scenes`` as one mesh, captured from the
    drawing vertex shader with transform feedback: (V, 3) float64 world positions, (V, 3) normals,
    (F, 3) faces."""
    renderer = TrilinearRenderer(ctx)
    verts, norms, faces = [], [], []
    start = 0
    try:
        for scene in scenes:
            for batch, (pos, nrm) in zip(scene.batches, renderer.capture(scene)):
                tri = batch.geometry.triangles
                n = pos.shape[1]
                for k in range(batch.count):
                    verts.append(pos[k].astype(np.float64))
                    norms.append(nrm[k].astype(np.float64))
                    faces.append(tri + start)
                    start += n
    finally:
        renderer.release()
    if not verts:
        raise InputError("the scene graph has no geometry to export")
    return np.concatenate(verts), np.concatenate(norms), np.concatenate(faces)
