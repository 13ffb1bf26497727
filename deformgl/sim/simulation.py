"""One interface for every simulation backend, and one constructor.

:class:`Simulation` is what the one run (:func:`deformgl.sim.run.run`), the renderers and the
benchmarks use; the fragment backend (:class:`~deformgl.sim.backends.explicit_gpu.FragmentIntegrator`,
Mosegaard & Sørensen 2005, section 3.1), the transform-feedback backend
(:class:`~deformgl.sim.backends.feedback.FeedbackSimulation`) and the float64 NumPy reference
(:class:`NumpySimulation`, Movania & Feng 2012, eq. 3-9) all implement it. Positions and
velocities cross to the CPU only when asked for.

:func:`make_simulation` is the one constructor: it picks the class of an integrator on a backend
(:data:`CLASSES`) and checks the options against the keyword arguments that class takes, so each
backend × integrator states its own options in its signature. The public API's
:class:`~deformgl.sim.restartable.GuardedSimulation` holds one it makes here (a context of its
own, and restarts at a smaller step under ``run(..., unstable="subdivide")``).
"""

from __future__ import annotations

import importlib
import inspect
from typing import Any, Protocol, runtime_checkable

import numpy as np

from deformgl.errors import ArgumentError
from deformgl.sim import integrators
from deformgl.sim.clock import CpuSimulationBase
from deformgl.sim.integrators import EXPLICIT_INTEGRATORS, INTEGRATORS, Constraints, State
from deformgl.sim.springs import SpringSystem
from deformgl.sim.scripted import Drag, Load

__all__ = ["BACKENDS", "Simulation", "SimulationSetupError", "NumpySimulation", "make_simulation"]

BACKENDS = ("fragment", "feedback", "numpy")
#: The class of each (integrator kind, backend): module and class name, imported on use. The
#: kind is "explicit" (the five of :data:`~deformgl.sim.integrators.EXPLICIT_INTEGRATORS`, whose
#: classes take the integrator's name), "implicit-euler" or "xpbd".
CLASSES: dict[tuple[str, str], tuple[str, str]] = {
    ("explicit", "fragment"): ("deformgl.sim.backends.explicit_gpu", "FragmentIntegrator"),
    ("explicit", "feedback"): ("deformgl.sim.backends.feedback", "FeedbackSimulation"),
    ("explicit", "numpy"): ("deformgl.sim.simulation", "NumpySimulation"),
    ("implicit-euler", "fragment"): ("deformgl.sim.backends.implicit_gpu", "ImplicitFragment"),
    ("implicit-euler", "numpy"): ("deformgl.sim.implicit", "ImplicitNumpySimulation"),
    ("xpbd", "fragment"): ("deformgl.sim.backends.xpbd_gpu", "XpbdFragment"),
    ("xpbd", "numpy"): ("deformgl.sim.xpbd", "XpbdNumpy"),
}
#: Why an integrator has no class on a backend.
NOT_ON = {
    ("implicit-euler", "feedback"): "implicit-euler runs on the fragment and numpy backends, not on feedback (its "
                                    "matrix-free product needs the node grid)",
    ("xpbd", "feedback"): "xpbd runs on the fragment and numpy backends, not feedback (its Jacobi sweep gathers "
                          "per-node neighbour multipliers from textures)",
}


class SimulationSetupError(ArgumentError):
    """An unknown integrator or backend, or options a backend does not take (an
    :class:`~deformgl.errors.ArgumentError`: an ``InputError`` and a ``ValueError``)."""


@runtime_checkable
class Simulation(Protocol):
    """A spring system stepped by one integrator on one backend.

    Attributes:
        system: the spring system.
        integrator: one of :data:`~deformgl.sim.integrators.INTEGRATORS`.
        backend: one of :data:`BACKENDS`.
        dt: step in s.
        time: simulated time in s.
        bytes_per_node: GPU bytes per node (0 on the NumPy backend).
        count: number of nodes.
    """

    system: SpringSystem
    integrator: str
    backend: str
    dt: float
    count: int

    @property
    def time(self) -> float: ...

    @property
    def bytes_per_node(self) -> float: ...

    def step(self, n: int = 1) -> None: ...

    def positions(self) -> np.ndarray: ...

    def velocities(self) -> np.ndarray: ...

    def position_slot(self) -> Any: ...

    def release(self) -> None: ...

    def __enter__(self) -> Simulation: ...

    def __exit__(self, *exc: object) -> None: ...


class NumpySimulation(CpuSimulationBase):
    """The float64 reference (:func:`deformgl.sim.integrators.step`) behind the
    :class:`Simulation` interface. Holds no GL objects: ``position_slot()`` is None.

    Args: as :class:`~deformgl.sim.backends.feedback.FeedbackSimulation`, without the context.
    """

    def __init__(self, system: SpringSystem, integrator: str, dt: float, *,
                 constraints: Constraints | None = None, drags: tuple[Drag, ...] = (),
                 loads: tuple[Load, ...] = (), state: State | None = None, t0: float = 0.0) -> None:
        if integrator not in EXPLICIT_INTEGRATORS:
            raise ValueError(f"unknown integrator {integrator!r}; expected one of {', '.join(EXPLICIT_INTEGRATORS)}")
        if not dt > 0:
            raise ValueError(f"NumpySimulation: dt must be > 0, got {dt}")
        self.system, self.integrator = system, integrator
        self._start_clock(dt, t0)
        self.constraints, self.drags, self.loads = constraints, tuple(drags), tuple(loads)
        self.count = system.count
        self.state = (integrators.initial_state(system, self.dt, t=self.t, drags=self.drags, loads=self.loads)
                      if state is None else state)

    def step(self, n: int = 1) -> None:
        """``n`` steps; time is ``t0 + steps * dt`` (no accumulated rounding)."""
        for _ in range(n):
            self._advance(integrators.step(self.system, self.integrator, self.state, self.dt, self.t,
                                           constraints=self.constraints, drags=self.drags, loads=self.loads))


def check_kind(integrator: str, backend: str, dt: float) -> None:
    """Refuse an unknown integrator or backend, or a dt that is not > 0 (before anything is built).

    Raises:
        SimulationSetupError: naming the argument.
    """
    if integrator not in INTEGRATORS:
        raise SimulationSetupError(f"unknown integrator {integrator!r}; expected one of {', '.join(INTEGRATORS)}")
    if backend not in BACKENDS:
        raise SimulationSetupError(f"unknown backend {backend!r}; expected one of {', '.join(BACKENDS)}")
    if isinstance(dt, bool) or not isinstance(dt, (int, float, np.number)) or not dt > 0.0:
        raise SimulationSetupError(f"make_simulation: dt must be a number > 0 (s), got {dt!r}")


def backend_class(integrator: str, backend: str) -> type:
    """The class that runs ``integrator`` on ``backend`` (:data:`CLASSES`).

    Raises:
        SimulationSetupError: an unknown integrator or backend, or a pair with no class (:data:`NOT_ON`).
    """
    check_kind(integrator, backend, 1.0)
    kind = "explicit" if integrator in EXPLICIT_INTEGRATORS else integrator
    if (kind, backend) in NOT_ON:
        raise SimulationSetupError(NOT_ON[kind, backend])
    module, name = CLASSES[kind, backend]
    cls: type = getattr(importlib.import_module(module), name)
    return cls


def options_taken(cls: type) -> tuple[str, ...]:
    """The options a backend class takes: the keyword-only arguments of its constructor."""
    parameters = inspect.signature(cls.__init__).parameters.values()  # type: ignore[misc]
    return tuple(p.name for p in parameters if p.kind is inspect.Parameter.KEYWORD_ONLY)


def make_simulation(system: SpringSystem, integrator: str = "verlet", backend: str = "fragment", *,
                    dt: float, ctx: Any = None, grid: Any = None, **options: Any) -> Simulation:
    """The one constructor of a :class:`Simulation`: ``integrator`` on ``backend``.

    Args:
        system: the spring system.
        integrator: one of :data:`~deformgl.sim.integrators.INTEGRATORS` ("implicit-euler":
            backward Euler with conjugate gradients, :mod:`deformgl.sim.implicit`; "xpbd",
            :mod:`deformgl.sim.xpbd`; both on the fragment and numpy backends).
        backend: "fragment" (a system with a node grid: :func:`~deformgl.sim.springs.from_grid`,
            :func:`~deformgl.sim.springs.cloth`), "feedback" or "numpy".
        dt: step in s, > 0.
        ctx: the GL context (the GPU backends).
        grid: the node grid (the fragment backend; default ``system.grid``).
        options: the keyword arguments of the backend class (:data:`CLASSES`, :func:`options_taken`):
            every one takes ``constraints``, ``drags``, ``loads``, ``state``, ``t0``; the fragment
            backend's explicit integrators also ``path`` ("auto", "general", "foundation"),
            ``layout`` and ``block`` (several nodes per fragment) and the foundation pass's
            variants (:class:`~deformgl.sim.backends.explicit_gpu.FragmentIntegrator`);
            "implicit-euler" ``cg_iterations``, ``cg_tolerance``, ``cg_check_every``,
            ``cg_preconditioner`` ("jacobi", "block-jacobi", "multigrid"), ``cg_warm_start``
            ("scaled", "previous", "zero") and on numpy ``solver`` and ``geometric``; "xpbd"
            ``iterations``, ``substeps``, ``omega``.

    Raises:
        SimulationSetupError: unknown integrator or backend, a pair with no class, a GPU backend
            without ``ctx``, the fragment backend without a grid, an option the backend class does
            not take (naming the option, the integrator and the backend), or an option value its
            class refuses.
    """
    check_kind(integrator, backend, dt)
    cls = backend_class(integrator, backend)
    taken = options_taken(cls)
    unknown = sorted(set(options) - set(taken))
    if unknown:
        raise SimulationSetupError(f"make_simulation: unknown option(s) {', '.join(map(repr, unknown))} for "
                                   f"{integrator} on the {backend} backend, which takes {', '.join(taken)}")
    if backend == "numpy":
        args: tuple = (system,)
    else:
        if ctx is None:
            raise SimulationSetupError(f"the {backend} backend needs a GL context (ctx=...); "
                                       f"deformgl.GuardedSimulation(...) makes one of its own")
        args = (ctx, system)
    if backend == "fragment":
        grid = system.grid if grid is None else grid
        if grid is None:
            raise SimulationSetupError("the fragment backend needs a system built on a node grid "
                                       "(springs.from_grid or springs.cloth) or grid=...")
        args += (grid,)
    if integrator in EXPLICIT_INTEGRATORS:
        args += (integrator,)
    try:
        made: Simulation = cls(*args, dt, **options)
        return made
    except ValueError as exc:  # an option value the class refuses ("cg_...", "xpbd: ..."): a setup error
        if isinstance(exc, SimulationSetupError) or not ("cg_" in str(exc) or str(exc).startswith("xpbd:")):
            raise
        raise SimulationSetupError(str(exc)) from None
