"""Geometry attached to the deforming detailed mesh through anchors and a trilinear grid
(Knuth, Kohlhammer & Kuijper, section 5), on a mesh driven by the spring-mass simulation and a
mapping (Mosegaard & Sørensen 3.3).

An attachment is a tube lying on the surface along a path: a 1D array of anchors registered on
the rest mesh gives, every frame, the attached object's deformation grid from the *deformed*
vertices (captured from the mapping vertex shader), and the tube is drawn through the scene
graph: grid node -> affine lift onto the surface -> tube geometry.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from deformgl.trilinear.anchors import AnchorArray
from deformgl.errors import InputError
from deformgl.trilinear.scenegraph import compose_scene
from deformgl.trilinear.batches import ComposedScene
from deformgl.trilinear.graph_nodes import GeometryNode, TransformNode
from deformgl.trilinear.cuboid import Box
from deformgl.trilinear.shapes import tube


@dataclass(frozen=True, eq=False)
class TubeAttachment:
    """A tube of radius ``radius`` lying on the mesh along anchors (the rest geometry).

    Attributes:
        anchors: (I,) anchors on the detailed mesh.
        box: the tube's box in its local frame: x along the path (0 .. rest length), y across,
            z above the surface.
        colour: RGB in [0, 1].
    """

    anchors: AnchorArray
    box: Box
    radius: float
    colour: tuple[float, float, float]

    @classmethod
    def along(cls, vertices: np.ndarray, faces: np.ndarray, start: np.ndarray, end: np.ndarray, *,
              count: int, radius: float, colour=(0.2, 0.45, 0.85)) -> "TubeAttachment":
        """Anchors at the mesh vertices nearest to ``count`` points from ``start`` to ``end``.

        Raises:
            InputError: fewer than 2 distinct anchor positions.
        """
        samples = np.linspace(start, end, count)
        _, nearest = cKDTree(vertices).query(samples)
        keep = np.concatenate([[True], nearest[1:] != nearest[:-1]])
        positions = vertices[nearest[keep]]
        if len(positions) < 2:
            raise InputError(f"attach: the path from {np.round(start, 4).tolist()} to "
                             f"{np.round(end, 4).tolist()} meets fewer than 2 mesh vertices")
        used = np.zeros(len(vertices), bool)
        used[faces.ravel()] = True
        if not used[nearest[keep]].all():
            raise InputError("attach: an anchor landed on a vertex that no face uses")
        ahead = np.concatenate([positions[1:], 2 * positions[-1:] - positions[-2:-1]])
        anchors = AnchorArray.on_mesh(vertices, faces, positions, ahead)
        length = float(np.linalg.norm(np.diff(positions, axis=0), axis=1).sum())
        box = Box(np.array([0.0, -radius, 0.0]), np.array([length, radius, 2.0 * radius]))
        rgb = tuple(float(c) for c in colour)
        if len(rgb) != 3:
            raise InputError(f"attach: colour must be RGB (3 values), got {len(rgb)}")
        return cls(anchors, box, float(radius), rgb)

    def compose(self, vertices: np.ndarray, faces: np.ndarray, *, rings: int = 48) -> ComposedScene:
        """The scene graph of the tube on the mesh's current ``vertices``, composed."""
        grid = self.anchors.grid(vertices, faces, self.box)
        lift = np.identity(4)
        lift[2, 3] = self.radius  # the tube's axis one radius above the surface
        geometry = tube(float(self.box.hi[0]), self.radius, sections=16, rings=rings, name="attached tube")
        leaf = GeometryNode(geometry, colour=self.colour)
        return compose_scene(TransformNode(grid, [TransformNode(lift, [leaf])]))
