"""A scene's physics on any integrator and backend: the spring system, its loads, drags and
obstacles from the scene file, and the run (fixed step count or convergence stop).

Scene positions are bounding-box fractions of the (recentred) scene box; sphere radii are in
units of its longest side. The foundation's fragment Verlet pass (``fragment_sim.py``) keeps
running scenes that use none of the extended physics (:attr:`scene.Physics.extended`) with the
default integrator and backend; everything else runs here:

* ``fragment``: :class:`~deformgl.fragment_integrators.FragmentIntegrator` (grid topology);
* ``feedback``: :class:`~deformgl.feedback_sim.FeedbackSimulation` (explicit neighbour lists);
* ``numpy``: the float64 reference :func:`deformgl.integrators.step`.

The convergence stop (Movania & Feng 2012, section 4) is measured on the GPU: every ``every``
steps the positions are copied before the last step (a GPU pass) and the nodes that moved more
than the threshold in that step are counted by an occlusion query (:mod:`deformgl.census`), so
one integer per check crosses to the CPU, never the state.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import moderngl
import numpy as np

from . import integrators
from .errors import SimulationError
from .grid import NodeGrid
from .integrators import Constraints, Sphere
from .model import SpringModel
from .progress import Progress
from .scene import Keyframes, Physics, Scene
from .springs import Drag, Load, SpringSystem, from_grid, max_angular_frequency

__all__ = ["SceneBox", "SceneRun", "check_positions_finite", "needs_integrators", "step_in_chunks", "scene_system", "scene_loads", "scene_drags",
           "scene_constraints", "run_scene"]


@dataclass(frozen=True)
class SceneBox:
    """The box scene fractions refer to: ``lo``, ``hi`` (3,) in recentred world coordinates."""

    lo: np.ndarray
    hi: np.ndarray

    def world(self, fraction) -> np.ndarray:
        """(3,) world position of a box-fraction point."""
        return self.lo + (self.hi - self.lo) * np.asarray(fraction, dtype=np.float64)

    @property
    def longest(self) -> float:
        """The longest side (unit of sphere radii)."""
        return float(np.max(self.hi - self.lo))

    def path(self, keyframes: Keyframes) -> Callable[[float], np.ndarray]:
        """t -> (3,) world position along a keyframed path."""
        return lambda t: self.world(keyframes.at(t))


def needs_integrators(physics: Physics) -> bool:
    """True when the scene must run on the five-integrator backends (not the foundation pass)."""
    return physics.integrator != "verlet" or physics.backend != "fragment" or physics.extended


def scene_system(grid: NodeGrid, model: SpringModel, physics: Physics) -> SpringSystem:
    """The scene's spring system: the grid's springs by class (a class of stiffness 0 is not
    built), the model's masses and fixed nodes, global damping, gravity and wind."""
    k1, k2, k3 = physics.class_stiffness()
    return from_grid(grid, k_structural=k1, k_shear=k2, k_flexion=k3,
                     damping_structural=physics.structural.damping, damping_shear=physics.shear.damping,
                     damping_flexion=physics.flexion.damping, mass=model.mass, fixed=model.fixed,
                     velocity_damping=physics.damping, gravity=physics.gravity, wind=physics.wind,
                     wind_drag=physics.wind_drag)


def scene_loads(model: SpringModel, physics: Physics) -> tuple[Load, ...]:
    """One load per ``[[physics.pull]]``: its force per node on the nodes of its region."""
    return tuple(Load((model.pull_groups >> g) & 1 == 1, pull.force_at)
                 for g, pull in enumerate(physics.pull))


def scene_drags(grid: NodeGrid, physics: Physics, box: SceneBox) -> tuple[Drag, ...]:
    """One drag per ``[[physics.drag]]``: the node nearest to the path's first point, pulled
    toward the moving point."""
    drags = []
    for spec in physics.drag:
        start = box.world(spec.path.at(spec.path.times[0]))
        node = int(np.argmin(np.linalg.norm(grid.rest_positions - start, axis=1)))
        drags.append(Drag(node, box.path(spec.path), spec.stiffness))
    return tuple(drags)


def scene_constraints(physics: Physics, box: SceneBox) -> Constraints | None:
    """Ground plane and spheres in world units, or None without obstacles."""
    if physics.ground is None and not physics.sphere:
        return None
    ground = None if physics.ground is None else float(box.world((0.0, physics.ground, 0.0))[1])
    spheres = tuple(Sphere(box.world(s.centre) if s.path is None else box.path(s.path),
                           s.radius * box.longest) for s in physics.sphere)
    return Constraints(ground=ground, spheres=spheres)


@dataclass
class SceneRun:
    """What a run produced: final positions (N, 3) float64, steps taken, whether the convergence
    stop ended it (None without one), GPU bytes per node (0 for numpy), the end time."""

    positions: np.ndarray
    steps: int
    converged: bool | None
    bytes_per_node: float
    time: float

    def summary(self, physics: Physics) -> str:
        """One line for the log."""
        line = f"{physics.integrator} on the {physics.backend} backend: {self.steps} steps"
        if self.converged is not None:
            line += " (converged)" if self.converged else " (step limit reached before convergence)"
        if self.bytes_per_node:
            line += f", {self.bytes_per_node:.0f} GPU bytes per node"
        return line


def check_positions_finite(positions: np.ndarray, grid: NodeGrid, steps: int, source, omega: float) -> None:
    """A non-finite node stops the run: the error names it (number and grid index), the step, and
    the dt limits from the highest angular frequency bound ``omega`` (rad/s)."""
    bad = ~np.isfinite(positions[:, :3]).all(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        ijk = tuple(int(v) for v in grid.ijk[i])
        raise SimulationError(
            f"{source}: simulation diverged: node {i} (grid {ijk}) is non-finite after step {steps} "
            f"({int(bad.sum())} nodes bad); reduce physics.dt or stiffness (highest angular frequency "
            f"w = {omega:.4g} rad/s: Verlet and semi-implicit Euler need dt < 2/w = {2.0 / omega:.4g} s, "
            f"RK4 dt < 2.83/w)")


def step_in_chunks(ctx: moderngl.Context, sim, steps: int, bar: Progress, chunk: int = 25) -> None:
    """``steps`` steps on the GPU in chunks of ``chunk``, updating the progress bar; no read-back."""
    done = 0
    while done < steps:
        n = min(chunk, steps - done)
        sim.step(n)
        ctx.finish()
        done += n
        bar.update(done)


def _run_numpy(system: SpringSystem, physics: Physics, constraints, drags, loads, bar: Progress,
               threshold: float | None) -> tuple[np.ndarray, int, bool | None]:
    dt, name = physics.dt, physics.integrator
    s = integrators.initial_state(system, dt, drags=drags, loads=loads)
    for n in range(physics.steps):
        new = integrators.step(system, name, s, dt, n * dt, constraints=constraints, drags=drags, loads=loads)
        moved = float(np.max(np.linalg.norm(new.x - s.x, axis=1), initial=0.0))
        s = new
        bar.update(n + 1)
        if not np.isfinite(moved):
            return s.x, n + 1, None if threshold is None else False
        if threshold is not None and (n + 1) % physics.converge.every == 0 and moved <= threshold:
            return s.x, n + 1, True
    return s.x, physics.steps, None if threshold is None else False


def _run_gpu(ctx: moderngl.Context, sim, physics: Physics, bar: Progress,
             threshold: float | None) -> tuple[int, bool | None]:
    from .census import NodeCensus

    steps = physics.steps
    if threshold is None:
        step_in_chunks(ctx, sim, steps, bar)
        return steps, None
    _, row, slots, _ = sim.position_slot()
    census = NodeCensus(ctx, count=sim.count, row=row, slots=slots)
    try:
        done, every = 0, physics.converge.every
        while done < steps:
            n = min(every, steps - done)
            if n > 1:
                sim.step(n - 1)
            texture, _, _, slot = sim.position_slot()
            before = census.snapshot(texture, slot=slot)
            sim.step(1)
            done += n
            bar.update(done)
            now, _, _, slot = sim.position_slot()
            if n == every and census.moved(now, before, threshold, slot=slot, before_slots=1) == 0:
                return done, True
        return steps, False
    finally:
        census.release()


def run_scene(ctx: moderngl.Context, scene: Scene, grid: NodeGrid, model: SpringModel, box: SceneBox, *,
              progress: bool) -> SceneRun:
    """Simulate a scene's nodes with its integrator on its backend; positions are read once."""
    physics = scene.physics
    system = scene_system(grid, model, physics)
    loads, drags = scene_loads(model, physics), scene_drags(grid, physics, box)
    constraints = scene_constraints(physics, box)
    threshold = None if physics.converge is None else physics.converge.threshold * grid.spacing
    with Progress(physics.steps, "steps", enabled=progress) as bar:
        if physics.backend == "numpy":
            x, steps, converged = _run_numpy(system, physics, constraints, drags, loads, bar, threshold)
            run = SceneRun(np.asarray(x, np.float64), steps, converged, 0.0, steps * physics.dt)
        else:
            if physics.backend == "fragment":
                from .fragment_integrators import FragmentIntegrator

                sim = FragmentIntegrator(ctx, system, grid, physics.integrator, physics.dt,
                                         constraints=constraints, drags=drags, loads=loads)
            else:
                from .feedback_sim import FeedbackSimulation

                sim = FeedbackSimulation(ctx, system, physics.integrator, physics.dt,
                                         constraints=constraints, drags=drags, loads=loads)
            try:
                steps, converged = _run_gpu(ctx, sim, physics, bar, threshold)
                run = SceneRun(sim.positions().astype(np.float64), steps, converged, sim.bytes_per_node,
                               steps * physics.dt)
            finally:
                sim.release()
    check_positions_finite(run.positions, grid, run.steps, scene.source, max_angular_frequency(system).omega)
    return run
