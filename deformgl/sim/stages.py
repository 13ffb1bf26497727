"""The five integrators described once: their stages, what each stage reads and writes, the GPU
state per node and the undamped stability limit factor (``dt <= factor / w_max``).

Movania & Feng 2012 compare explicit Euler (eq. 4-5), semi-implicit Euler (eq. 7), midpoint,
RK4 and position Verlet (eq. 6); the buffers are those of
:data:`deformgl.sim.integrators.GPU_BUFFERS` (ping-pong: no stage reads what it writes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from deformgl.sim.integrators import GPU_BUFFERS, INTEGRATORS, VEC4_BYTES

__all__ = ["Stage", "IntegratorSpec", "SPECS", "spec"]


@dataclass(frozen=True)
class Stage:
    """One pass of a step.

    Attributes:
        name: the stage.
        reads: the per-node buffers it samples.
        writes: the per-node buffers it renders / captures.
        time: stage time as a fraction of dt after the step's start.
    """

    name: str
    reads: tuple[str, ...]
    writes: tuple[str, ...]
    time: float = 0.0


@dataclass(frozen=True)
class IntegratorSpec:
    """An integrator: its stages in order and what it costs.

    Attributes:
        name: one of :data:`~deformgl.sim.integrators.INTEGRATORS`.
        stages: the passes of one step.
        buffers: the per-node vec4 buffers alive during a step.
        velocity: whether velocity is state (False: Verlet's backward difference).
        limit_factor: undamped ``dt <= limit_factor / w_max``; None: unstable without damping.
    """

    name: str
    stages: tuple[Stage, ...]
    buffers: tuple[str, ...]
    velocity: bool
    limit_factor: float | None

    @property
    def bytes_per_node(self) -> int:
        """GPU state bytes per node (``integrators.memory_per_node``)."""
        return VEC4_BYTES * len(self.buffers)


_XV = ("x", "v")
SPECS: dict[str, IntegratorSpec] = {
    "euler": IntegratorSpec("euler", (Stage("step", _XV, ("x_out", "v_out")),),
                            GPU_BUFFERS["euler"], True, None),
    "semi-implicit": IntegratorSpec("semi-implicit", (Stage("step", _XV, ("x_out", "v_out")),),
                                    GPU_BUFFERS["semi-implicit"], True, 2.0),
    "midpoint": IntegratorSpec("midpoint", (Stage("half", _XV, ("x_mid", "v_mid")),
                                            Stage("full", _XV + ("x_mid", "v_mid"), ("x_out", "v_out"), 0.5)),
                               GPU_BUFFERS["midpoint"], True, None),
    "rk4": IntegratorSpec("rk4", (
        Stage("k1", _XV, ("x_stage_a", "v_stage_a", "sum_x_a", "sum_v_a")),
        Stage("k2", _XV + ("x_stage_a", "v_stage_a", "sum_x_a", "sum_v_a"),
              ("x_stage_b", "v_stage_b", "sum_x_b", "sum_v_b"), 0.5),
        Stage("k3", _XV + ("x_stage_b", "v_stage_b", "sum_x_b", "sum_v_b"),
              ("x_stage_a", "v_stage_a", "sum_x_a", "sum_v_a"), 0.5),
        Stage("k4", _XV + ("x_stage_a", "v_stage_a", "sum_x_a", "sum_v_a"), ("x_stage_b", "v_stage_b"), 1.0)),
        GPU_BUFFERS["rk4"], True, 2.0 * math.sqrt(2.0)),
    "verlet": IntegratorSpec("verlet", (Stage("step", ("x", "x_prev"), ("x_out",)),),
                             GPU_BUFFERS["verlet"], False, 2.0),
}
assert tuple(SPECS) == INTEGRATORS


def spec(name: str) -> IntegratorSpec:
    """The :class:`IntegratorSpec` of ``name``; ValueError names the known ones."""
    try:
        return SPECS[name]
    except KeyError:
        raise ValueError(f"unknown integrator {name!r}; expected one of {', '.join(INTEGRATORS)}") from None
