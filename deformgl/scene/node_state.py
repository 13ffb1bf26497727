"""Where a scene's node positions come from when it is drawn: the simulation (kept on the GPU
where its state texture carries the packed normals), a node-frames file or an analytic motion
(:class:`NodeState`; used by :mod:`deformgl.scene.pipeline` and :mod:`deformgl.scene.animation`)."""

from __future__ import annotations

from typing import Any

import moderngl
import numpy as np

from deformgl.errors import InputError
from deformgl.mapping.node_drivers import DrivenNodes, Motion, load_node_frames
from deformgl.scene.physics import SceneBox, SceneRun, simulate_scene
from deformgl.scene.spec import Scene
from deformgl.sim.backends.verlet_data import NodeTextures

__all__ = ["NodeState"]


class NodeState:
    """Where a scene's node positions come from: the simulation, a file or an analytic motion.

    ``position_texture`` is what the draw passes read; ``release`` frees every GL object.
    ``built`` is the scene's :class:`~deformgl.scene.pipeline.SceneModel` (typed loosely: the
    pipeline imports this module).
    """

    def __init__(self, ctx: moderngl.Context, scene: Scene, built: Any, *, progress: bool,
                 velocities: bool = False) -> None:
        nodes = scene.nodes
        self.sim: Any = None  # a simulation drawn from its own state texture (packed normals)
        self.driven: DrivenNodes | None = None
        self.run: SceneRun | None = None  # the run, if the scene simulates
        self.notes: list[str] = []  # what the step plan and restarts changed, for the log
        self.textures: NodeTextures
        if nodes.source == "simulate":
            self.run = simulate_scene(ctx, scene, built.grid, built.system, built.loads, SceneBox(*built.bbox),
                                 progress=progress, notes=self.notes, keep=True, velocities=velocities)
            if self.run.sim is not None:
                self.sim = self.run.sim
                self.textures = self.sim.textures
                return
            if self.run.positions is None:
                raise RuntimeError("simulate_scene returned neither positions nor a simulation")  # never
            positions = self.run.positions
        if nodes.source == "file":
            if nodes.file is None:
                raise ValueError(f"{scene.source}: nodes.file is not set")  # the schema sets it
            frames = load_node_frames(nodes.file, built.grid.count, built.centre)
            if not -len(frames) <= nodes.frame < len(frames):
                raise InputError(f"{scene.source}: nodes.frame: {nodes.frame} is outside the "
                                 f"{len(frames)} frame(s) of {nodes.file}")
            positions = frames[nodes.frame]
        elif nodes.source == "motion":
            m = nodes.motion
            if m is None:
                raise ValueError(f"{scene.source}: nodes.motion is not set")  # the schema sets it
            motion = Motion(m.kind, m.angle, m.axis, m.along, m.towards, m.translate)
            positions = motion.apply(built.grid.rest_positions, m.amount)
        self._positions = np.asarray(positions, np.float64)
        self.textures = NodeTextures(ctx, built.grid)
        try:
            self.driven = DrivenNodes(ctx, self.textures, built.grid)
            self.driven.set_positions(positions)
        except BaseException:
            self.release()
            raise

    @property
    def position_texture(self) -> moderngl.Texture:
        """State texture with the node positions and packed normals to draw."""
        if self.sim:
            return self.sim.position_texture
        if self.driven is None:
            raise RuntimeError("NodeState: no node positions (not built, or released)")
        return self.driven.position_texture

    def positions(self) -> np.ndarray:
        """(N, 3) float64 node positions (recentred): the simulation's (a read-back) or the
        driven ones."""
        if self.sim:
            return np.asarray(self.sim.positions(), np.float64)
        return self._positions

    def velocities(self) -> tuple[np.ndarray | None, float]:
        """(N, 3) float64 node velocities in m/s and the simulation's step in s; (None, 0) for
        nodes that were not simulated (or a run not asked for ``velocities``)."""
        if self.sim:
            return np.asarray(self.sim.velocities(), np.float64), float(self.sim.dt)
        if self.run is not None and self.run.velocities is not None:
            return self.run.velocities, self.run.sim_dt
        return None, 0.0

    @property
    def layout(self):
        """The compact layout of the node textures."""
        return self.textures.layout

    def release(self) -> None:
        """Release every GL object."""
        if self.sim is not None:
            self.sim.release()
            self.sim = None
        else:
            if self.driven is not None:
                self.driven.release()
            self.textures.release()
