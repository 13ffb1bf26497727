"""The scenes of Knuth, Kohlhammer & Kuijper built with the trilinear scene graph, their
rendering, and ``deformgl bench trilinear`` (section 6).

Scenes (:data:`SCENES`):

* ``tubes``: figure 1, a 2D grid of tubes wrapped around a torus by the scene graph alone; left
  with linear transforms (each tube placed by the tangent affine map at its centre: tubes stick
  out), right with one trilinear grid at the root (tubes stay in contact);
* ``tile``: figure 9, a detailed tile (grooved floor with a ring and a column, made with trimesh)
  repeated by translations under a torus-wrap grid: seamless C0 joins;
* ``helix``: section 6, a helix of many small spheres.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import moderngl
import numpy as np
import trimesh

from .bench import machine_line
from .camera import View, frame_box
from .errors import InputError
from .imagediff import write_png_atomic
from .render import Lighting, RenderTarget
from .scenegraph import (
    ComposedScene, Geometry, GeometryNode, GroupNode, Node, TransformNode, TrilinearRenderer, compose_scene,
    shader_defines,
)
from .trilinear import NORMAL_MODES, Box, Function, Helix, Taper, TorusWrap, Trilinear, Twist, tangent_affine

MODES = ("linear", "trilinear")
BACKGROUND = (1.0, 1.0, 1.0)
LIGHT = Lighting(direction=(0.3, 0.8, 0.6), ambient=0.25)
COLOURS = ((0.85, 0.55, 0.3), (0.35, 0.55, 0.8), (0.55, 0.75, 0.45))

#: Torus axis z -> y, so that the default camera (y up) sees the ring from above at an angle.
Z_UP_TO_Y_UP = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])


# ---- meshes -------------------------------------------------------------------------------------
def uv_sphere(radius: float, segments: int, rings: int, name: str = "sphere") -> Geometry:
    """A UV sphere at the origin with ``2 * segments * (rings - 1)`` triangles."""
    theta = np.linspace(0.0, np.pi, rings + 1)[1:-1]
    phi = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    unit = np.concatenate([[[0.0, 0.0, 1.0]], ring, [[0.0, 0.0, -1.0]]])
    s = segments
    tris = [[0, 1 + (j + 1) % s, 1 + j] for j in range(s)]
    for i in range(rings - 2):
        for j in range(s):
            a, b = 1 + i * s + j, 1 + i * s + (j + 1) % s
            tris += [[a, b, a + s], [b, b + s, a + s]]
    last = len(unit) - 1
    base = 1 + (rings - 2) * s
    tris += [[last, base + j, base + (j + 1) % s] for j in range(s)]
    tris = np.array(tris)[:, [0, 2, 1]]  # counter-clockwise seen from outside
    return Geometry(unit * radius, unit, tris, name)


def tube(length: float, radius: float, *, sections: int = 12, rings: int = 16, name: str = "tube") -> Geometry:
    """A capped tube along x from 0 to ``length``, centred on y = z = 0, with ``rings`` vertex
    rings along its length so that a deformation bends it smoothly."""
    x = np.linspace(0.0, length, rings)
    a = np.linspace(0.0, 2.0 * np.pi, sections, endpoint=False)
    xx, aa = np.meshgrid(x, a, indexing="ij")
    side_n = np.stack([np.zeros_like(aa), np.cos(aa), np.sin(aa)], -1).reshape(-1, 3)
    side_v = np.stack([xx, radius * np.cos(aa), radius * np.sin(aa)], -1).reshape(-1, 3)
    tris = []
    for i in range(rings - 1):
        for j in range(sections):
            p, q = i * sections + j, i * sections + (j + 1) % sections
            tris += [[p, q, p + sections], [q, q + sections, p + sections]]
    verts, norms = [side_v], [side_n]
    start = len(side_v)
    for end, sign in ((0.0, -1.0), (length, 1.0)):
        ring = np.stack([np.full(sections, end), radius * np.cos(a), radius * np.sin(a)], -1)
        verts += [[[end, 0.0, 0.0]], ring]
        norms += [np.tile([sign, 0.0, 0.0], (sections + 1, 1))]
        for j in range(sections):
            p, q = start + 1 + j, start + 1 + (j + 1) % sections
            tris.append([start, q, p] if sign < 0 else [start, p, q])
        start += sections + 1
    return Geometry(np.concatenate(verts), np.concatenate(norms), np.array(tris), name)


def hall_tile(*, resolution: int = 40, name: str = "tile") -> Geometry:
    """The figure 9 tile over [0, 1]^2 (z up), made with trimesh: a floor with a groove along its
    border and a raised ring, and a revolved column with base and capital at its centre."""
    n = resolution
    s = np.linspace(0.0, 1.0, n + 1)
    x, y = np.meshgrid(s, s, indexing="ij")
    edge = np.minimum(np.minimum(x, 1 - x), np.minimum(y, 1 - y))
    r = np.hypot(x - 0.5, y - 0.5)
    z = 0.05 - 0.03 * (edge < 0.05) + 0.025 * np.exp(-((r - 0.3) / 0.035) ** 2)
    verts = np.stack([x, y, z], -1).reshape(-1, 3)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    floor = trimesh.Trimesh(verts, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]), process=False)
    profile = [[0.0, 0.0], [0.12, 0.0], [0.12, 0.04], [0.08, 0.06], [0.07, 0.12], [0.065, 0.2], [0.062, 0.28],
               [0.065, 0.33], [0.1, 0.36], [0.11, 0.4], [0.0, 0.4]]
    column = trimesh.creation.revolve(profile, sections=20)
    column.apply_translation([0.5, 0.5, 0.05])
    mesh = trimesh.util.concatenate([floor, column])
    return Geometry.from_trimesh(mesh, name)


# ---- scenes --------------------------------------------------------------------------------------
@dataclass
class BuiltScene:
    """A scene graph and what it is."""

    root: Node
    description: str
    grids: dict[str, Trilinear]


def _torus_root(wrap: TorusWrap, box: Box, cells: tuple[int, int, int]) -> tuple[TransformNode, Trilinear]:
    grid = Trilinear.from_function(wrap, box, cells, name="torus wrap")
    return TransformNode(grid, name="torus wrap"), grid


def _check_mode(mode: str) -> None:
    if mode not in MODES:
        raise InputError(f"transform mode must be one of {MODES}, got {mode!r}")


def _placed(f: Function, centre: np.ndarray, offset: np.ndarray, mode: str) -> np.ndarray:
    """The placement of an object whose local origin goes to ``offset``: a translation in the
    trilinear scene, the tangent affine map of ``f`` at ``centre`` in the linear one."""
    move = np.identity(4)
    move[:3, 3] = offset
    return tangent_affine(f, centre) @ move if mode == "linear" else move


def tubes_scene(mode: str, *, along: int = 10, around: int = 12) -> BuiltScene:
    """Figure 1: ``along`` x ``around`` tubes of length 1 and diameter 1, touching, on a torus."""
    _check_mode(mode)
    wrap = TorusWrap(length=float(along), width=float(around), major=4.6, minor=around / (2 * np.pi))
    geo = tube(1.0, 0.5, sections=16, rings=17)
    box = Box(np.zeros(3), np.array([along, around, 1.0]))
    root = TransformNode(Z_UP_TO_Y_UP, name="z up to y up")
    grids = {}
    if mode == "trilinear":
        parent, grids["torus wrap"] = _torus_root(wrap, box, (4 * along, 2 * around, 1))
        root.add(parent)
    else:
        parent = root.add(GroupNode(name="tubes"))
    for i in range(along):
        for j in range(around):
            centre = np.array([i + 0.5, j + 0.5, 0.5])
            place = _placed(wrap, centre, np.array([i, j + 0.5, 0.5]), mode)
            colour = COLOURS[(i + j) % 2]
            parent.add(TransformNode(place, [GeometryNode(geo, colour=colour)], name=f"tube {i},{j}"))
    return BuiltScene(root, f"{along * around} tubes wrapped around a torus, {mode} transforms", grids)


def tile_scene(*, along: int = 16, around: int = 6, normals: str = "direct") -> BuiltScene:
    """Figure 9: ``along`` x ``around`` hall tiles mapped onto a torus by one grid."""
    wrap = TorusWrap(length=float(along), width=float(around), major=3.2, minor=1.0)
    geo = hall_tile()
    box = Box(np.array([0.0, 0.0, geo.box.lo[2]]), np.array([along, around, geo.box.hi[2]]))
    root = TransformNode(Z_UP_TO_Y_UP, name="z up to y up", normals=normals)
    parent, grid = _torus_root(wrap, box, (4 * along, 4 * around, 1))
    root.add(parent)
    for i in range(along):
        for j in range(around):
            move = np.identity(4)
            move[:2, 3] = i, j
            parent.add(TransformNode(move, [GeometryNode(geo, colour=COLOURS[2])]))
    return BuiltScene(root, f"{along * around} tiles on a torus (figure 9), {normals} normals",
                      {"torus wrap": grid})


def helix_scene(mode: str, count: int, *, segments: int = 8, rings: int = 6, radius: float = 0.5,
                turns: float = 12.0) -> BuiltScene:
    """Section 6: ``count`` spheres of diameter ``2 radius`` in a row along a helix."""
    _check_mode(mode)
    geo = uv_sphere(radius, segments, rings)
    d = 2.0 * radius
    length = count * d
    helix = Helix(radius=length / turns / (2 * np.pi) * 0.9, pitch=2.5 * d)
    root = TransformNode(Z_UP_TO_Y_UP, name="helix")
    grids = {}
    if mode == "trilinear":
        box = Box(np.array([0.0, -radius, -radius]), np.array([length, radius, radius]))
        grid = Trilinear.from_function(helix, box, (max(1, count // 2), 1, 1), name="helix")
        grids["helix"] = grid
        parent = root.add(TransformNode(grid, name="helix grid"))
    else:
        parent = root.add(GroupNode(name="spheres"))
    for i in range(count):
        centre = np.array([(i + 0.5) * d, 0.0, 0.0])
        parent.add(TransformNode(_placed(helix, centre, centre, mode), [GeometryNode(geo, colour=COLOURS[i % 2])]))
    return BuiltScene(root, f"{count} spheres on a helix, {mode} transforms", grids)


def spheres_scene(mode: str, *, along: int = 37, around: int = 5, segments: int = 64, rings: int = 64) -> BuiltScene:
    """Section 6 vertex-throughput scene: ``along`` x ``around`` finely tessellated spheres
    attached to a torus; with trilinear transforms every sphere is deformed by a grid."""
    _check_mode(mode)
    wrap = TorusWrap(length=float(along), width=float(around), major=6.0, minor=1.2)
    geo = uv_sphere(0.5, segments, rings)
    box = Box(np.zeros(3), np.array([along, around, 1.0]))
    root = TransformNode(Z_UP_TO_Y_UP)
    grids = {}
    if mode == "trilinear":
        parent, grids["torus wrap"] = _torus_root(wrap, box, (2 * along, 6 * around, 1))
        root.add(parent)
    else:
        parent = root.add(GroupNode())
    for i in range(along):
        for j in range(around):
            centre = np.array([i + 0.5, j + 0.5, 0.5])
            parent.add(TransformNode(_placed(wrap, centre, centre, mode), [GeometryNode(geo, colour=COLOURS[j % 2])]))
    return BuiltScene(root, f"{along * around} spheres on a torus, {mode} transforms", grids)


def depth_scene(depth: int, *, cells: int = 8, segments: int = 256, rings: int = 256) -> BuiltScene:
    """One sphere under ``depth`` nested grid transforms of ``cells``^3 cells each (twists and
    tapers), innermost first; every level's box is the bounding box of its content."""
    geo = uv_sphere(1.0, segments, rings)
    node: Node = GeometryNode(geo, colour=COLOURS[1])
    box = geo.box
    grids = {}
    for level in range(depth):
        f = Twist(0.6 / depth) if level % 2 == 0 else Taper(0.15 / depth)
        grid = Trilinear.from_function(f, box, (cells, cells, cells))
        grids[f"level {level}"] = grid
        node = TransformNode(grid, [node], name=f"level {level}")
        box = Box.of_points(np.array(grid.image_bounds()))
    return BuiltScene(node, f"a sphere under {depth} nested {cells}^3 grids", grids)


SCENES: dict[str, str] = {
    "tubes": "figure 1: tubes wrapped around a torus, linear (left) vs trilinear (right)",
    "tile": "figure 9: a detailed tile mapped onto a torus",
    "helix": "section 6: a helix of small spheres",
}


# ---- rendering -----------------------------------------------------------------------------------
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
                    samples: int = 4, view: View | None = None) -> list[np.ndarray]:
    """Render composed scenes with one shared camera; returns (H, W, 3) uint8 images."""
    view = view or scene_view(scenes, size)
    target = RenderTarget(ctx, size, samples)
    renderer = TrilinearRenderer(ctx)
    try:
        images = []
        for scene in scenes:
            target.begin(BACKGROUND)
            renderer.draw(scene, view, LIGHT)
            images.append(target.read_rgb())
        return images
    finally:
        renderer.release()
        target.release()


def render_trilinear_scene(ctx: moderngl.Context, name: str, size: tuple[int, int] = (960, 480), *,
                           samples: int = 4, normals: str = "direct") -> np.ndarray:
    """Render one of :data:`SCENES` to an (H, W, 3) uint8 image.

    ``tubes`` is two halves side by side, linear left and trilinear right, same camera.

    Args:
        ctx: GL context.
        name: a key of :data:`SCENES`.
        size: (width, height) pixels.
        samples: MSAA samples.
        normals: ``"direct"`` (smooth) or ``"tangent"`` (orthogonal, seams at cell borders), 4.2.

    Raises:
        InputError: unknown scene name or normal mode, or a size below 16x16.
    """
    if name not in SCENES:
        raise InputError(f"unknown trilinear scene {name!r}; choose one of {', '.join(SCENES)}")
    if normals not in NORMAL_MODES:
        raise InputError(f"normals must be one of {NORMAL_MODES}, got {normals!r}")
    w, h = (int(v) for v in size)
    if w < 16 or h < 16:
        raise InputError(f"image size {w}x{h} is too small (at least 16x16)")
    if name == "tubes":
        half = (w // 2, h)
        roots = [tubes_scene(m).root for m in MODES]
        for root in roots:
            root.normals = normals
        scenes = [compose_scene(root) for root in roots]
        view = scene_view(scenes, half, azimuth=0.0, elevation=50.0, distance=1.15)
        left, right = render_composed(ctx, scenes, half, samples=samples, view=view)
        if w % 2:
            right = np.concatenate([right, right[:, -1:]], axis=1)
        return np.concatenate([left, right], axis=1)
    built = tile_scene(normals=normals) if name == "tile" else helix_scene("trilinear", 600, turns=6.0)
    built.root.normals = normals
    scene = compose_scene(built.root)
    view = scene_view(scene, (w, h), azimuth=15.0, elevation=40.0, distance=1.0 if name == "tile" else 1.2)
    return render_composed(ctx, [scene], (w, h), samples=samples, view=view)[0]


def write_trilinear_scene(ctx: moderngl.Context, name: str, output: str | Path,
                          size: tuple[int, int] = (960, 480), *, samples: int = 4,
                          normals: str = "direct") -> Path:
    """``deformgl trilinear SCENE -o OUT.png``: render (:func:`render_trilinear_scene`) and
    write the PNG atomically; returns its path."""
    image = render_trilinear_scene(ctx, name, size, samples=samples, normals=normals)
    path = Path(output)
    write_png_atomic(path, image)
    return path


# ---- benchmark (section 6) -----------------------------------------------------------------------
@dataclass(frozen=True)
class BenchSetup:
    """One row of the paper's table: scene, objects, sphere tessellation, paper's FPS."""

    scene: str
    objects: int
    segments: int
    rings: int
    paper_fps: tuple[float, float]

    def build(self, mode: str) -> BuiltScene:
        """The scene graph of this set-up with linear or trilinear transforms."""
        if self.scene == "spheres":
            return spheres_scene(mode, along=37, around=self.objects // 37, segments=self.segments, rings=self.rings)
        return helix_scene(mode, self.objects, segments=self.segments, rings=self.rings)


#: 185 x 8,064 = 1.49M, 4,617 x 36 = 166k and 2,566 x 256 = 657k triangles (paper: 1.5M, 164k, 656k).
BENCH_SETUPS = (
    BenchSetup("spheres", 185, 64, 64, (19.5, 14.9)),
    BenchSetup("helix", 4617, 6, 4, (16.5, 13.3)),
    BenchSetup("helix", 2566, 16, 9, (10.8, 8.4)),
)


@dataclass
class TrilinearRow:
    """Linear vs trilinear timings of one set-up (milliseconds, medians)."""

    setup: BenchSetup
    triangles: int
    compose_ms: dict[str, float]
    draw_ms: dict[str, float]
    paths: dict[str, dict[str, int]]
    grid_error: float

    def fps(self, mode: str) -> float:
        """Frames per second including the CPU composition."""
        return 1e3 / (self.compose_ms[mode] + self.draw_ms[mode])

    def ratio(self) -> float:
        """Trilinear over linear frames per second (the paper's figure)."""
        return self.fps("trilinear") / self.fps("linear")

    def draw_ratio(self) -> float:
        """Trilinear over linear, GPU draw only."""
        return self.draw_ms["linear"] / self.draw_ms["trilinear"]


def time_frames(ctx: moderngl.Context, roots: dict[str, Node], size: tuple[int, int], repeats: int, *,
                view: View | None = None) -> tuple[dict[str, tuple[float, float]], dict[str, ComposedScene]]:
    """Median compose and draw times (ms) of full frames of several scenes, interleaved frame by
    frame (in alternating order) so that all see the same machine load. A frame: compose on the
    CPU, then upload, draw and ``ctx.finish()`` into a ``size`` offscreen target without MSAA.
    The camera frames the first scene unless ``view`` is given; the first frame of each
    (compiling programs, allocating buffers) is not counted.

    Returns:
        Per key: (compose ms, draw ms); and the last composed scene of each.
    """
    target = RenderTarget(ctx, size, 0)
    renderer = TrilinearRenderer(ctx)
    try:
        scenes = {key: compose_scene(root) for key, root in roots.items()}
        view = view or scene_view(next(iter(scenes.values())), size)
        times: dict[str, list[tuple[float, float]]] = {key: [] for key in roots}
        keys = list(roots)
        for i in range(repeats + 1):
            for key in keys if i % 2 else keys[::-1]:  # alternate the order: no position bias
                root = roots[key]
                t0 = time.perf_counter()
                scenes[key] = compose_scene(root)
                t1 = time.perf_counter()
                target.begin(BACKGROUND)
                renderer.draw(scenes[key], view, LIGHT)
                ctx.finish()
                t2 = time.perf_counter()
                if i:
                    times[key].append((t1 - t0, t2 - t1))
        medians = {key: (statistics.median(c for c, _ in t) * 1e3, statistics.median(d for _, d in t) * 1e3)
                   for key, t in times.items()}
        return medians, scenes
    finally:
        renderer.release()
        target.release()


def bench_trilinear(ctx: moderngl.Context, *, size: tuple[int, int] = (512, 512), repeats: int = 16,
                    setups: tuple[BenchSetup, ...] = BENCH_SETUPS) -> list[TrilinearRow]:
    """Frames per second with linear vs trilinear transforms for the paper's three set-ups.

    Both modes draw the same meshes with the same camera; the linear scene places every object
    with the tangent affine map, the trilinear one by a grid at the root, composed per leaf.
    """
    rows = []
    for setup in setups:
        built = {mode: setup.build(mode) for mode in ("trilinear", "linear")}
        medians, scenes = time_frames(ctx, {m: b.root for m, b in built.items()}, size, repeats)
        error = max((g.error for g in built["trilinear"].grids.values()), default=0.0)
        rows.append(TrilinearRow(setup, scenes["trilinear"].triangle_count,
                                 {m: medians[m][0] for m in medians}, {m: medians[m][1] for m in medians},
                                 {m: s.paths() for m, s in scenes.items()}, error))
    return rows


@dataclass
class DepthRow:
    """The same geometry under ``depth`` nested grid transforms."""

    depth: int
    compose_ms: float
    draw_ms: float
    cells: tuple[int, int, int]
    defines: dict[str, object]
    triangles: int


def bench_depth(ctx: moderngl.Context, *, size: tuple[int, int] = (512, 512), repeats: int = 16,
                depths: tuple[int, ...] = (1, 8)) -> list[DepthRow]:
    """Shader cost per depth: ms/frame of one sphere under 1 vs 8 nested 8^3 grids."""
    roots = {str(d): depth_scene(d).root for d in depths}
    medians, scenes = time_frames(ctx, roots, size, repeats)
    rows = []
    for d in depths:
        scene = scenes[str(d)]
        (batch,) = scene.batches
        cells = tuple(s - 1 for s in batch.grids[0].shape[1:4]) if batch.path == "grid" else (1, 1, 1)
        rows.append(DepthRow(d, *medians[str(d)], cells, shader_defines(batch.path, batch.normals),
                             scene.triangle_count))
    return rows


def format_trilinear(rows: list[TrilinearRow], depth_rows: list[DepthRow], machine: str, *,
                     size: tuple[int, int], repeats: int) -> str:
    """The ``bench trilinear`` report."""
    lines = [machine,
             f"trilinear scene graph (Knuth et al., section 6): {size[0]}x{size[1]} offscreen, no MSAA, "
             f"median of {repeats} frames; a frame = CPU composition + upload + draw + finish",
             f"{'scene':>8} {'objects':>7} {'triangles':>9} | {'linear':>6} {'compose':>8} {'draw':>8} | "
             f"{'trilin.':>7} {'compose':>8} {'draw':>8} {'paths (trilinear)':>22} | {'fps ratio':>9} "
             f"{'draw ratio':>10} | {'paper':>5} | {'grid err':>8}"]
    lines.append("-" * len(lines[-1]))
    for r in rows:
        p = r.paths["trilinear"]
        path_text = f"{p['affine']}a/{p['cuboid']}c/{p['grid']}g"
        paper = r.setup.paper_fps[1] / r.setup.paper_fps[0]
        lines.append(
            f"{r.setup.scene:>8} {r.setup.objects:>7} {r.triangles:>9} | {r.fps('linear'):>6.2f} "
            f"{r.compose_ms['linear']:>6.1f}ms {r.draw_ms['linear']:>6.1f}ms | {r.fps('trilinear'):>7.2f} "
            f"{r.compose_ms['trilinear']:>6.1f}ms {r.draw_ms['trilinear']:>6.1f}ms {path_text:>22} | "
            f"{r.ratio():>8.2f}x {r.draw_ratio():>9.2f}x | {paper:>5.2f} | {r.grid_error:>8.1e}")
    lines.append("fps: frames/s; fps ratio = trilinear / linear (target >= 0.8); draw ratio: GPU part only; "
                 "paths: leaves drawn affine / one cuboid (eq. 4) / 3D-texture grid; grid err: stated "
                 "approximation error of the root grid (scene units, objects have diameter 1)")
    if depth_rows:
        lines.append("")
        lines.append("shader cost vs depth: one sphere under nested 8^3 grids (twist/taper), composed per frame")
        lines.append(f"{'depth':>5} {'triangles':>9} {'compose ms':>10} {'draw ms':>8} {'leaf grid':>9}  "
                     "shader defines")
        for d in depth_rows:
            lines.append(f"{d.depth:>5} {d.triangles:>9} {d.compose_ms:>10.2f} {d.draw_ms:>8.2f} "
                         f"{'x'.join(map(str, d.cells)):>9}  {d.defines}")
    return "\n".join(lines)


def trilinear_bench_report(ctx: moderngl.Context, *, size: tuple[int, int] = (512, 512), repeats: int = 16,
                           progress: Callable[[str], None] | None = None) -> str:
    """``deformgl bench trilinear``: run both benchmarks and format the report."""
    if progress:
        progress("linear vs trilinear, three set-ups")
    rows = bench_trilinear(ctx, size=size, repeats=repeats)
    if progress:
        progress("depth 1 vs 8")
    depth_rows = bench_depth(ctx, size=size, repeats=repeats)
    return format_trilinear(rows, depth_rows, machine_line(ctx), size=size, repeats=repeats)
