"""A non-grid spring mesh on the transform-feedback backend (Movania & Feng 2012, section 4).

The fragment backend needs the grid's implicit topology; the feedback backend reads explicit
neighbour lists, so it runs springs along the edges of any triangle mesh. Here: a soft shell
(an icosphere, one spring per edge, a stiffer bending-free membrane) dropped onto a sphere
obstacle and the ground, stepped with RK4 on the GPU, read back once and drawn lit to a PNG.

Run:  python examples/mesh_springs_example.py out.png [--steps N]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import trimesh

from deformgl.render.camera import frame_box
from deformgl.scene.obstacles import draw_obstacles
from deformgl.gl.context import create_context
from deformgl.sim.backends.feedback import FeedbackSimulation
from deformgl.files import write_png_atomic
from deformgl.sim.integrators import Constraints, Sphere
from deformgl.render.passes import Lighting, RenderTarget
from deformgl.trilinear.scenegraph import compose_scene
from deformgl.trilinear.graph_nodes import Geometry, GeometryNode
from deformgl.trilinear.renderer import TrilinearRenderer
from deformgl.sim.springs import from_triangle_mesh, max_angular_frequency


def shell_system():
    """An icosphere shell of radius 0.3 m, 0.2 m above a sphere obstacle, springs on its edges."""
    shell = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    vertices = np.asarray(shell.vertices) + np.array([0.12, 0.75, 0.0])
    system = from_triangle_mesh(vertices, shell.faces, stiffness=60.0, damping=0.02, mass=2e-4,
                                velocity_damping=2e-4)
    constraints = Constraints(ground=0.0, spheres=(Sphere((0.0, 0.2, 0.0), 0.2),))
    return system, np.asarray(shell.faces), constraints


def run(out: Path, steps: int = 1500) -> np.ndarray:
    """Simulate and render; returns the final vertex positions."""
    system, faces, constraints = shell_system()
    dt = 0.5 * 2.83 / max_angular_frequency(system).omega  # half RK4's stability limit
    ctx = create_context()
    try:
        sim = FeedbackSimulation(ctx, system, "rk4", dt, constraints=constraints)
        try:
            sim.step(steps)
            x = sim.positions().astype(np.float64)
        finally:
            sim.release()
        if not np.isfinite(x).all():
            raise SystemExit("the shell diverged")
        lo, hi = np.array([-0.5, 0.0, -0.5]), np.array([0.5, 1.0, 0.5])
        view = frame_box(lo, hi, projection="perspective", azimuth=30.0, elevation=20.0, fov=35.0,
                         distance=1.4, target=np.array([0.5, 0.35, 0.5]), aspect=4 / 3)
        lighting = Lighting(direction=(0.4, 1.0, 0.6), colour=(1.0, 1.0, 1.0), ambient=0.2,
                            material=(0.3, 0.6, 0.85), specular=0.3, shininess=32.0)
        target = RenderTarget(ctx, (480, 360), 4)
        renderer = TrilinearRenderer(ctx)
        try:
            target.begin((0.96, 0.96, 0.94))
            deformed = trimesh.Trimesh(x, faces, process=False)
            shell = Geometry.from_trimesh(deformed, "shell")
            renderer.draw(compose_scene(GeometryNode(shell, colour=(0.3, 0.6, 0.85))), view, lighting)
            draw_obstacles(ctx, constraints, steps * dt, lo, hi, 0.0, view, lighting)
            write_png_atomic(out, target.read_rgb())
        finally:
            renderer.release()
            target.release()
    finally:
        ctx.release()
    return x


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("output", type=Path)
    p.add_argument("--steps", type=int, default=1500)
    args = p.parse_args()
    run(args.output, args.steps)
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
