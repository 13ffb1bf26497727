"""A scene graph whose transforms are trilinear (Knuth, Kohlhammer & Kuijper, sections 4-4.2).

Nodes: :class:`GroupNode`, :class:`TransformNode` (an affine 4x4 matrix or a
:class:`~deformgl.trilinear.Trilinear` grid over the bounding box of its content) and
:class:`GeometryNode` (a mesh leaf). :func:`compose_scene` traverses from the world to the leaves
on the CPU and gives every leaf one composed transform (4.1): affine matrices multiply exactly;
at a trilinear node the child's lattice is transformed by the composed parent at the higher of the
two resolutions. A leaf right under a trilinear node is drawn with that composed grid as it
is; a leaf with affine nodes between gets the composed grid resampled over its own box at the
resolution of the grid cells it crosses. The leaf stage is vectorized over all leaves that share
a parent grid and a mesh.

Each leaf is then classified by the linearity test (3.2): linear ones are drawn through the plain
affine path, one-cuboid ones by eq. 4, the rest through a 3D-texture grid
(``shaders/trilinear/transform.vert``). :class:`TrilinearRenderer` draws every batch of leaves
sharing mesh, path, normal mode and colour with one instanced draw.

Per-instance data (float32, one row per leaf):

* affine: 12 floats, rows of the 3x4 matrix acting on local vertex positions;
* cuboid: box minimum (4), 1 / box size (4), six vec4 of the 3x8 rows (eq. 2 ``C`` or eq. 1
  corners);
* grid: (box minimum, nx), (cells / box size, ny), (block offset + 0.5 texel, nz).

The grid atlas is an RGBA32F 3D texture (W, H, D): texel (ox + i, oy + j, oz + k) is the image
of lattice point (i, j, k) of the block at offset (ox, oy, oz); w is 1.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import moderngl
import numpy as np

from deformgl.render.camera import View
from deformgl.errors import GLError, InputError
from deformgl.gl.programs import Program
from deformgl.render.passes import Lighting
from deformgl.trilinear.transforms import (
    LINEAR_RTOL, NORMAL_MODES, Box, Trilinear, check_affine, coefficient_matrix, compose,
    corner_weights, grid_corners, is_linear_coefficients, lattice_matches, transform_normals, unit_lattice,
)

PATHS = ("affine", "cuboid", "grid")
_IDENTITY = np.identity(4)
_IDENTITY.flags.writeable = False
DEFAULT_COLOUR = (0.85, 0.6, 0.35)


@dataclass(eq=False)
class Geometry:
    """A mesh in its local coordinates, uploaded once per renderer.

    Attributes:
        vertices: (N, 3) float64 positions.
        normals: (N, 3) float64 unit normals.
        triangles: (M, 3) int vertex indices (M may be 0: a point set, for capture).
        name: for messages.
    """

    vertices: np.ndarray
    normals: np.ndarray
    triangles: np.ndarray
    name: str = "mesh"
    box: Box = field(init=False)

    def __post_init__(self) -> None:
        self.vertices = np.asarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        self.normals = np.asarray(self.normals, dtype=np.float64).reshape(-1, 3)
        self.triangles = np.asarray(self.triangles, dtype=np.int64).reshape(-1, 3)
        if len(self.vertices) == 0 or len(self.normals) != len(self.vertices):
            raise InputError(f"{self.name}: needs vertices and one normal per vertex")
        if not (np.all(np.isfinite(self.vertices)) and np.all(np.isfinite(self.normals))):
            raise InputError(f"{self.name}: non-finite vertices or normals")
        if len(self.triangles) and (self.triangles.min() < 0 or self.triangles.max() >= len(self.vertices)):
            raise InputError(f"{self.name}: triangle index out of range")
        length = np.linalg.norm(self.normals, axis=1, keepdims=True)
        if np.any(length < 1e-12):
            raise InputError(f"{self.name}: zero-length normal")
        self.normals = self.normals / length
        self.box = Box.of_points(self.vertices)

    @classmethod
    def from_trimesh(cls, mesh, name: str = "mesh") -> Geometry:
        """From a ``trimesh.Trimesh`` (its vertex normals)."""
        return cls(np.asarray(mesh.vertices), np.asarray(mesh.vertex_normals), np.asarray(mesh.faces), name)


class Node:
    """A scene-graph node with children.

    Args:
        children: child nodes.
        normals: ``"direct"`` or ``"tangent"`` (4.2) for the leaves below, or None to inherit
            (default at the root: direct).
        name: for messages.
    """

    def __init__(self, children=(), *, normals: str | None = None, name: str = "") -> None:
        if normals is not None and normals not in NORMAL_MODES:
            raise InputError(f"node {name!r}: normals must be one of {NORMAL_MODES}, got {normals!r}")
        self.children: list[Node] = []
        self.normals = normals
        self.name = name
        for child in children:
            self.add(child)

    def add(self, child: Node) -> Node:
        """Append a child; returns it."""
        if not isinstance(child, Node):
            raise InputError(f"node {self.name!r}: a child must be a Node, got {type(child).__name__}")
        self.children.append(child)
        return child

    def walk(self) -> Iterator[Node]:
        """This node and all below, depth first."""
        stack: list[Node] = [self]
        while stack:
            node = stack.pop()
            yield node
            stack.extend(reversed(node.children))


class GroupNode(Node):
    """Groups children without a transform."""


class TransformNode(Node):
    """Transforms its children into its parent's space.

    Args:
        transform: an affine 4x4 matrix, or a :class:`Trilinear` whose box contains the children.
    """

    def __init__(self, transform, children=(), *, normals: str | None = None, name: str = "") -> None:
        super().__init__(children, normals=normals, name=name)
        self.transform = transform

    @property
    def transform(self):
        """The 4x4 float64 matrix or the :class:`Trilinear`."""
        return self._transform

    @transform.setter
    def transform(self, value) -> None:
        self._transform = value if isinstance(value, Trilinear) else check_affine(value)


class GeometryNode(Node):
    """A leaf drawing a :class:`Geometry` in one colour."""

    def __init__(self, geometry: Geometry, *, colour=DEFAULT_COLOUR, normals: str | None = None,
                 name: str = "") -> None:
        super().__init__((), normals=normals, name=name or geometry.name)
        self.geometry = geometry
        self.colour = tuple(float(c) for c in colour)

    def add(self, child: Node) -> Node:
        raise InputError(f"geometry node {self.name!r} cannot have children")


@dataclass(eq=False)
class Batch:
    """Leaves drawn together: one mesh, one path, one normal mode, one colour.

    Exactly one group of arrays is set, by ``path`` (k = number of leaves):
    affine: ``affine`` (k, 3, 4) on local coordinates; cuboid: ``box_lo``, ``box_size`` (k, 3)
    and ``corners`` (k, 8, 3) in eq. 1 order; grid: ``box_lo``, ``box_size`` and ``grids``, a
    list of stacked lattices (k_i, nx+1, ny+1, nz+1, 3) in instance order.
    """

    geometry: Geometry
    path: str
    normals: str
    colour: tuple[float, float, float]
    leaves: list[GeometryNode]
    affine: np.ndarray | None = None
    box_lo: np.ndarray | None = None
    box_size: np.ndarray | None = None
    corners: np.ndarray | None = None
    grids: list[np.ndarray] = field(default_factory=list)

    @property
    def count(self) -> int:
        """Number of leaves (instances)."""
        return len(self.leaves)

    def transforms(self) -> list:
        """Per leaf: a 4x4 matrix (affine) or a :class:`Trilinear` over the leaf's box."""
        if self.path == "affine":
            out = []
            for m in self.affine:
                full = np.identity(4)
                full[:3] = m
                out.append(full)
            return out
        boxes = [Box(lo, lo + s) for lo, s in zip(self.box_lo, self.box_size)]
        if self.path == "cuboid":
            return [Trilinear.from_corners(b, c) for b, c in zip(boxes, self.corners)]
        lattices = [p for stack in self.grids for p in stack]
        return [Trilinear(b, p) for b, p in zip(boxes, lattices)]

    def reference(self, vertices: np.ndarray | None = None,
                  normals: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Float64 NumPy twin of the vertex shader: (k, N, 3) world positions and unit normals."""
        v = self.geometry.vertices if vertices is None else np.asarray(vertices, np.float64)
        n = self.geometry.normals if normals is None else np.asarray(normals, np.float64)
        worlds, outs = [], []
        for t in self.transforms():
            if isinstance(t, Trilinear):
                world, jac = t(v), t.jacobian(v)
            else:
                world = v @ t[:3, :3].T + t[:3, 3]
                jac = np.broadcast_to(t[:3, :3], (len(v), 3, 3))
            worlds.append(world)
            outs.append(transform_normals(jac, n, self.normals))
        return np.array(worlds), np.array(outs)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) of the drawn leaves in world space."""
        if self.path == "affine":
            corners = self.geometry.box.corners()
            pts = np.einsum("kij,mj->kmi", self.affine[:, :, :3], corners) + self.affine[:, None, :, 3]
        elif self.path == "cuboid":
            pts = self.corners
        else:
            pts = np.concatenate([g.reshape(-1, 3) for g in self.grids])
        pts = pts.reshape(-1, 3)
        return pts.min(0), pts.max(0)


@dataclass(eq=False)
class ComposedScene:
    """The result of :func:`compose_scene`: batches of leaves with one transform each."""

    batches: list[Batch]

    @property
    def leaf_count(self) -> int:
        """Number of leaves."""
        return sum(b.count for b in self.batches)

    @property
    def triangle_count(self) -> int:
        """Triangles drawn per frame."""
        return sum(b.count * len(b.geometry.triangles) for b in self.batches)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) of the whole scene in world space."""
        if not self.batches:
            raise InputError("the scene has no geometry")
        los, his = zip(*(b.bounds() for b in self.batches))
        return np.min(los, axis=0), np.max(his, axis=0)

    def locate(self, leaf: GeometryNode) -> tuple[Batch, int]:
        """The batch of ``leaf`` and its instance index (first occurrence)."""
        for batch in self.batches:
            for i, node in enumerate(batch.leaves):
                if node is leaf:
                    return batch, i
        raise KeyError(f"leaf {leaf.name!r} is not in this scene")

    def transform_of(self, leaf: GeometryNode):
        """The composed transform of ``leaf`` (see :meth:`Batch.transforms`) and its path."""
        batch, i = self.locate(leaf)
        return batch.transforms()[i], batch.path

    def paths(self) -> dict[str, int]:
        """Number of leaves per draw path."""
        out = {p: 0 for p in PATHS}
        for b in self.batches:
            out[b.path] += b.count
        return out


# ---- traversal and composition (section 4.1) ------------------------------------------------------
def _collect(root: Node) -> list[tuple[GeometryNode, Trilinear | None, np.ndarray, str]]:
    """Depth-first from the world: (leaf, composed grid or None, affine after it, normal mode).

    The composed transform of a leaf is ``grid * affine``; affine nodes multiply into
    ``affine`` exactly, trilinear nodes are composed into a new grid (:func:`compose`).
    """
    leaves = []
    append = leaves.append
    stack: list[tuple[Node, Trilinear | None, np.ndarray, str]] = [(root, None, np.identity(4), "direct")]
    pop, push = stack.pop, stack.append
    while stack:
        node, grid, affine, normals = pop()
        normals = node.normals or normals
        if isinstance(node, GeometryNode):
            append((node, grid, affine, normals))
            continue
        if isinstance(node, TransformNode):
            t = node._transform
            if isinstance(t, Trilinear):
                if grid is None:
                    grid = Trilinear(t.box, t.points @ affine[:3, :3].T + affine[:3, 3], t.error)
                else:
                    grid = compose(grid, t, between=affine)
                affine = _IDENTITY
            else:
                affine = affine @ t
        for child in reversed(node.children):
            push((child, grid, affine, normals))
    return leaves


def _leaf_lattices(grid: Trilinear, mats: np.ndarray, box: Box) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Resample ``grid * mats[i]`` over ``box`` for k leaves at once.

    Each leaf gets as many cells per axis as its box edge crosses cells of ``grid`` (the
    higher resolution, 4.1; at least 1). Yields (leaf indices, (k', nx+1, ny+1, nz+1, 3)).
    """
    lin, off = mats[:, :3, :3], mats[:, :3, 3]
    cell = grid.box.size / np.array(grid.cells)
    crossed = np.abs(lin * box.size[None, None, :] / cell[None, :, None]).max(axis=1)
    n = np.clip(np.ceil(crossed - 1e-6), 1, max(grid.cells)).astype(np.int64)
    base = int(n.max()) + 1
    key = (n[:, 0] * base + n[:, 1]) * base + n[:, 2]
    for value in np.unique(key):
        sel = np.flatnonzero(key == value)
        c = tuple(int(v) for v in n[sel[0]])
        lattice = box.from_unit(unit_lattice(c)).reshape(-1, 3)
        pre = lattice @ lin[sel].transpose(0, 2, 1) + off[sel, None, :]
        pts = grid(pre.reshape(-1, 3)).reshape(len(sel), *(v + 1 for v in c), 3)
        yield sel, pts


def _leaf_parts(grid: Trilinear, mats: np.ndarray, box: Box) -> Iterator[tuple[np.ndarray, np.ndarray, Box]]:
    """The leaves' final transforms as (leaf indices, stacked lattices, their box).

    A leaf right under its trilinear node (no affine between) is drawn with that node's composed
    transform itself, over the node's box, exactly; the others are resampled over their own box
    (:func:`_leaf_lattices`).
    """
    direct = np.all(mats.reshape(len(mats), 16) == _IDENTITY.ravel(), axis=1)
    if direct.any():
        sel = np.flatnonzero(direct)
        yield sel, np.broadcast_to(grid.points, (len(sel), *grid.points.shape)), grid.box
    rest = np.flatnonzero(~direct)
    if len(rest):
        for sel, pts in _leaf_lattices(grid, mats[rest], box):
            yield rest[sel], pts, box


def _classify(points: np.ndarray, rtol: float) -> tuple[np.ndarray, np.ndarray]:
    """For stacked lattices (k, nx+1, ny+1, nz+1, 3): (linear mask, exactly-one-cuboid mask)."""
    corners = grid_corners(points)
    linear = is_linear_coefficients(coefficient_matrix(corners), rtol)
    cells = tuple(s - 1 for s in points.shape[1:4])
    if cells == (1, 1, 1):
        return linear, np.ones(len(points), bool)
    w = corner_weights(unit_lattice(cells).reshape(-1, 3))              # (m, 8)
    exact = lattice_matches((w @ corners).reshape(points.shape), points, rtol)
    return linear & exact, exact


def _corners_to_affine(corners: np.ndarray, box: Box) -> np.ndarray:
    """(k, 3, 4) affine matrices on local coordinates from parallelepiped corners over ``box``."""
    lin = np.stack([corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0],
                    corners[:, 4] - corners[:, 0]], axis=2) / box.size
    off = corners[:, 0] - lin @ box.lo
    return np.concatenate([lin, off[:, :, None]], axis=2)


class _BatchBuilder:
    def __init__(self) -> None:
        self.parts: dict[tuple, dict[str, list]] = {}
        self.meta: dict[tuple, tuple[Geometry, str, str, tuple]] = {}

    def add(self, geometry: Geometry, path: str, normals: str, colour: tuple, leaves: list, **arrays) -> None:
        key = (id(geometry), path, normals, colour)
        self.meta.setdefault(key, (geometry, path, normals, colour))
        part = self.parts.setdefault(key, {"leaves": []})
        part["leaves"].extend(leaves)
        for name, value in arrays.items():
            part.setdefault(name, []).append(value)

    def build(self) -> list[Batch]:
        out = []
        for key, part in self.parts.items():
            geometry, path, normals, colour = self.meta[key]
            b = Batch(geometry, path, normals, colour, part["leaves"])
            for name in ("affine", "box_lo", "box_size", "corners"):
                if name in part:
                    setattr(b, name, np.concatenate(part[name]))
            b.grids = part.get("grids", [])
            out.append(b)
        return out


def compose_scene(root: Node, *, rtol: float = LINEAR_RTOL) -> ComposedScene:
    """Compose every leaf's transform (CPU, float64) and sort leaves into draw batches.

    Args:
        root: the scene.
        rtol: tolerance of the linearity test (3.2), relative to each leaf's size.

    Returns:
        The batches; a leaf whose composed transform is linear is in an ``"affine"`` batch.
    """
    groups: dict[tuple, list] = {}
    for leaf, grid, affine, normals in _collect(root):
        key = (id(grid), id(leaf.geometry), normals, leaf.colour)
        groups.setdefault(key, []).append((leaf, grid, affine))
    builder = _BatchBuilder()
    for (_, _, normals, colour), members in groups.items():
        grid, geometry = members[0][1], members[0][0].geometry
        leaves = [m[0] for m in members]
        mats = np.array([m[2] for m in members])
        if grid is None:
            builder.add(geometry, "affine", normals, colour, leaves, affine=mats[:, :3])
            continue
        for sel, pts, box in _leaf_parts(grid, mats, geometry.box):
            linear, exact = _classify(pts, rtol)
            corners = grid_corners(pts)
            for mask, path in ((linear, "affine"), (exact & ~linear, "cuboid"), (~exact, "grid")):
                count = int(mask.sum())
                if not count:
                    continue
                chosen = [leaves[i] for i in sel[mask]]
                if path == "affine":
                    builder.add(geometry, path, normals, colour, chosen,
                                affine=_corners_to_affine(corners[mask], box))
                    continue
                boxes = {"box_lo": np.repeat(box.lo[None], count, 0),
                         "box_size": np.repeat(box.size[None], count, 0)}
                if path == "cuboid":
                    builder.add(geometry, path, normals, colour, chosen, corners=corners[mask], **boxes)
                else:
                    builder.add(geometry, path, normals, colour, chosen, grids=pts[mask], **boxes)
    return ComposedScene(builder.build())


# ---- drawing ---------------------------------------------------------------------------------------
_INSTANCE_ATTRIBUTES = {
    "affine": ("i_row0", "i_row1", "i_row2"),
    "cuboid": ("i_box_lo", "i_box_scale", "i_xa", "i_xb", "i_ya", "i_yb", "i_za", "i_zb"),
    "grid": ("i_grid_lo", "i_grid_scale", "i_grid_origin"),
}


def pack_atlas(shapes: list[tuple[int, int, int]], max_size: int) -> tuple[np.ndarray, tuple[int, int, int]]:
    """Place blocks of (sx, sy, sz) texels in a 3D atlas: rows along x, rows stacked in y,
    layers in z.

    Returns:
        (k, 3) texel offsets and the atlas size (W, H, D).

    Raises:
        GLError: a block or the atlas does not fit ``max_size`` on an axis.
    """
    offsets = np.zeros((len(shapes), 3), dtype=np.int64)
    x = y = z = row_h = layer_d = width = height = 0
    for i, (sx, sy, sz) in enumerate(shapes):
        if max(sx, sy, sz) > max_size:
            raise GLError(f"a grid of {sx}x{sy}x{sz} points exceeds the 3D texture limit {max_size}")
        if x + sx > max_size:
            x, y, row_h = 0, y + row_h, 0
        if y + sy > max_size:
            x, y, z, row_h, layer_d = 0, 0, z + layer_d, 0, 0
        offsets[i] = (x, y, z)
        x += sx
        row_h, layer_d = max(row_h, sy), max(layer_d, sz)
        width, height = max(width, x), max(height, y + row_h)
    depth = z + layer_d
    if depth > max_size:
        raise GLError(f"the grid atlas needs {depth} layers, more than the 3D texture limit {max_size}")
    return offsets, (max(width, 1), max(height, 1), max(depth, 1))


def atlas_image(grids: list[np.ndarray], offsets: np.ndarray, size: tuple[int, int, int]) -> np.ndarray:
    """The RGBA32F atlas (D, H, W, 4): stacked lattices written at their offsets, w = 1."""
    w, h, d = size
    image = np.zeros((d, h, w, 4), dtype=np.float32)
    image[..., 3] = 1.0
    start = 0
    for stack in grids:
        k, sx, sy, sz = stack.shape[:4]
        off = offsets[start:start + k]
        i, j, l = np.meshgrid(np.arange(sx), np.arange(sy), np.arange(sz), indexing="ij")
        xs = off[:, 0, None] + i.ravel()[None]
        ys = off[:, 1, None] + j.ravel()[None]
        zs = off[:, 2, None] + l.ravel()[None]
        image[zs, ys, xs, :3] = stack.reshape(k, -1, 3)
        start += k
    return image


def instance_data(batch: Batch, *, cuboid_form: int = 4, origins: np.ndarray | None = None) -> np.ndarray:
    """Per-instance float32 rows of a batch, in the attribute order of ``transform.vert``.

    Args:
        batch: the batch.
        cuboid_form: 4 packs the rows of ``C`` (eq. 2), 1 the rows of the corners (eq. 1).
        origins: grid path: (k, 3) block offsets + 0.5 in the atlas.
    """
    k = batch.count
    if batch.path == "affine":
        return batch.affine.reshape(k, 12).astype(np.float32)
    out = np.zeros((k, 4 * len(_INSTANCE_ATTRIBUTES[batch.path])), dtype=np.float32)
    if batch.path == "cuboid":
        out[:, 0:3] = batch.box_lo
        out[:, 4:7] = 1.0 / batch.box_size
        rows = coefficient_matrix(batch.corners) if cuboid_form == 4 else np.swapaxes(batch.corners, 1, 2)
        out[:, 8:] = rows.reshape(k, 24)
        return out
    cells = np.concatenate([np.repeat(np.array(s.shape[1:4])[None] - 1, len(s), 0) for s in batch.grids])
    out[:, 0:3], out[:, 3] = batch.box_lo, cells[:, 0]
    out[:, 4:7], out[:, 7] = cells / batch.box_size, cells[:, 1]
    out[:, 8:11], out[:, 11] = origins, cells[:, 2]
    return out


def shader_defines(path: str, normals: str, cuboid_form: int = 4) -> dict[str, object]:
    """The ``#define``s of ``trilinear/transform.vert`` for a draw path and normal mode."""
    if path not in PATHS or normals not in NORMAL_MODES:
        raise InputError(f"unknown draw path {path!r} or normal mode {normals!r}")
    return {"TRANSFORM_PATH": PATHS.index(path), "CUBOID_FORM": cuboid_form,
            "NORMALS_TANGENT": int(normals == "tangent")}


class TrilinearRenderer:
    """Draws a :class:`ComposedScene`: one instanced draw per batch, grids in one 3D atlas.

    Programs are ``trilinear/transform.vert`` + ``trilinear/lit.frag`` with defines
    ``TRANSFORM_PATH`` (0 affine, 1 cuboid, 2 grid), ``CUBOID_FORM`` and ``NORMALS_TANGENT``;
    :meth:`capture` runs the same vertex shader with transform feedback.

    Args:
        ctx: GL context.
        cuboid_form: 4 evaluates single cuboids by eq. 4 (default), 1 by eq. 1.
    """

    def __init__(self, ctx: moderngl.Context, *, cuboid_form: int = 4) -> None:
        if cuboid_form not in (1, 4):
            raise InputError(f"cuboid_form must be 1 (eq. 1) or 4 (eq. 4), got {cuboid_form}")
        self.ctx = ctx
        self.cuboid_form = cuboid_form
        self.max_3d = int(ctx.info.get("GL_MAX_3D_TEXTURE_SIZE", 256))
        self.programs: dict[tuple, Program] = {}
        # keyed by id(geometry); the geometry is kept so that its id is not reused
        self.meshes: dict[int, tuple[Geometry, moderngl.Buffer, moderngl.Buffer | None]] = {}
        self.instances: dict[tuple, list] = {}   # key -> [buffer, capacity, {vao kind: vao}]
        self.atlas: moderngl.Texture3D | None = None
        self.atlas_size = (0, 0, 0)
        self._capture_fbo: moderngl.Framebuffer | None = None
        self._capture_rb: moderngl.Renderbuffer | None = None

    def defines(self, path: str, normals: str) -> dict[str, object]:
        """The shader variant of a path and normal mode (:func:`shader_defines`)."""
        return shader_defines(path, normals, self.cuboid_form)

    def program(self, path: str, normals: str, capture: bool = False) -> Program:
        """The (cached) program of a path and normal mode, for drawing or for capture."""
        key = (path, normals, capture)
        if key not in self.programs:
            if capture:
                prog = Program(self.ctx, "trilinear/transform.vert", None, defines=self.defines(path, normals),
                               varyings=("v_world", "v_normal"))
            else:
                prog = Program(self.ctx, "trilinear/transform.vert", "trilinear/lit.frag",
                               defines=self.defines(path, normals))
            self.programs[key] = prog
        return self.programs[key]

    def _mesh(self, geometry: Geometry) -> tuple[moderngl.Buffer, moderngl.Buffer | None]:
        key = id(geometry)
        if key not in self.meshes:
            data = np.concatenate([geometry.vertices, geometry.normals], axis=1).astype(np.float32)
            vbo = self.ctx.buffer(data.tobytes())
            ibo = self.ctx.buffer(geometry.triangles.astype(np.int32).tobytes()) if len(geometry.triangles) else None
            self.meshes[key] = (geometry, vbo, ibo)
        return self.meshes[key][1:]

    def _upload_atlas(self, batches: list[Batch]) -> dict[int, np.ndarray]:
        """Pack and upload all grid lattices; returns per batch (by id) the (k, 3) origins."""
        grid_batches = [b for b in batches if b.path == "grid"]
        if not grid_batches:
            return {}
        grids = [s for b in grid_batches for s in b.grids]
        shapes = [tuple(int(v) for v in s.shape[1:4]) for s in grids for _ in range(len(s))]
        offsets, size = pack_atlas(shapes, self.max_3d)
        image = atlas_image(grids, offsets, size)
        if self.atlas is None or self.atlas_size != size:
            if self.atlas is not None:
                self.atlas.release()
            self.atlas = self.ctx.texture3d(size, 4, dtype="f4")
            self.atlas.filter = (moderngl.LINEAR, moderngl.LINEAR)
            self.atlas.repeat_x = self.atlas.repeat_y = self.atlas.repeat_z = False
            self.atlas_size = size
        self.atlas.write(image.tobytes())
        origins, start = {}, 0
        for b in grid_batches:
            origins[id(b)] = offsets[start:start + b.count] + 0.5
            start += b.count
        return origins

    def _vertex_array(self, batch: Batch, data: np.ndarray, capture: bool) -> moderngl.VertexArray:
        key = (id(batch.geometry), batch.path, batch.normals, batch.colour)
        entry = self.instances.get(key)
        if entry is None or entry[1] < data.nbytes:
            if entry is not None:
                for vao in entry[2].values():
                    vao.release()
                entry[0].release()
            entry = [self.ctx.buffer(reserve=max(data.nbytes, 64)), max(data.nbytes, 64), {}]
            self.instances[key] = entry
        entry[0].write(data.tobytes())
        if capture not in entry[2]:
            vbo, ibo = self._mesh(batch.geometry)
            prog = self.program(batch.path, batch.normals, capture)
            names = _INSTANCE_ATTRIBUTES[batch.path]
            layout = [(vbo, "3f 3f", "in_position", "in_normal"),
                      (entry[0], " ".join(["4f"] * len(names)) + "/i", *names)]
            if capture or ibo is None:
                entry[2][capture] = self.ctx.vertex_array(prog.gl, layout)
            else:
                entry[2][capture] = self.ctx.vertex_array(prog.gl, layout, index_buffer=ibo, index_element_size=4)
        return entry[2][capture]

    def _bind_grid(self, prog: Program) -> None:
        self.atlas.use(0)
        prog.set(u_grid_atlas=0, u_atlas_texel=tuple(1.0 / s for s in self.atlas_size))

    def draw(self, scene: ComposedScene, view: View, lighting: Lighting) -> None:
        """Draw every batch into the bound framebuffer (call ``RenderTarget.begin`` first)."""
        origins = self._upload_atlas(scene.batches)
        vp = tuple(view.view_projection.T.astype("f4").ravel())
        light = lighting.uniforms()
        for batch in scene.batches:
            if not len(batch.geometry.triangles):
                continue
            data = instance_data(batch, cuboid_form=self.cuboid_form, origins=origins.get(id(batch)))
            vao = self._vertex_array(batch, data, capture=False)
            prog = self.program(batch.path, batch.normals)
            prog.set(u_view_projection=vp, u_eye=tuple(float(e) for e in view.eye),
                     **{**light, "u_material_colour": batch.colour})
            if batch.path == "grid":
                self._bind_grid(prog)
            vao.render(moderngl.TRIANGLES, instances=batch.count)

    def capture(self, scene: ComposedScene) -> list[tuple[np.ndarray, np.ndarray]]:
        """Run the drawing vertex shader with transform feedback, per batch: (k, N, 3) world
        positions and (k, N, 3) normals, float32 as the GPU computed them.

        Binds a 1x1 framebuffer of its own (Mesa skips draws without a complete framebuffer).
        """
        if self._capture_fbo is None:
            self._capture_rb = self.ctx.renderbuffer((1, 1))
            self._capture_fbo = self.ctx.framebuffer(color_attachments=[self._capture_rb])
        self._capture_fbo.use()
        origins = self._upload_atlas(scene.batches)
        out = []
        for batch in scene.batches:
            data = instance_data(batch, cuboid_form=self.cuboid_form, origins=origins.get(id(batch)))
            vao = self._vertex_array(batch, data, capture=True)
            prog = self.program(batch.path, batch.normals, capture=True)
            prog.set(u_view_projection=tuple(np.identity(4, dtype="f4").ravel()))
            if batch.path == "grid":
                self._bind_grid(prog)
            n = len(batch.geometry.vertices)
            result = self.ctx.buffer(reserve=batch.count * n * 6 * 4)
            try:
                vao.transform(result, moderngl.POINTS, vertices=n, instances=batch.count)
                got = np.frombuffer(result.read(), dtype=np.float32).reshape(batch.count, n, 6)
            finally:
                result.release()
            out.append((got[..., :3].copy(), got[..., 3:].copy()))
        return out

    def release(self) -> None:
        """Release every GL object."""
        for _, _, vaos in self.instances.values():
            for vao in vaos.values():
                vao.release()
        for entry in self.instances.values():
            entry[0].release()
        for _, vbo, ibo in self.meshes.values():
            vbo.release()
            if ibo is not None:
                ibo.release()
        for prog in self.programs.values():
            prog.release()
        for obj in (self.atlas, self._capture_fbo, self._capture_rb):
            if obj is not None:
                obj.release()
        self.instances, self.meshes, self.programs = {}, {}, {}
        self.atlas = self._capture_fbo = self._capture_rb = None
