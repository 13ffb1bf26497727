"""The scenes of Knuth, Kohlhammer & Kuijper built with the trilinear scene graph, their
rendering (the benchmark of section 6 is ``python -m studies.trilinear_speed``).

Scenes (:data:`SCENES`):

* ``tubes``: figure 1, a 2D grid of tubes wrapped around a torus by the scene graph alone; left
  with linear transforms (each tube placed by the tangent affine map at its centre: tubes stick
  out), right with one trilinear grid at the root (tubes stay in contact);
* ``tile``: figure 9, a detailed tile (grooved floor with a ring and a column, made with trimesh)
  repeated by translations under a torus-wrap grid: seamless C0 joins;
* ``helix``: section 6, a helix of many small spheres.

The three are shipped as scene-graph files (``scenes/trilinear_<name>.toml``, docs/SCENEGRAPH.md),
which :func:`render_trilinear_scene` renders; the builders here make the same graphs in Python
(the benchmark's variants: linear transforms, other counts); the view and the light they are
drawn with are :mod:`deformgl.trilinear.graphbuild`'s (``scene_view``, ``LIGHT``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import moderngl
import numpy as np

from deformgl.data import packaged_scene
from deformgl.errors import InputError
from deformgl.files import write_png_atomic
from deformgl.trilinear.graphbuild import render_graph
from deformgl.trilinear.graphfile import load_graph
from deformgl.trilinear.graph_nodes import GeometryNode, GroupNode, Node, TransformNode
from deformgl.trilinear.shapes import hall_tile, tube, uv_sphere
from deformgl.trilinear.cuboid import Box, Function
from deformgl.trilinear.deformations import Helix, Taper, TorusWrap, Twist, tangent_affine
from deformgl.trilinear.grid import Trilinear
from deformgl.trilinear.normal_transform import NORMAL_MODES

__all__ = ["BACKGROUND", "COLOURS", "MODES", "SCENES", "Z_UP_TO_Y_UP", "BuiltScene", "demo_graph_file", "depth_scene",
           "helix_scene", "render_trilinear_scene", "spheres_scene", "tile_scene", "tubes_scene",
           "write_trilinear_scene"]

MODES = ("linear", "trilinear")
BACKGROUND = (1.0, 1.0, 1.0)
COLOURS = ((0.85, 0.55, 0.3), (0.35, 0.55, 0.8), (0.55, 0.75, 0.45))

#: Torus axis z -> y, so that the default camera (y up) sees the ring from above at an angle.
Z_UP_TO_Y_UP = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])


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
    parent: Node
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
    parent: Node
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
def demo_graph_file(name: str) -> Path:
    """The shipped scene-graph file of the demo ``name`` (``scenes/trilinear_<name>.toml``)."""
    if name not in SCENES:
        raise InputError(f"unknown trilinear scene {name!r}; choose one of {', '.join(SCENES)}")
    return packaged_scene(f"trilinear_{name}.toml")


def render_trilinear_scene(ctx: moderngl.Context, name: str, size: tuple[int, int] = (960, 480), *,
                           samples: int = 4, normals: str = "direct") -> np.ndarray:
    """Render one of :data:`SCENES` from its shipped scene-graph file to an (H, W, 3) uint8 image.

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
    path = demo_graph_file(name)
    if normals not in NORMAL_MODES:
        raise InputError(f"normals must be one of {NORMAL_MODES}, got {normals!r}")
    graph = load_graph(path)
    graph.view.samples = samples
    return render_graph(ctx, graph, path.parent, size=size, normals=normals, file=str(path))


def write_trilinear_scene(ctx: moderngl.Context, name: str, output: str | Path,
                          size: tuple[int, int] = (960, 480), *, samples: int = 4,
                          normals: str = "direct") -> Path:
    """``deformgl trilinear SCENE -o OUT.png``: render (:func:`render_trilinear_scene`) and
    write the PNG atomically; returns its path."""
    image = render_trilinear_scene(ctx, name, size, samples=samples, normals=normals)
    path = Path(output)
    write_png_atomic(path, image)
    return path
