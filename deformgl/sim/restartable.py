"""A simulation that can start again with a smaller step: the public API's.

:class:`GuardedSimulation` holds one backend's simulation (:func:`deformgl.sim.simulation.make_simulation`:
fragment, feedback or the NumPy reference), implements the
:class:`deformgl.sim.simulation.Simulation` protocol, makes a GL context of its own when given
none, and can start again from the rest state with a smaller step, which the one run
(:func:`deformgl.sim.run.run`) does under ``unstable="subdivide"``. ``dg.Body.simulate`` makes
one.
"""

from __future__ import annotations

from typing import Any

import moderngl
import numpy as np

from deformgl.grid.nodes import NodeGrid
from deformgl.sim import simulation as backends
from deformgl.sim.springs import SpringSystem
from deformgl.sim.scripted import Drag, Load

__all__ = ["GuardedSimulation"]


class GuardedSimulation:
    """One spring system stepped by one integrator on one backend, restartable with another step:
    a :class:`deformgl.sim.simulation.Simulation` around the backend's, which
    :func:`deformgl.sim.run.run` guards.

    Args: as :func:`deformgl.sim.simulation.make_simulation` (``ctx`` None on a GPU backend: a
    context of its own, released with it).

    Attributes:
        system, integrator, backend: what runs; dt: the step it runs (s, ``dt / substeps`` after a
        subdivided run); base_dt: the step it was made with (s); time: simulated seconds; ctx: the
        GL context (None on numpy); source: the name the run's errors start with (a body sets its
        mesh's); options: the backend's options.
    """

    def __init__(self, system: SpringSystem, integrator: str = "verlet", backend: str = "fragment", *, dt: float,
                 ctx: moderngl.Context | None = None, grid: NodeGrid | None = None, **options: Any) -> None:
        backends.check_kind(integrator, backend, dt)
        own = None
        if backend != "numpy" and ctx is None:
            from deformgl.gl.context import create_context

            ctx = own = create_context()
        self._own_ctx: moderngl.Context | None = own
        self.system, self.integrator, self.backend, self.grid = system, integrator, backend, grid
        self.ctx, self.options, self.dt = ctx, options, float(dt)
        self.base_dt = float(dt)
        self.source = "<simulation>"
        self._inner: backends.Simulation | None = None
        try:
            self.restart(self.dt)
        except BaseException:
            self.release()
            raise

    def restart(self, dt: float) -> None:
        """Start again from the rest state with step ``dt`` (s)."""
        if self._inner is not None:
            self._inner.release()
            self._inner = None
        self._inner = backends.make_simulation(self.system, self.integrator, self.backend, dt=dt, ctx=self.ctx,
                                               grid=self.grid, **self.options)
        self.dt = float(dt)

    @property
    def _live(self) -> backends.Simulation:
        if self._inner is None:
            raise RuntimeError("the simulation is released")
        return self._inner

    @property
    def count(self) -> int:
        """Nodes."""
        return self.system.count

    @property
    def time(self) -> float:
        """Simulated seconds since the start."""
        return float(self._live.time)

    @property
    def bytes_per_node(self) -> float:
        """GPU bytes allocated per node (0 on numpy)."""
        return float(self._live.bytes_per_node)

    @property
    def loads(self) -> tuple[Load, ...]:
        """The scripted loads it was made with."""
        return tuple(self.options.get("loads", ()))

    @property
    def drags(self) -> tuple[Drag, ...]:
        """The drags it was made with."""
        return tuple(self.options.get("drags", ()))

    def step(self, n: int = 1) -> None:
        """``n`` steps, unguarded (see :func:`deformgl.sim.run.run`); nothing is read back."""
        self._live.step(n)

    def positions(self) -> np.ndarray:
        """(N, 3) node positions (one read-back on the GPU backends)."""
        return np.asarray(self._live.positions())[:, :3]

    def velocities(self) -> np.ndarray:
        """(N, 3) node velocities (one read-back on the GPU backends)."""
        return np.asarray(self._live.velocities())[:, :3]

    @property
    def residual(self) -> float | None:
        """The relative constraint residual of an iterative integrator's last step (XPBD), else None."""
        return getattr(self._live, "residual", None)

    @property
    def backend_simulation(self) -> backends.Simulation:
        """The backend simulation it runs now (replaced by a restart)."""
        return self._live

    def position_slot(self) -> tuple[moderngl.Texture, int, int, int] | None:
        """Where the positions lie on the GPU: (texture, nodes per row, slots per node, slot);
        None on the numpy backend."""
        where = self._live.position_slot()
        if where is None:
            return None
        texture, row, slots, slot = where
        return texture, int(row), int(slots), int(slot)

    def release(self) -> None:
        """Release every GL object (and the context it created); idempotent."""
        if self._inner is not None:
            self._inner.release()
            self._inner = None
        if self._own_ctx is not None:
            self._own_ctx.release()
            self._own_ctx = None

    def __enter__(self) -> GuardedSimulation:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()
