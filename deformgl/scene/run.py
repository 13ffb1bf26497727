"""A scene's physics on any integrator and backend: the spring system, its loads, drags and
obstacles from the scene file, and the run (fixed step count or convergence stop).

Scene positions are bounding-box fractions of the (recentred) scene box; sphere radii are in
units of its longest side. The foundation's fragment Verlet pass (``fragment_sim.py``) keeps
running scenes that use none of the extended physics (:attr:`scene.Physics.extended`) with the
default integrator and backend; everything else runs here:

* ``fragment``: :class:`~deformgl.sim.backends.fragment.FragmentIntegrator` (grid topology);
* ``feedback``: :class:`~deformgl.sim.backends.feedback.FeedbackSimulation` (explicit neighbour lists);
* ``numpy``: the float64 reference, :class:`~deformgl.sim.simulation.NumpySimulation`.

All three are built by :func:`~deformgl.sim.simulation.make_simulation` and run by the one run
loop :func:`deformgl.sim.run.run`.

The convergence stop (Movania & Feng 2012, section 4) is measured on the GPU: every ``every``
steps the positions are copied before the last step (a GPU pass) and the nodes that moved more
than the threshold in that step are counted by an occlusion query (:mod:`deformgl.sim.census`), so
one integer per check crosses to the CPU, never the state.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

import moderngl
import numpy as np

from deformgl.errors import SimulationError
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.integrators import Constraints, Sphere
from deformgl.sim.model import SpringModel
from deformgl.progress import Progress
from deformgl.sim.guards import BlowUp, BlowUpWatch, StepPlan, plan_steps
from deformgl.sim.run import make_watch
from deformgl.sim.run import run as run_simulation
from deformgl.sim.simulation import make_simulation
from deformgl.scene.schema import Keyframes, Physics, Scene
from deformgl.sim.springs import Drag, Load, SpringSystem, from_grid

__all__ = ["SceneBox", "SceneRun", "bad_limit", "needs_integrators", "run_scene",
           "run_with_retries", "scene_constraints", "scene_drags", "scene_loads", "scene_system", "step_watched"]

T = TypeVar("T")


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
    """What a run produced: final positions (N, 3) float64, steps taken (of dt / substeps),
    whether the convergence stop ended it (None without one), GPU bytes per node (0 for numpy),
    the end time, the substeps per scene step."""

    positions: np.ndarray
    steps: int
    converged: bool | None
    bytes_per_node: float
    time: float
    substeps: int = 1

    def summary(self, physics: Physics) -> str:
        """One line for the log."""
        line = f"{physics.integrator} on the {physics.backend} backend: {self.steps} steps"
        if self.substeps > 1:
            line += f" ({self.substeps} substeps per scene step)"
        if self.converged is not None:
            line += " (converged)" if self.converged else " (step limit reached before convergence)"
        if self.bytes_per_node:
            line += f", {self.bytes_per_node:.0f} GPU bytes per node"
        return line


def bad_limit(physics: Physics, box: SceneBox) -> float:
    """World distance from the (recentred) box centre beyond which a node counts as blown up."""
    return physics.safety.bad_distance * box.longest


def step_watched(ctx: moderngl.Context, sim, steps: int, bar: Progress, watch: BlowUpWatch | None = None, *,
                 chunk: int = 25, converge: tuple[float, int] | None = None) -> tuple[int, bool | None]:
    """:func:`deformgl.sim.run.run` as (steps done, converged: True/False, None without a
    convergence stop); kept for the callers that step a simulation they built themselves.

    Raises:
        BlowUp: a check counted bad nodes.
    """
    result = run_simulation(sim, steps, ctx=ctx, watch=watch, converge=converge, progress=bar, chunk=chunk)
    return result.steps, result.converged


def run_with_retries(plan: StepPlan, policy: str, attempt: Callable[[StepPlan], T],
                     notes: list[str]) -> tuple[T, StepPlan]:
    """``attempt(plan)``; with the "subdivide" policy a :class:`BlowUp` restarts it with twice the
    substeps (up to :data:`~deformgl.safety.MAX_SUBSTEPS`), each restart noted in ``notes``."""
    while True:
        try:
            return attempt(plan), plan
        except BlowUp as exc:
            if policy != "subdivide":
                raise
            finer = plan.halved()
            if finer is None:
                raise SimulationError(f"{exc} (still at {plan.substeps} substeps per step, the most "
                                      f"--subdivide uses)") from None
            notes.append(f"{exc}; {finer.note}")
            plan = finer


def run_scene(ctx: moderngl.Context, scene: Scene, grid: NodeGrid, model: SpringModel, box: SceneBox, *,
              progress: bool, plan: StepPlan | None = None, notes: list[str] | None = None,
              system: SpringSystem | None = None) -> SceneRun:
    """Simulate a scene's nodes with its integrator on its backend; positions are read once.

    Args:
        plan: the checked step plan (default: :func:`~deformgl.safety.plan_steps` of the scene,
            which refuses a dt above the limit unless ``physics.safety.unstable`` says otherwise).
        notes: receives what the plan and the restarts changed, if given.
        system: the scene's :func:`scene_system`, if the caller built it already.
    """
    physics = scene.physics
    system = scene_system(grid, model, physics) if system is None else system
    plan = plan_steps(system, physics, scene.source) if plan is None else plan
    notes = [] if notes is None else notes
    if plan.note:
        notes.append(plan.note)
    loads, drags = scene_loads(model, physics), scene_drags(grid, physics, box)
    constraints = scene_constraints(physics, box)
    limit = bad_limit(physics, box)

    def attempt(p: StepPlan) -> SceneRun:
        converge = None
        if physics.converge is not None:  # per scene step: over a substep a node moves 1/substeps as far
            converge = (physics.converge.threshold * grid.spacing / p.substeps, physics.converge.every * p.substeps)
        with Progress(p.step_count, "steps", enabled=progress) as bar:
            sim = make_simulation(system, physics.integrator, physics.backend, dt=p.step_dt, ctx=ctx, grid=grid,
                                  constraints=constraints, drags=drags, loads=loads)
            watch = None
            try:
                watch = make_watch(ctx, sim, every=physics.safety.check_every, limit=limit, grid=grid,
                                   source=scene.source, dt=p.step_dt)
                result = run_simulation(sim, p.step_count, ctx=ctx, watch=watch, converge=converge, progress=bar)
                return SceneRun(np.asarray(sim.positions(), np.float64), result.steps, result.converged,
                                sim.bytes_per_node, result.steps * p.step_dt, p.substeps)
            finally:
                if watch is not None:
                    watch.release()
                sim.release()

    # every run ends with a blow-up check (census or NumPy), so its positions are finite
    run, _ = run_with_retries(plan, physics.safety.unstable, attempt, notes)
    return run
