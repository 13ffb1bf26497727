"""What every simulation backend shares on top of its own ``step``: the simulated time, and
``with`` support (release on exit). See :class:`deformgl.sim.simulation.Simulation`."""

from __future__ import annotations


class SimulationBase:
    """Mixin: ``time`` from the backend's ``t``, ``with`` releases on exit."""

    t: float

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
