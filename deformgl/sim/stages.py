"""The five integrators described once: their stages, what each stage reads and writes, the
shader variant of each stage on both GPU backends, how the buffers change roles after a step, the
GPU state per node and the undamped stability limit factor (``dt <= factor / w_max``).

Movania & Feng 2012 compare explicit Euler (Movania & Feng 2012, eq. 4-5), semi-implicit Euler
(Movania & Feng 2012, eq. 7), midpoint, RK4 and position Verlet (Movania & Feng 2012, eq. 6); the
buffers are those of :data:`deformgl.sim.integrators.GPU_BUFFERS` (ping-pong: no stage reads what
it writes).

Both backends build their passes from this table (:mod:`deformgl.sim.backends.explicit_gpu`,
:mod:`deformgl.sim.backends.feedback`): a pass per :class:`Stage`, in order, at its stage time;
its shader switches are the stage's :attr:`Stage.defines` plus what follows from what it reads and
writes (:meth:`Stage.derived_defines`: ``EVAL_STAGE``, ``READ_SUMS``, ``WRITE_SUMS``) and, for the
whole integrator, ``VELOCITY`` when velocity is state (:attr:`IntegratorSpec.velocity`).
Constraints (ground, spheres) apply in the final stage only. After a step the buffers change roles
as :attr:`IntegratorSpec.rotation` says.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from deformgl.sim.integrators import EXPLICIT_INTEGRATORS, GPU_BUFFERS, VEC4_BYTES

__all__ = ["Stage", "IntegratorSpec", "SPECS", "BUFFERS", "spec"]

#: What each per-node buffer holds: ``(kind, quantity)``. kind: "state" (a step starts from it),
#: "stage" (an intermediate state at which a later stage evaluates the forces), "sum" (RK4's
#: running sum of the weighted stage slopes), "out" (the next state); quantity: "x", "v" or
#: "x_prev". A pass that writes several buffers writes them in the order x, v, sum_x, sum_v (the
#: output locations of ``shaders/sim/integrators/step.frag``).
BUFFERS: dict[str, tuple[str, str]] = {
    "x": ("state", "x"), "v": ("state", "v"), "x_prev": ("state", "x_prev"),
    "x_out": ("out", "x"), "v_out": ("out", "v"),
    "x_mid": ("stage", "x"), "v_mid": ("stage", "v"),
    "x_stage_a": ("stage", "x"), "v_stage_a": ("stage", "v"),
    "x_stage_b": ("stage", "x"), "v_stage_b": ("stage", "v"),
    "sum_x_a": ("sum", "x"), "sum_v_a": ("sum", "v"),
    "sum_x_b": ("sum", "x"), "sum_v_b": ("sum", "v"),
}

#: A shader switch: (name, value); True gives a bare ``#define``.
Define = tuple[str, int]


@dataclass(frozen=True)
class Stage:
    """One pass of a step.

    Attributes:
        name: the stage, also the backends' pass key (the final stage is "step").
        reads: the per-node buffers it samples.
        writes: the per-node buffers it renders / captures (order: x, v, sum_x, sum_v).
        time: stage time as a fraction of dt after the step's start (loads and drag targets are
            evaluated there).
        defines: the method switches of ``shaders/sim/integrators/step.frag`` (fragment
            backend), e.g. ``(("RK4_STAGE", 2),)``; the derived ones are not listed here.
        vertex: the transform-feedback vertex shader of the stage (under ``shaders/``).
        vertex_defines: which of ``defines`` the vertex shader takes too (the others are implied
            by the file).
        final: the last stage of the step: constraints (ground, spheres) apply here.
    """

    name: str
    reads: tuple[str, ...]
    writes: tuple[str, ...]
    time: float = 0.0
    defines: tuple[Define, ...] = ()
    vertex: str = ""
    vertex_defines: tuple[str, ...] = ()
    final: bool = False

    def at(self, t: float, dt: float) -> float:
        """The stage's time in a step of dt from t (exactly t for a stage at its start)."""
        return t if self.time == 0.0 else t + self.time * dt

    def _reads_kind(self, kind: str) -> bool:
        return any(BUFFERS[b][0] == kind for b in self.reads)

    @property
    def eval_stage(self) -> bool:
        """Forces are evaluated at a stage state (the stage reads a "stage" buffer)."""
        return self._reads_kind("stage")

    @property
    def read_sums(self) -> bool:
        """The stage reads RK4's running sums."""
        return self._reads_kind("sum")

    @property
    def write_sums(self) -> bool:
        """The stage writes RK4's running sums."""
        return any(BUFFERS[b][0] == "sum" for b in self.writes)

    def derived_defines(self) -> dict[str, object]:
        """The fragment switches that follow from reads and writes (only those that are set)."""
        flags = {"EVAL_STAGE": self.eval_stage, "READ_SUMS": self.read_sums,
                 "WRITE_SUMS": self.write_sums}
        return {k: True for k, on in flags.items() if on}

    def fragment_defines(self) -> dict[str, object]:
        """The stage's switches of ``step.frag``: its method defines and the derived ones."""
        return {**dict(self.defines), **self.derived_defines()}

    def feedback_defines(self) -> dict[str, object]:
        """The stage's switches of its transform-feedback vertex shader."""
        return {k: v for k, v in self.defines if k in self.vertex_defines}


@dataclass(frozen=True)
class IntegratorSpec:
    """An integrator: its stages in order and what it costs.

    Attributes:
        name: one of :data:`~deformgl.sim.integrators.EXPLICIT_INTEGRATORS`.
        stages: the passes of one step.
        buffers: the per-node vec4 buffers alive during a step.
        velocity: whether velocity is state (False: Verlet's backward difference).
        limit_factor: undamped ``dt <= limit_factor / w_max``; None: unstable without damping.
        rotation: after a step, ``(new_role, old_role)`` for each buffer whose role changes: the
            buffer that played ``old_role`` during the step plays ``new_role`` in the next one
            (a permutation of ``buffers``; roles not listed keep their buffer).
    """

    name: str
    stages: tuple[Stage, ...]
    buffers: tuple[str, ...]
    velocity: bool
    limit_factor: float | None
    rotation: tuple[tuple[str, str], ...] = ()

    def __post_init__(self) -> None:
        known = set(self.buffers)
        for stage in self.stages:
            unknown = (set(stage.reads) | set(stage.writes)) - known
            if unknown:
                raise ValueError(f"{self.name} {stage.name}: buffers {sorted(unknown)} not in {self.buffers}")
        if [s.final for s in self.stages] != [False] * (len(self.stages) - 1) + [True]:
            raise ValueError(f"{self.name}: exactly the last stage must be final")
        new, old = [n for n, _ in self.rotation], [o for _, o in self.rotation]
        if sorted(new) != sorted(old) or len(set(new)) != len(new) or not set(new) <= known:
            raise ValueError(f"{self.name}: rotation {self.rotation} is not a permutation of buffers")

    @property
    def bytes_per_node(self) -> int:
        """GPU state bytes per node (``integrators.memory_per_node``)."""
        return VEC4_BYTES * len(self.buffers)

    @property
    def state(self) -> tuple[str, ...]:
        """The buffers a step starts from (x, v; Verlet x, x_prev), in ``buffers`` order."""
        return tuple(b for b in self.buffers if BUFFERS[b][0] == "state")

    @property
    def final(self) -> Stage:
        """The last stage (constraints apply there)."""
        return self.stages[-1]

    def before(self, role: str) -> str:
        """The role whose buffer plays ``role`` after a step (``role`` itself if unchanged)."""
        return dict(self.rotation).get(role, role)

    def rotate(self, roles: list[int]) -> list[int]:
        """Roles after a step: ``roles[i]`` is what plays ``buffers[i]`` (a pool index)."""
        index = {b: i for i, b in enumerate(self.buffers)}
        return [roles[index[self.before(b)]] for b in self.buffers]

    @property
    def limit_formula(self) -> str | None:
        """The undamped limit as written in messages, e.g. "2/w", "2.83/w"; None if unstable."""
        return None if self.limit_factor is None else f"{self.limit_factor:.3g}/w"


_XV = ("x", "v")
_OUT = ("x_out", "v_out")
_SWAP_OUT = (("x", "x_out"), ("v", "v_out"), ("x_out", "x"), ("v_out", "v"))
_A = ("x_stage_a", "v_stage_a", "sum_x_a", "sum_v_a")
_B = ("x_stage_b", "v_stage_b", "sum_x_b", "sum_v_b")
_RK4 = "feedback/rk4_stage.vert"

SPECS: dict[str, IntegratorSpec] = {
    "euler": IntegratorSpec(
        "euler",
        (Stage("step", _XV, _OUT, defines=(("EULER", True),), vertex="feedback/euler.vert",
               final=True),),
        GPU_BUFFERS["euler"], True, None, _SWAP_OUT),
    "semi-implicit": IntegratorSpec(
        "semi-implicit",
        (Stage("step", _XV, _OUT, defines=(("SEMI_IMPLICIT", True),),
               vertex="feedback/euler.vert", vertex_defines=("SEMI_IMPLICIT",), final=True),),
        GPU_BUFFERS["semi-implicit"], True, 2.0, _SWAP_OUT),
    "midpoint": IntegratorSpec(
        "midpoint",
        (Stage("half", _XV, ("x_mid", "v_mid"), defines=(("MIDPOINT_HALF", True),),
               vertex="feedback/midpoint_half.vert"),
         Stage("step", _XV + ("x_mid", "v_mid"), _OUT, 0.5, defines=(("MIDPOINT_FULL", True),),
               vertex="feedback/midpoint_full.vert", final=True)),
        GPU_BUFFERS["midpoint"], True, None, _SWAP_OUT),
    "rk4": IntegratorSpec(
        "rk4",
        (Stage("stage1", _XV, _A, defines=(("RK4_STAGE", 1),), vertex=_RK4,
               vertex_defines=("RK4_STAGE",)),
         Stage("stage2", _XV + _A, _B, 0.5, defines=(("RK4_STAGE", 2),), vertex=_RK4,
               vertex_defines=("RK4_STAGE",)),
         Stage("stage3", _XV + _B, _A, 0.5, defines=(("RK4_STAGE", 3),), vertex=_RK4,
               vertex_defines=("RK4_STAGE",)),
         Stage("step", _XV + _A, _B[:2], 1.0, defines=(("RK4_FINAL", True),),
               vertex="feedback/rk4_final.vert", final=True)),
        # the result (in stage set b) becomes x, v; the old x, v take its place
        GPU_BUFFERS["rk4"], True, 2.0 * math.sqrt(2.0),
        (("x", "x_stage_b"), ("v", "v_stage_b"), ("x_stage_b", "x"), ("v_stage_b", "v"))),
    "verlet": IntegratorSpec(
        "verlet",
        (Stage("step", ("x", "x_prev"), ("x_out",), defines=(("VERLET", True),),
               vertex="feedback/verlet.vert", final=True),),
        # x' becomes x, x becomes x_prev, the old x_prev is written next
        GPU_BUFFERS["verlet"], False, 2.0,
        (("x", "x_out"), ("x_prev", "x"), ("x_out", "x_prev"))),
}
assert tuple(SPECS) == EXPLICIT_INTEGRATORS


def spec(name: str) -> IntegratorSpec:
    """The :class:`IntegratorSpec` of ``name``; ValueError names the known ones."""
    try:
        return SPECS[name]
    except KeyError:
        raise ValueError(f"unknown integrator {name!r}; expected one of {', '.join(EXPLICIT_INTEGRATORS)}") from None
