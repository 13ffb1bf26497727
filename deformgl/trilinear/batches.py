"""What :func:`~deformgl.trilinear.scenegraph.compose_scene` produces: :class:`Batch`es of leaves
drawn together (one mesh, draw path, normal mode and colour) with one composed transform per leaf,
and the :class:`ComposedScene` holding them, with a float64 NumPy twin of the vertex shader."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from deformgl.errors import InputError
from deformgl.trilinear.graph_nodes import Geometry, GeometryNode
from deformgl.trilinear.cuboid import Box
from deformgl.trilinear.grid import Trilinear
from deformgl.trilinear.normal_transform import transform_normals

#: Draw paths, in the order of ``TRANSFORM_PATH`` in ``shaders/trilinear/transform.vert``.
PATHS = ("affine", "cuboid", "grid")


@dataclass(eq=False)
class Batch:
    """Leaves drawn together: one mesh, one path, one normal mode, one colour.

    Exactly one group of arrays is set, by ``path`` (k = number of leaves):
    affine: ``affine`` (k, 3, 4) on local coordinates; cuboid: ``box_lo``, ``box_size`` (k, 3)
    and ``corners`` (k, 8, 3) in Knuth, Kohlhammer & Kuijper, eq. 1 order; grid: ``box_lo``, ``box_size`` and ``grids``, a
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

    def need(self, name: str, value: np.ndarray | None) -> np.ndarray:
        """``value``, the array ``name`` of this batch, which its path must have set.

        Raises:
            InputError: it is None (a batch built without the arrays of its path).
        """
        if value is None:
            raise InputError(f"a batch on the {self.path!r} path needs {name}, which is not set")
        return value

    @property
    def count(self) -> int:
        """Number of leaves (instances)."""
        return len(self.leaves)

    def transforms(self) -> list:
        """Per leaf: a 4x4 matrix (affine) or a :class:`Trilinear` over the leaf's box."""
        if self.path == "affine":
            out = []
            for m in self.need("affine", self.affine):
                full = np.identity(4)
                full[:3] = m
                out.append(full)
            return out
        boxes = [Box(lo, lo + s) for lo, s in zip(self.need("box_lo", self.box_lo),
                                                    self.need("box_size", self.box_size))]
        if self.path == "cuboid":
            return [Trilinear.from_corners(b, c) for b, c in zip(boxes, self.need("corners", self.corners))]
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
            affine = self.need("affine", self.affine)
            pts = np.einsum("kij,mj->kmi", affine[:, :, :3], corners) + affine[:, None, :, 3]
        elif self.path == "cuboid":
            pts = self.need("corners", self.corners)
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
