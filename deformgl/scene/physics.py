"""A scene's physics on any integrator and backend: the spring system, its loads, drags and
obstacles from the scene file, and the run (fixed step count or convergence stop).

Scene positions are bounding-box fractions of the (recentred) scene box; sphere radii are in
units of its longest side. Every scene runs here, on its integrator and backend:

* ``fragment``: :class:`~deformgl.sim.backends.explicit_gpu.FragmentIntegrator` (grid topology; for
  Verlet on a system the foundation pass models it picks that pass, whose state texture carries
  the packed node normals the mappings draw from);
* ``feedback``: :class:`~deformgl.sim.backends.feedback.FeedbackSimulation` (explicit neighbour lists);
* ``numpy``: the float64 reference, :class:`~deformgl.sim.simulation.NumpySimulation`.

All three are built by :func:`~deformgl.sim.simulation.make_simulation` and run by the one run
:func:`deformgl.sim.run.run` (:func:`simulate_scene`).

The convergence stop (``[physics.converge]``, :mod:`deformgl.sim.equilibrium`) is by default
the equilibrium criterion: every ``interval`` simulated seconds the positions are read back and
the net force on the free nodes and the kinetic energy are measured against the applied force
and the run's peak. The paper's displacement criterion (Movania & Feng 2012, section 4,
``criterion = "displacement"``) is measured on the GPU: every ``every`` steps the positions are
copied before the last step (a GPU pass) and the nodes that moved more than the threshold in that
step are counted by an occlusion query (:mod:`deformgl.sim.census`), so one integer per check
crosses to the CPU, never the state.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import moderngl
import numpy as np

from deformgl.grid.blocks import parse_block
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.integrators import Constraints, Sphere
from deformgl.sim.guards import StepPlan
from deformgl.sim.guards import SCENE_WORDING
from deformgl.sim.run import run
from deformgl.sim.integrators import IMPLICIT_INTEGRATORS
from deformgl.sim.simulation import make_simulation
from deformgl.errors import SceneError
from deformgl.scene.spec import Keyframes, Physics, Region, Scene
from deformgl.sim.materials import ElasticMaterial, LatticeReport, lattice_system, sheet_system
from deformgl.sim.springs import SpringSystem, from_grid
from deformgl.sim.scripted import Drag, Load

__all__ = ["MATERIAL_MAJORITY", "region_nodes", "xpbd_options", "layout_options", "check_layout", "SceneBox", "SceneRun", "bad_limit", "simulate_scene", "scene_constraints", "scene_drags", "scene_loads",
           "scene_system"]

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


def _fractions(grid: NodeGrid, bbox: np.ndarray) -> np.ndarray:
    return grid.bbox_fraction(grid.rest_positions, bbox[0], bbox[1])


#: a node is held by a region when at least this share of its material lies in the region
MATERIAL_MAJORITY = 0.5


def region_nodes(region: Region, grid: NodeGrid, bbox: np.ndarray) -> np.ndarray:
    """(N,) bool: the nodes a region (fractions of ``bbox``, (2, 3)) selects.

    On a grid without a fill: the nodes whose rest positions lie in the region. On a grid whose
    cells carry the mesh (:mod:`deformgl.grid.fill`) a region selects the mesh's material in it:
    each node's material is the fill's samples inside the mesh spread over their cells' corners
    with the trilinear weights, and a node is selected when at least :data:`MATERIAL_MAJORITY`
    of it lies in the region; where the region holds material but no node has that majority
    (a region thinner than a cell), the nodes with at least half the largest share are (the
    node plane next to a thin slab of material, its border nodes' partial cells included).
    A region that holds none of the mesh's material selects no node.
    """
    fill = grid.fill
    if fill is None:
        return region.contains(_fractions(grid, bbox))
    points = fill.inside_positions(grid.origin, grid.spacing)
    held = region.contains(grid.bbox_fraction(points, bbox[0], bbox[1]))
    if not held.any():
        return np.zeros(grid.count, bool)
    share = fill.node_weights(grid.index, held) / fill.node_weights(grid.index)
    nodes = share >= MATERIAL_MAJORITY
    return nodes if nodes.any() else share >= share.max() / 2.0


def _caught(region: Region, grid: NodeGrid, bbox: np.ndarray, source: str, key: str) -> np.ndarray:
    """The nodes a region selects; none is an error naming the key (a silent no-op would let
    an unfixed body fall out of the frame)."""
    nodes = region_nodes(region, grid, bbox)
    if not nodes.any():
        what = "holds none of the mesh's material" if grid.fill is not None else "catches no node of the grid"
        raise SceneError(f"{source}: {key}: the region {what} ({grid.count} nodes "
                         f"at spacing {grid.spacing:.4g}); widen it or refine the grid")
    return nodes


def scene_system(grid: NodeGrid, physics: Physics, bbox: np.ndarray, *, source: str = "scene", keys: str = "physics.",
                 report: list[LatticeReport] | None = None) -> SpringSystem:
    """The scene's spring system: with ``physics.material`` the calibrated lattice of
    :mod:`deformgl.sim.materials` (springs, masses and Rayleigh damping from the material);
    otherwise the grid's springs by class (a class of stiffness 0 is not built) and the mass
    per node. Either way the nodes of the ``[[physics.fixed]]`` regions (fractions of ``bbox``,
    (2, 3)) are fixed, and gravity and wind apply. ``report``, if given, receives the lattice's
    :class:`~deformgl.sim.materials.LatticeReport`. ``keys``: what the messages put before a
    key (a scene's table, ``"physics."``; the Python API's ``""``: its arguments are named as
    passed, ``fixed[0]``).

    Raises:
        SceneError: a fixed region that catches no node (``source: physics.fixed[i]: ...``).
    """
    if getattr(physics.material, "model", "lattice") != "lattice":  # (deformgl.scene.spline_model builds it)
        raise SceneError(f"{source}: material.model: scene_system builds the lattice, not a "
                         f"{physics.material.model!r} body")  # type: ignore[union-attr]
    fixed = np.zeros(grid.count, bool)
    for i, region in enumerate(physics.fixed):
        fixed |= _caught(region, grid, bbox, source, f"{keys}fixed[{i}]")
    material = physics.material
    if material is not None:
        build = lattice_system if isinstance(material, ElasticMaterial) else sheet_system
        system, lattice = build(grid, material, fixed=fixed, gravity=physics.gravity,  # type: ignore[arg-type]
                                wind=physics.wind, wind_drag=physics.wind_drag)
        if report is not None:
            report.append(lattice)
        return system
    k1, k2, k3 = physics.class_stiffness()
    return from_grid(grid, k_structural=k1, k_shear=k2, k_flexion=k3,
                     damping_structural=physics.structural.damping, damping_shear=physics.shear.damping,
                     damping_flexion=physics.flexion.damping, mass=physics.mass, fixed=fixed,
                     velocity_damping=physics.damping, gravity=physics.gravity, wind=physics.wind,
                     wind_drag=physics.wind_drag)


def scene_loads(grid: NodeGrid, physics: Physics, bbox: np.ndarray, *, source: str = "scene",
                mass: np.ndarray | None = None) -> tuple[Load, ...]:
    """One load per ``[[physics.pull]]`` on the nodes of its region: its force per node, or with
    a material its total force in N spread over the region's material, each node's share its
    mass over the region's (``mass``: (N,) the system's node masses in kg; a load per kilogram,
    the same pull at every grid resolution, and a node carrying a sliver of the mesh gets a
    sliver of it).

    Raises:
        SceneError: a pull region that catches no node.
    """
    if physics.material is not None and physics.pull and mass is None:
        raise TypeError("scene_loads: a material scene's pulls need the node masses (mass=)")
    loads = []
    for i, pull in enumerate(physics.pull):
        nodes = _caught(pull.region, grid, bbox, source, f"physics.pull[{i}]")
        if physics.material is None:
            loads.append(Load(nodes, pull.force_at))
        else:
            loads.append(Load(nodes, _per_kg(pull.force_at, float(np.sum(np.asarray(mass)[nodes]))), per_kg=True))
    return tuple(loads)


def _per_kg(total: Callable[[float], np.ndarray], mass: float) -> Callable[[float], np.ndarray]:
    """t -> the total force in N over ``mass`` kg, N/kg."""
    return lambda t: np.asarray(total(t), dtype=np.float64) / mass


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
    """What a run produced: final positions (N, 3) float64 (None when the simulation is kept),
    steps taken (of dt / substeps),
    whether the convergence stop ended it (None without one), GPU bytes per node (0 for numpy),
    the end time, the substeps per scene step, and (``simulate_scene(keep=True)``) the simulation
    itself, which the caller then releases."""

    positions: np.ndarray | None
    steps: int
    converged: bool | None
    bytes_per_node: float
    time: float
    substeps: int = 1
    sim: Any = None
    #: the convergence stop's last measures (None without one)
    convergence: str | None = None
    #: the inversion census at the end (None: a body without cells); its phrase ("" if none)
    inverted_cells: int | None = None
    inverted: str = ""
    #: an implicit integrator's linear solves (:attr:`deformgl.sim.run.RunResult.solver`)
    solver: dict | None = None
    #: on request (``simulate_scene(velocities=True)``) and when the simulation is not kept: the final
    #: velocities (N, 3) float64 in m/s and the simulation's step in s (for exported fields)
    velocities: np.ndarray | None = None
    sim_dt: float = 0.0

    def summary(self, physics: Physics) -> str:
        """One line for the log."""
        line = f"{physics.integrator} on the {physics.backend} backend: {self.steps} steps"
        if self.substeps > 1:
            line += f" ({self.substeps} substeps per scene step)"
        if self.converged is not None:
            line += " (converged" if self.converged else " (step limit reached before convergence"
            line += f": {self.convergence})" if self.convergence else ")"
        if self.bytes_per_node:
            line += f", {self.bytes_per_node:.0f} GPU bytes per node"
        if self.inverted:
            line += f"; at the end {self.inverted}"
        return line


def scripted_until(physics: Physics) -> float:
    """The simulated time (s) of the scene's last scripted change: the last keyframe of a drag or
    a moving sphere, a pull's start, end of ramp or (finite) stop; the convergence stop waits
    for it (a body at rest before a pull starts has not converged)."""
    times = [0.0]
    times += [d.path.times[-1] for d in physics.drag]
    times += [s.path.times[-1] for s in physics.sphere if s.path is not None]
    for pull in physics.pull:
        times += [pull.start + pull.ramp] + ([pull.stop] if math.isfinite(pull.stop) else [])
    return max(times)


def bad_limit(physics: Physics, box: SceneBox) -> float:
    """World distance from the (recentred) box centre beyond which a node counts as blown up."""
    return physics.safety.bad_distance * box.longest


def simulate_scene(ctx: moderngl.Context, scene: Scene, grid: NodeGrid, system: SpringSystem,
              loads: tuple[Load, ...], box: SceneBox, *, progress: bool, plan: StepPlan | None = None,
              notes: list[str] | None = None, keep: bool = False, frame_every: int = 0,
              on_frame: Callable[[int, Any], None] | None = None, velocities: bool = False) -> SceneRun:
    """Simulate a scene's nodes with its integrator on its backend through the one run
    (:func:`deformgl.sim.run.run`: dt check, blow-up census, convergence stop, subdivision);
    positions are read once.

    Args:
        system, loads: the scene's :func:`scene_system` and :func:`scene_loads`.
        plan: the checked step plan (default: :func:`~deformgl.sim.guards.plan_steps` of the
            scene, which refuses a dt above the limit unless ``physics.safety.unstable`` says
            otherwise).
        notes: receives what the plan and the restarts changed, if given.
        keep: when the simulation's state texture carries the packed node normals (the fragment
            backend's Verlet fast path), return it in :attr:`SceneRun.sim` for drawing, unreleased
            and unread (``positions`` None); otherwise it is read once and released.
        frame_every, on_frame: ``on_frame(step, sim)`` at step 0 and every ``frame_every`` scene
            steps (:func:`deformgl.sim.run.run`): where an animation draws its frames.
    """
    physics = scene.physics
    drags = scene_drags(grid, physics, box)
    constraints = scene_constraints(physics, box)
    check_layout(ctx, scene, system, grid, loads, drags, constraints)
    made: list = []

    def make(dt: float):
        while made:  # a restart starts from the start state: the blown-up attempt is done with
            made.pop().release()
        extra = physics.implicit.options() if physics.integrator in IMPLICIT_INTEGRATORS else {}
        made.append(make_simulation(system, physics.integrator, physics.backend, dt=dt, ctx=ctx, grid=grid,
                                    constraints=constraints, drags=drags, loads=loads, **extra,
                                    **xpbd_options(physics), **layout_options(physics)))
        return made[-1]

    try:
        # every run ends with a blow-up check (census or NumPy), so its positions are finite
        result = run(make, settings=physics, system=system, source=scene.source, limit=bad_limit(physics, box),
                     check_every=physics.safety.check_every, ctx=ctx, grid=grid, converge=physics.converge,
                     loads=loads, drags=drags, hold_until=scripted_until(physics), progress=progress, plan=plan,
                     notes=notes, wording=SCENE_WORDING, frame_every=frame_every, on_frame=on_frame)
        sim = made[-1]
        # a kept simulation is drawn from its state texture: nothing is read back
        kept = keep and bool(getattr(sim, "packed_normals", False))
        positions = None if kept else np.asarray(sim.positions(), np.float64)
        step_dt = result.dt if result.dt is not None else physics.dt
        out = SceneRun(positions, result.steps, result.converged, sim.bytes_per_node, result.steps * step_dt,
                       result.substeps, sim if kept else None, result.convergence, result.inverted_cells,
                       result.inverted, result.solver)
        if velocities and not kept:
            out.velocities, out.sim_dt = np.asarray(sim.velocities(), np.float64), float(sim.dt)
        if kept:
            made.clear()
        return out
    finally:
        for sim in made:
            sim.release()


def xpbd_options(physics) -> dict[str, int]:
    """``iterations`` and ``substeps`` of ``[physics.xpbd]`` for make_simulation (XPBD only)."""
    if physics.integrator != "xpbd":
        return {}
    x = physics.xpbd
    return {} if x is None else {"iterations": x.iterations, "substeps": x.substeps}


def check_layout(ctx, scene: Scene, system: SpringSystem, grid: NodeGrid, loads, drags, constraints) -> None:
    """A block forced by ``[physics] layout`` runs on the foundation's Verlet pass, on this
    renderer: a SceneError naming the key and what the pass does not model, or what the renderer
    lacks, before anything runs."""
    if scene.physics.layout in ("auto", "compact"):
        return
    from deformgl.sim.backends.blocked import blocked_refusal
    from deformgl.sim.backends.verlet_data import verlet_terms

    if ctx is not None:
        lacks = blocked_refusal(ctx.info, parse_block(scene.physics.layout))
        if lacks is not None:
            raise SceneError(f"{scene.source}: physics.layout: {scene.physics.layout!r}: {lacks}; use \"auto\"")

    terms = verlet_terms(system, grid, loads=loads, drags=drags, constraints=constraints)
    if isinstance(terms, str):
        raise SceneError(f"{scene.source}: physics.layout: {scene.physics.layout!r} (several nodes per fragment) runs "
                         f"on the foundation's Verlet pass, which does not model {terms}; use \"auto\" or \"compact\"")


def layout_options(physics) -> dict:
    """``layout`` or ``block`` of ``[physics] layout`` for make_simulation (nothing for "auto")."""
    if physics.layout == "auto":
        return {}
    if physics.layout == "compact":
        return {"layout": "compact"}
    return {"block": parse_block(physics.layout)}
