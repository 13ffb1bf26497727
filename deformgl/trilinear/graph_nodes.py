"""The nodes of the trilinear scene graph (Knuth, Kohlhammer & Kuijper, section 4):
:class:`Geometry` (a mesh in local coordinates), :class:`GroupNode`, :class:`TransformNode` (an
affine 4x4 matrix or a :class:`~deformgl.trilinear.transforms.Trilinear` grid) and
:class:`GeometryNode` (a mesh leaf)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from deformgl.errors import InputError
from deformgl.trilinear.cuboid import Box
from deformgl.trilinear.grid import Trilinear, check_affine
from deformgl.trilinear.normal_transform import NORMAL_MODES

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
        """Set a 4x4 affine matrix (checked) or a :class:`Trilinear`."""
        self._transform = value if isinstance(value, Trilinear) else check_affine(value)


class GeometryNode(Node):
    """A leaf drawing a :class:`Geometry` in one colour."""

    def __init__(self, geometry: Geometry, *, colour=DEFAULT_COLOUR, normals: str | None = None,
                 name: str = "") -> None:
        super().__init__((), normals=normals, name=name or geometry.name)
        self.geometry = geometry
        self.colour = tuple(float(c) for c in colour)

    def add(self, child: Node) -> Node:
        """Refused: a leaf has no children."""
        raise InputError(f"geometry node {self.name!r} cannot have children")
