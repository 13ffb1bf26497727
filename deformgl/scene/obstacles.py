"""Drawing a scene's obstacles (ground plane and spheres) with the scene-graph renderer.

Movania & Feng 2012, section 5 shows the cloth on its sphere; without the sphere in the picture
a draped cloth is hard to read. A sphere is drawn at its position at the end of the run, half a
grid spacing smaller than the collision radius: the nodes sit on the collision surface and the
flat triangles between them cut up to ``h^2 / (8 r)`` into it, which would let the sphere show
through the cloth.
"""

from __future__ import annotations

import moderngl
import numpy as np
import trimesh

from deformgl.render.camera import View
from deformgl.sim.integrators import Constraints
from deformgl.render.passes import Lighting
from deformgl.trilinear.scenegraph import compose_scene
from deformgl.trilinear.graph_nodes import Geometry, GeometryNode, GroupNode, Node, TransformNode
from deformgl.trilinear.renderer import TrilinearRenderer

__all__ = ["OBSTACLE_COLOUR", "obstacle_scene", "draw_obstacles"]

OBSTACLE_COLOUR = (0.62, 0.64, 0.7)
_GROUND_COLOUR = (0.8, 0.8, 0.78)


def _translate_scale(centre: np.ndarray, scale: float) -> np.ndarray:
    m = np.identity(4)
    m[:3, :3] *= scale
    m[:3, 3] = centre
    return m


def obstacle_scene(constraints: Constraints, t: float, lo: np.ndarray, hi: np.ndarray, spacing: float):
    """The composed scene graph of the obstacles at time ``t``; the ground spans 1.5x the box.

    Args:
        constraints: the scene's obstacles (world units).
        t: time of the picture (s).
        lo, hi: the scene box, for the ground's extent.
        spacing: grid spacing; spheres are drawn half of it smaller.
    """
    leaves: list[Node] = []
    if constraints.spheres:
        ball = Geometry.from_trimesh(trimesh.creation.icosphere(subdivisions=4, radius=1.0), "sphere")
        for sphere in constraints.spheres:
            radius = max(sphere.radius - 0.5 * spacing, 0.5 * sphere.radius)
            leaves.append(TransformNode(_translate_scale(sphere.centre_at(t), radius),
                                        [GeometryNode(ball, colour=OBSTACLE_COLOUR)]))
    if constraints.ground is not None:
        centre, half = (lo + hi) / 2.0, 0.75 * (hi - lo)
        x0, x1, z0, z1 = centre[0] - half[0], centre[0] + half[0], centre[2] - half[2], centre[2] + half[2]
        y = constraints.ground
        quad = Geometry(np.array([[x0, y, z0], [x1, y, z0], [x1, y, z1], [x0, y, z1]]),
                        np.tile([0.0, 1.0, 0.0], (4, 1)), np.array([[0, 2, 1], [0, 3, 2]]), "ground")
        leaves.append(GeometryNode(quad, colour=_GROUND_COLOUR))
    return compose_scene(GroupNode(leaves))


def draw_obstacles(ctx: moderngl.Context, constraints: Constraints, t: float, lo: np.ndarray, hi: np.ndarray,
                   spacing: float, view: View, lighting: Lighting) -> None:
    """Draw the obstacles into the bound framebuffer (depth-tested against what is there)."""
    renderer = TrilinearRenderer(ctx)
    try:
        renderer.draw(obstacle_scene(constraints, t, lo, hi, spacing), view, lighting)
    finally:
        renderer.release()
