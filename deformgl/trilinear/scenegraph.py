"""A scene graph whose transforms are trilinear (Knuth, Kohlhammer & Kuijper, sections 4-4.2).

Nodes: :class:`GroupNode`, :class:`TransformNode` (an affine 4x4 matrix or a
:class:`~deformgl.trilinear.grid.Trilinear` grid over the bounding box of its content) and
:class:`GeometryNode` (a mesh leaf). :func:`compose_scene` traverses from the world to the leaves
on the CPU and gives every leaf one composed transform (4.1): affine matrices multiply exactly;
at a trilinear node the child's lattice is transformed by the composed parent at the higher of the
two resolutions. A leaf right under a trilinear node is drawn with that composed grid as it
is; a leaf with affine nodes between gets the composed grid resampled over its own box at the
resolution of the grid cells it crosses. The leaf stage is vectorized over all leaves that share
a parent grid and a mesh.

Each leaf is then classified by the linearity test (3.2): linear ones are drawn through the plain
affine path, one-cuboid ones by Knuth, Kohlhammer & Kuijper, eq. 4, the rest through a 3D-texture grid
(``shaders/trilinear/transform.vert``). :class:`~deformgl.trilinear.renderer.TrilinearRenderer` draws
every batch of leaves sharing mesh, path, normal mode and colour with one instanced draw.

This module holds the composition; the nodes are in :mod:`deformgl.trilinear.graph_nodes`, the batches
in :mod:`deformgl.trilinear.batches`, the GPU renderer in :mod:`deformgl.trilinear.renderer`.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from deformgl.trilinear.batches import Batch, ComposedScene
from deformgl.trilinear.graph_nodes import Geometry, GeometryNode, Node, TransformNode
from deformgl.trilinear.cuboid import (
    LINEAR_RTOL, Box, coefficient_matrix, corner_weights, grid_corners, is_linear_coefficients, unit_lattice,
)
from deformgl.trilinear.grid import Trilinear, compose, lattice_matches

__all__ = ["compose_scene", "SceneComposer"]

_IDENTITY = np.identity(4)
_IDENTITY.flags.writeable = False


# ---- traversal and composition (section 4.1) ------------------------------------------------------
#: One leaf found by the traversal: (leaf, composed grid or None, its chain key, affine slot, normals).
_Leaf = tuple[GeometryNode, "Trilinear | None", object, int, str]


def _grid_key(t: Trilinear) -> tuple:
    """The content of a grid node's transform (changes when its lattice, box or error do)."""
    return id(t), t.points.tobytes(), t.box.lo.tobytes(), t.box.hi.tobytes(), t.error


class _Slots:
    """The affine products of a traversal, multiplied after it, level by level, in one batched
    ``matmul`` per depth: slot 0 is the identity, slot i = slot ``parent[i]`` @ ``mats[i]``, so
    every leaf's affine is the product of the matrices on its chain since the last grid node,
    in the same order as multiplying along the way (``affine @ t``)."""

    def __init__(self) -> None:
        self.parent = [0]
        self.mats: list[np.ndarray] = [_IDENTITY]
        self.depth = [0]
        self._resolved: dict[int, np.ndarray] = {0: _IDENTITY}

    def push(self, slot: int, matrix: np.ndarray) -> int:
        self.parent.append(slot)
        self.mats.append(matrix)
        self.depth.append(self.depth[slot] + 1)
        return len(self.mats) - 1

    def one(self, slot: int) -> np.ndarray:
        """The product at ``slot`` now (a grid node needs the affine before it during the walk)."""
        if slot not in self._resolved:
            self._resolved[slot] = self.one(self.parent[slot]) @ self.mats[slot]
        return self._resolved[slot]

    def all(self) -> np.ndarray:
        """(slots, 4, 4) every product."""
        out = np.empty((len(self.mats), 4, 4))
        out[0] = _IDENTITY
        if len(self.mats) == 1:
            return out
        depth, parent, mats = np.array(self.depth), np.array(self.parent), np.array(self.mats)
        for d in range(1, int(depth.max()) + 1):
            sel = np.flatnonzero(depth == d)
            out[sel] = np.matmul(out[parent[sel]], mats[sel])
        return out


def _collect(root: Node, grids: dict | None = None) -> tuple[list[_Leaf], np.ndarray]:
    """Depth-first from the world: the leaves in drawing order and the affine products.

    The composed transform of a leaf is ``grid * affine``; affine nodes multiply into
    ``affine`` (deferred to :meth:`_Slots.all`), trilinear nodes are composed into a new grid
    (:func:`compose`). ``grids``: composed grids of a previous traversal by chain key, reused
    where the chain (its grid nodes' content and the affines between) did not change; on
    return it holds this traversal's.
    """
    slots = _Slots()
    previous = {} if grids is None else dict(grids)
    made: dict = {}
    seen: dict = {}
    leaves: list[_Leaf] = []
    append = leaves.append
    stack: list[tuple[Node, Trilinear | None, object, int, str]] = [(root, None, None, 0, "direct")]
    pop, push = stack.pop, stack.append
    while stack:
        node, grid, key, slot, normals = pop()
        normals = node.normals or normals
        if isinstance(node, GeometryNode):
            append((node, grid, key, slot, normals))
            continue
        if isinstance(node, TransformNode):
            t = node._transform
            if isinstance(t, Trilinear):
                affine = slots.one(slot)
                key = (key, id(node), affine.tobytes(), _grid_key(t))
                seen[key] = seen.get(key, -1) + 1  # the same node twice on one chain: two grids
                key = (key, seen[key])
                composed = previous.get(key)
                if composed is None:
                    if grid is None:
                        composed = Trilinear(t.box, t.points @ affine[:3, :3].T + affine[:3, 3], t.error)
                    else:
                        composed = compose(grid, t, between=affine)
                made[key] = grid = composed
                slot = 0
            else:
                slot = slots.push(slot, t)
        for child in reversed(node.children):
            push((child, grid, key, slot, normals))
    if grids is not None:
        grids.clear()
        grids.update(made)
    return leaves, slots.all()


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
        cx, cy, cz = (int(v) for v in n[sel[0]])
        c = (cx, cy, cz)
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
        (:class:`SceneComposer` does the same, frame after frame, recomposing only what changed.)
    """
    return SceneComposer(rtol=rtol).compose(root)


class SceneComposer:
    """:func:`compose_scene` for a scene drawn frame after frame: what did not change since the
    previous :meth:`compose` is not recomposed.

    Remembered from the previous frame, by content (so changing a matrix or a lattice in place
    counts too): each composed grid by its chain (the grid nodes' lattices and the affine
    products between them), and each group's leaf stage (resampling, linearity test, batch
    parts) by its leaves, their composed grid and the affine products of their chains (one
    bytes comparison per group). Only the traversal and the affine products (one batched
    product per depth) run every frame. The output is the one :func:`compose_scene` gives.

    Args:
        rtol: tolerance of the linearity test (3.2).

    Attributes:
        recomposed, reused: leaves whose leaf stage ran / was taken from the previous frame, in
            the last :meth:`compose`.
    """

    def __init__(self, *, rtol: float = LINEAR_RTOL) -> None:
        self.rtol = rtol
        self._grids: dict = {}
        self._groups: dict = {}
        self.recomposed = 0
        self.reused = 0

    def compose(self, root: Node) -> ComposedScene:
        """The composed scene of ``root`` now."""
        found, affines = _collect(root, self._grids)
        groups: dict[tuple, list] = {}
        for leaf, grid, key, slot, normals in found:
            groups.setdefault((id(grid), id(leaf.geometry), normals, leaf.colour), []).append((leaf, grid, key, slot))
        builder = _BatchBuilder()
        cache: dict = {}
        self.recomposed = self.reused = 0
        for (_, _, normals, colour), members in groups.items():
            grid, geometry = members[0][1], members[0][0].geometry
            leaves = [m[0] for m in members]
            mats = affines[np.fromiter((m[3] for m in members), np.int64, len(members))]
            if grid is None:
                builder.add(geometry, "affine", normals, colour, leaves, affine=mats[:, :3])
                continue
            key = (members[0][2], id(geometry), normals, colour, tuple(leaves), mats.tobytes())
            parts = self._groups.get(key)
            if parts is None:
                parts = list(_grid_parts(grid, geometry, mats, self.rtol))
                self.recomposed += len(leaves)
            else:
                self.reused += len(leaves)
            cache[key] = parts
            for path, chosen, arrays in parts:
                builder.add(geometry, path, normals, colour, [leaves[i] for i in chosen], **arrays)
        self._groups = cache
        return ComposedScene(builder.build())


def _grid_parts(grid: Trilinear, geometry: Geometry, mats: np.ndarray,
                rtol: float) -> Iterator[tuple[str, np.ndarray, dict[str, np.ndarray]]]:
    """The leaf stage of one group under a composed grid: (path, leaf indices, batch arrays)."""
    for sel, pts, box in _leaf_parts(grid, mats, geometry.box):
        linear, exact = _classify(pts, rtol)
        corners = grid_corners(pts)
        for mask, path in ((linear, "affine"), (exact & ~linear, "cuboid"), (~exact, "grid")):
            count = int(mask.sum())
            if not count:
                continue
            chosen = sel[mask]
            if path == "affine":
                yield path, chosen, {"affine": _corners_to_affine(corners[mask], box)}
                continue
            boxes = {"box_lo": np.repeat(box.lo[None], count, 0), "box_size": np.repeat(box.size[None], count, 0)}
            if path == "cuboid":
                yield path, chosen, {"corners": corners[mask], **boxes}
            else:
                yield path, chosen, {"grids": pts[mask], **boxes}
