"""What every simulation backend shares on top of its own ``step``: the simulated time, and
``with`` support (release on exit). See :class:`deformgl.sim.simulation.Simulation`."""

from __future__ import annotations

from typing import Any

import numpy as np


class SimulationBase:
    """Mixin: the clock (time is ``t0 + steps * dt``, never accumulated: ``t += dt`` rounds, and
    a load that switches on at a step's time then fires a step early), ``time``, and ``with``
    releases on exit.

    Attributes:
        dt: step in s; t0: time of the start state; steps_done: steps taken; t: current time.
    """

    t: float
    t0: float
    dt: float
    steps_done: int

    def _start_clock(self, dt: float, t0: float) -> None:
        self.dt, self.t0, self.t, self.steps_done = float(dt), float(t0), float(t0), 0

    def _at(self, steps: int) -> float:
        """The time after ``steps`` steps from the start state."""
        return self.t0 + steps * self.dt

    def _tick(self) -> None:
        """One step taken: advance the clock."""
        self.steps_done += 1
        self.t = self._at(self.steps_done)

    @property
    def time(self) -> float:
        """Simulated time in s."""
        return float(self.t)

    def release(self) -> None:  # pragma: no cover - every backend overrides it
        """Release what the simulation holds."""

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


class CpuSimulationBase(SimulationBase):
    """Mixin of the float64 NumPy backends (explicit, implicit Euler, XPBD): the state on the
    CPU (``state``: a :class:`~deformgl.sim.integrators.State`), ``last_moved`` (the run loop's
    convergence test), the accessors, and no GL objects (``position_slot()`` is None)."""

    backend = "numpy"
    state: Any
    #: largest node displacement of the last step (the convergence test of the run loop)
    last_moved: float = float("inf")

    def _advance(self, new: Any) -> None:
        """One step taken into state ``new``: its largest displacement, the state, the clock."""
        self.last_moved = float(np.max(np.linalg.norm(new.x - self.state.x, axis=1), initial=0.0))
        self.state = new
        self._tick()

    def positions(self) -> np.ndarray:
        """(N, 3) float64 positions (a copy)."""
        return self.state.x.copy()

    def velocities(self) -> np.ndarray:
        """(N, 3) float64 velocities (a copy; Verlet: the backward difference)."""
        return self.state.v.copy()

    def position_slot(self) -> None:
        """No GPU texture on the NumPy backend."""
        return None

    @property
    def bytes_per_node(self) -> float:
        return 0.0

    def release(self) -> None:
        """Nothing to release."""
