"""Guards of a scene run: the dt against the integrator's stability limit before the run, and
a GPU census of blown-up nodes during it.

Before the run (:func:`plan_steps`), the scene's dt is checked against the limit of its
integrator on its spring system (:func:`deformgl.sim.limits.check_dt`: the Gershgorin bound
``w_max^2 <= max_i 2 sum_j k_ij / m_i``, the exact spectrum on small systems). Above it the
scene is refused with the bound and the node and spring that set it, unless
``physics.safety.unstable`` (``--allow-unstable``, ``--subdivide``) says to run it anyway or to
split every step into enough substeps to be below the limit. The messages name the settings the
way the caller's user sets them (:class:`Wording`): a scene's keys and the CLI's flags
(:data:`SCENE_WORDING`, the default), or the Python API's arguments (:data:`API_WORDING`).

During the run (:class:`BlowUpWatch`), every ``check_every`` steps a census pass
(:mod:`deformgl.sim.census`) counts the nodes whose position is NaN, +-Inf or farther than
``bad_distance`` box lengths from the box centre; only that count crosses to the CPU. A non-zero
count stops the run with :class:`BlowUp` (the step, a node, how many); on that error path the
state is read back once to name the node. With ``subdivide`` the run is restarted from the start
with half the step (twice the steps, the same simulated time), up to ``MAX_SUBSTEPS`` substeps
per scene step (:func:`retry_with_substeps`, under the one run :func:`deformgl.sim.run.run`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, TypeVar

import moderngl
import numpy as np

from deformgl.sim.materials import ElasticMaterial
from deformgl.errors import RefusedStepError, SimulationError
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.springs import SpringSystem
from deformgl.sim.limits import check_dt

__all__ = ["API_WORDING", "MAX_SUBSTEPS", "SAFETY_MARGIN", "SCENE_WORDING", "BlowUp", "BlowUpWatch", "StepPlan",
           "StepSettings", "UNSTABLE_POLICIES", "Watch", "Wording", "bad_nodes", "describe_bad_node", "plan_steps", "retry_with_substeps"]

T = TypeVar("T")

#: What a run does with a dt above the integrator's stability limit (``physics.safety.unstable``,
#: ``run(..., unstable=)``): refuse it, run it anyway, or split each step into substeps (and
#: restart after a blow-up with twice as many).
UNSTABLE_POLICIES = ("refuse", "run", "subdivide")
#: The most substeps per scene step that ``subdivide`` uses (before the run and after a blow-up).
MAX_SUBSTEPS = 16
#: ``subdivide`` aims at this fraction of the limit (the limit itself is marginally stable).
SAFETY_MARGIN = 0.9


@dataclass(frozen=True)
class StepPlan:
    """How a scene's steps are run: ``substeps`` steps of ``dt / substeps`` per scene step.

    Attributes:
        dt: the scene's dt (s); steps: the scene's step count.
        substeps: >= 1.
        note: what the plan changed or accepted, for the log ("" when nothing).
    """

    dt: float
    steps: int
    substeps: int = 1
    note: str = ""

    @property
    def step_dt(self) -> float:
        """The dt each GPU step uses (s)."""
        return self.dt / self.substeps

    @property
    def step_count(self) -> int:
        """GPU steps in all."""
        return self.steps * self.substeps

    def halved(self) -> StepPlan | None:
        """The plan with twice the substeps (at most :data:`MAX_SUBSTEPS`), None when it already
        has that many."""
        if self.substeps >= MAX_SUBSTEPS:
            return None
        k = min(2 * self.substeps, MAX_SUBSTEPS)
        return StepPlan(self.dt, self.steps, k, f"restarted with {k} substeps per step (dt {self.dt / k:.4g} s)")


@dataclass(frozen=True)
class Wording:
    """How the guards' messages name the dt and the ``unstable`` policy, so that a user reads the
    names they set them by.

    Attributes:
        where: what follows ``"<source>: "`` in a dt refusal ("physics.dt: " names the scene key;
            "" when the message itself is enough).
        dt: the dt's name in "reduce <dt>".
        run_anyway: how to run an unstable dt anyway.
        subdivide: how to ask for substeps.
        policy: the setting behind both, in parentheses after them ("" for none).
        cap: the substep cap, as "more than <cap>" says it.
    """

    where: str
    dt: str
    run_anyway: str
    subdivide: str
    policy: str
    cap: str


#: A scene file and the CLI: ``[physics] dt``, ``physics.safety.unstable``, ``--subdivide``.
SCENE_WORDING = Wording(where="physics.dt: ", dt="physics.dt", run_anyway="--allow-unstable",
                        subdivide="--subdivide", policy="physics.safety.unstable",
                        cap=f"--subdivide's {MAX_SUBSTEPS}")
#: The Python API (:func:`deformgl.run`): ``dt=``, ``unstable="run"``, ``unstable="subdivide"``.
API_WORDING = Wording(where="", dt="dt", run_anyway='unstable="run"', subdivide='unstable="subdivide"',
                      policy="", cap=f'the {MAX_SUBSTEPS} that unstable="subdivide" uses')


class _Policy(Protocol):
    @property
    def unstable(self) -> str: ...


class StepSettings(Protocol):
    """What :func:`plan_steps` reads of a run's settings (a scene's ``Physics`` is one): the step
    ``dt`` (s), the step count, the integrator's name and ``safety.unstable`` (``"refuse"``,
    ``"run"`` or ``"subdivide"``). How the messages name them comes with the call
    (``plan_steps(..., wording=...)``, :class:`Wording`): a scene's keys by default."""

    @property
    def dt(self) -> float: ...
    @property
    def steps(self) -> int: ...
    @property
    def integrator(self) -> str: ...
    @property
    def safety(self) -> _Policy: ...


def plan_steps(system: SpringSystem, physics: StepSettings, source, *,
               wording: Wording = SCENE_WORDING) -> StepPlan:
    """Check ``physics.dt`` against the limit of ``physics.integrator`` on ``system``.

    Args:
        wording: how the messages name the dt and the policy (:data:`SCENE_WORDING`: the scene
            keys and CLI flags; :data:`API_WORDING`: the arguments of :func:`deformgl.run`).

    Raises:
        SimulationError: ``"<file>: physics.dt: dt ... is above the verlet limit ... set by node
            N (spring S, k = ..., m = ...)"`` when the dt is above the limit and
            ``physics.safety.unstable`` is "refuse" (with :data:`API_WORDING`: ``"<source>: dt
            ... Pass unstable="run" ..."``).
    """
    dt, policy, w = physics.dt, physics.safety.unstable, wording
    refusal = check_dt(system, physics.integrator, dt)
    if refusal is None:
        return StepPlan(dt, physics.steps)
    where = f"{source}: {w.where}{refusal.message}{material_terms(system, getattr(physics, 'material', None) or system.material, refusal.limit.dt)}"
    if policy == "refuse":
        hint = ""
        if refusal.limit.bound == "gershgorin":
            hint = (" (a conservative bound, used above 30,000 free nodes: the exact limit of a volume "
                    "can be up to twice it; running anyway keeps the blow-up census watching)")
        setting = f" ({w.policy})" if w.policy else ""
        raise RefusedStepError(f"{where}{hint}. Lower it, or pass {w.subdivide} to split each step or "
                              f"{w.run_anyway} to run it anyway{setting}")
    if policy == "run":
        return StepPlan(dt, physics.steps, 1, f"running anyway: {refusal.message}")
    limit = refusal.limit.dt
    if limit <= 0.0:
        raise RefusedStepError(f"{where}; no substep is stable, so {w.subdivide} cannot help")
    substeps = max(1, math.ceil(dt / (SAFETY_MARGIN * limit)))
    if substeps > MAX_SUBSTEPS:
        raise RefusedStepError(f"{where}; it needs {substeps} substeps per step, more than {w.cap}: "
                              f"reduce {w.dt}")
    return StepPlan(dt, physics.steps, substeps,
                    f"dt {dt:.4g} s is above the {physics.integrator} limit {limit:.4g} s: "
                    f"{substeps} substeps of {dt / substeps:.4g} s per step")


def retry_with_substeps(plan: StepPlan, policy: str, attempt: Callable[[StepPlan], T], notes: list[str], *,
                        wording: Wording = SCENE_WORDING, retries: int | None = None) -> tuple[T, StepPlan]:
    """The retry policy of a run: ``attempt(plan)``; a :class:`BlowUp` restarts it with twice the
    substeps (up to :data:`MAX_SUBSTEPS`), each restart noted in ``notes``, at most ``retries``
    times (None: as many as the cap allows under "subdivide", none under any other policy).
    Returns what the last attempt returned and its plan.

    Raises:
        BlowUp: a blow-up once the restarts allowed are used.
        SimulationError: a blow-up at :data:`MAX_SUBSTEPS` substeps.
    """
    left = (MAX_SUBSTEPS if policy == "subdivide" else 0) if retries is None else retries
    while True:
        try:
            return attempt(plan), plan
        except BlowUp as exc:
            if left <= 0:
                raise
            left -= 1
            finer = plan.halved()
            if finer is None:
                raise SimulationError(f"{exc} (still at {plan.substeps} substeps per step, the most "
                                      f"{wording.subdivide} uses)") from None
            notes.append(f"{exc}; {finer.note}")
            plan = finer


def material_terms(system: SpringSystem, material: object, limit: float) -> str:
    """The dt limit in a material's terms, for the refusal: ``limit`` (s) as a multiple of
    ``h sqrt(rho / E)``, the scale it falls with (:func:`deformgl.sim.materials.critical_dt`);
    empty without an elastic material."""
    if not isinstance(material, ElasticMaterial):
        return ""
    h = system.spacing
    scale = h * math.sqrt(material.density / material.youngs_modulus)
    return (f"; it is {limit / scale:.3g} h sqrt(rho/E) (h = {h:.4g} m, E = {material.youngs_modulus:.4g} Pa, "
            f"rho = {material.density:.4g} kg/m^3)")


class BlowUp(SimulationError):
    """Nodes went non-finite or far away: ``step`` (the check that saw it), ``count``, and the
    message naming a node."""

    def __init__(self, message: str, step: int, count: int) -> None:
        super().__init__(message)
        self.step = step
        self.count = count

    @classmethod
    def at(cls, source, step: int, dt: float, count: int, node: str, limit: float,
           last_clean: int | None, wording: Wording = SCENE_WORDING) -> BlowUp:
        """The error of a check at ``step`` that found ``count`` bad nodes, ``node`` the first
        (:func:`describe_bad_node`); ``last_clean``: the step of the last check that found none;
        ``wording``: how the advice names the dt and the subdivision."""
        last = f"; none at step {last_clean}" if last_clean is not None else ""
        return cls(f"{source}: simulation blew up: at step {step} (dt {dt:.4g} s{last}) {count} node(s) are "
                   f"non-finite or beyond {limit:.4g} from the centre, first {node}; reduce {wording.dt} or "
                   f"stiffness, or pass {wording.subdivide}", step, count)


def bad_nodes(positions: np.ndarray, limit: float) -> np.ndarray:
    """(N,) bool: the nodes of ``positions`` (N, 3+) with a non-finite coordinate or one beyond
    ``limit`` (what the census's BAD pass counts on the GPU)."""
    xyz = np.asarray(positions, np.float64)[:, :3]
    with np.errstate(invalid="ignore"):
        # (asarray: the same array; NumPy's stubs type ``~`` and ``|`` of arrays as bool | array)
        return np.asarray(~np.isfinite(xyz).all(axis=1) | (np.abs(xyz) > limit).any(axis=1))


def describe_bad_node(positions: np.ndarray, grid: NodeGrid | None, limit: float) -> str:
    """``"node 17 (grid (1, 2, 0)) at (nan, 0, 1)"`` for the first node of ``positions`` (N, 3+)
    that is non-finite or has a component beyond ``limit``; "" when there is none."""
    xyz = np.asarray(positions, np.float64)[:, :3]
    bad = bad_nodes(xyz, limit)
    if not bad.any():
        return ""
    i = int(np.argmax(bad))
    where = f" (grid {tuple(int(v) for v in grid.ijk[i])})" if grid is not None else ""
    return f"node {i}{where} at ({', '.join(f'{v:.4g}' for v in xyz[i])})"


class Watch:
    """The blow-up check of a run, every ``every`` steps and once at the end: the schedule, the
    count and the :class:`BlowUp` message. Subclasses count the bad nodes (:meth:`count_bad`).

    Args:
        sim: the simulation (``positions()``, ``count``).
        every: steps between checks (0: only when :meth:`check` is called at the end).
        limit: a node with a coordinate beyond this (world units) counts as blown up.
        grid: names the bad node's grid index in the message, if given.
        source: the scene file, for the message.
        dt: the step, for the message.
        wording: how the message's advice names the dt and the subdivision.
    """

    #: the class default, so a watch built without ``__init__`` words its message for a scene
    wording: Wording = SCENE_WORDING

    def __init__(self, sim, *, every: int, limit: float, grid: NodeGrid | None, source, dt: float,
                 wording: Wording = SCENE_WORDING) -> None:
        self.sim, self.every, self.limit, self.grid, self.source, self.dt = sim, every, limit, grid, source, dt
        self.wording = wording
        self.last_clean: int | None = None  # step of the last check that found nothing

    def due(self, done: int) -> bool:
        """Whether a check falls at ``done`` steps."""
        return self.every > 0 and done % self.every == 0

    def next_stop(self, done: int, total: int) -> int:
        """The step count of the next check after ``done`` (``total`` if none before it)."""
        if self.every <= 0:
            return total
        return min(total, (done // self.every + 1) * self.every)

    def count_bad(self) -> int:
        """How many nodes are non-finite or beyond :attr:`limit` now."""
        return int(bad_nodes(self.sim.positions(), self.limit).sum())

    def check(self, done: int) -> None:
        """Count the bad nodes after ``done`` steps; raise :class:`BlowUp` if there are any."""
        count = self.count_bad()
        if count == 0:
            self.last_clean = done
            return
        node = describe_bad_node(self.sim.positions(), self.grid, self.limit)
        raise BlowUp.at(self.source, done, self.dt, count, node, self.limit, self.last_clean, self.wording)

    def release(self) -> None:
        """Release what the count holds (nothing here)."""


class BlowUpWatch(Watch):
    """:class:`Watch` of a GPU simulation: one census query per check, nothing read back unless
    nodes went bad. The simulation must have ``position_slot() -> (texture, row, slots, slot)``.

    Args:
        ctx: the GL context; the other arguments as :class:`Watch`.
    """

    def __init__(self, ctx: moderngl.Context, sim, *, every: int, limit: float, grid: NodeGrid | None,
                 source, dt: float, wording: Wording = SCENE_WORDING) -> None:
        from deformgl.sim.census import NodeCensus

        super().__init__(sim, every=every, limit=limit, grid=grid, source=source, dt=dt, wording=wording)
        _, row, slots, _ = sim.position_slot()
        self.census = NodeCensus(ctx, count=sim.count, row=row, slots=slots)

    def count_bad(self) -> int:
        texture, _, _, slot = self.sim.position_slot()
        return self.census.bad(texture, self.limit, slot=slot)

    def release(self) -> None:
        """Release the census."""
        self.census.release()
