"""One interface for every simulation backend, and one constructor.

:class:`Simulation` is what the run loop (:func:`deformgl.sim.run.run`), the renderers and the
benchmarks use; the fragment backend (:class:`~deformgl.sim.backends.fragment.FragmentIntegrator`,
Mosegaard & Sørensen 2005, section 3.1), the transform-feedback backend
(:class:`~deformgl.sim.backends.feedback.FeedbackSimulation`) and the float64 NumPy reference
(:class:`NumpySimulation`, Movania & Feng 2012, eq. 3-9) all implement it. Positions and
velocities cross to the CPU only when asked for.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np

from deformgl.errors import InputError
from deformgl.sim import integrators
from deformgl.sim.base import CpuSimulationBase
from deformgl.sim.integrators import EXPLICIT_INTEGRATORS, IMPLICIT_INTEGRATORS, INTEGRATORS, Constraints, State
from deformgl.sim.springs import Drag, Load, SpringSystem

__all__ = ["BACKENDS", "Simulation", "SimulationSetupError", "NumpySimulation", "make_simulation"]

BACKENDS = ("fragment", "feedback", "numpy")
#: Options only the fragment backend takes (its Verlet fast path and the pass variants).
FRAGMENT_OPTIONS = ("path", "draw", "branch", "layout", "block")
#: Options of the implicit integrators (:mod:`deformgl.sim.implicit`); the NumPy backend also
#: takes ``solver`` ("cg", "direct") and ``geometric`` ("projected", "full", "none").
IMPLICIT_OPTIONS = ("cg_iterations", "cg_tolerance", "cg_check_every", "cg_preconditioner", "cg_warm_start")
#: Options only XPBD takes (:class:`deformgl.sim.xpbd.XpbdSettings`).
XPBD_OPTIONS = ("iterations", "substeps", "omega")


class SimulationSetupError(InputError, ValueError):
    """An unknown integrator or backend, or options a backend does not take."""


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


def make_simulation(system: SpringSystem, integrator: str = "verlet", backend: str = "fragment", *,
                    dt: float, ctx=None, grid=None, **options) -> Simulation:
    """The one constructor of a :class:`Simulation`.

    Args:
        system: the spring system.
        integrator: one of :data:`~deformgl.sim.integrators.INTEGRATORS` ("implicit-euler":
            backward Euler with conjugate gradients, :mod:`deformgl.sim.implicit`; fragment and
            numpy backends).
        backend: "fragment" (a system with a node grid: :func:`~deformgl.sim.springs.from_grid`,
            :func:`~deformgl.sim.springs.cloth`), "feedback" or "numpy".
        dt: step in s, > 0.
        ctx: the GL context (the GPU backends).
        grid: the node grid (the fragment backend; default ``system.grid``).
        options: ``constraints``, ``drags``, ``loads``, ``state``, ``t0``; with "xpbd" also
            ``iterations``, ``substeps``, ``omega`` (:mod:`deformgl.sim.xpbd`); on the fragment
            backend also ``path`` ("auto": the foundation pass for Verlet where it models the
            system, "general", "foundation") and the foundation pass's ``draw``, ``branch``,
            ``layout`` and ``block`` (several nodes per fragment; see
            :class:`~deformgl.sim.backends.fragment.FragmentIntegrator`);
            "implicit-euler" takes ``cg_iterations``, ``cg_tolerance``, ``cg_check_every``,
            ``cg_preconditioner`` ("jacobi", "block-jacobi", "multigrid"), ``cg_warm_start`` ("scaled",
            "previous", "zero") (:data:`IMPLICIT_OPTIONS`) and on
            numpy ``solver`` and ``geometric``.

    Raises:
        SimulationSetupError: unknown integrator or backend, a GPU backend without ``ctx``, the
            fragment backend without a grid, or an unknown option.
    """
    if integrator not in INTEGRATORS:
        raise SimulationSetupError(f"unknown integrator {integrator!r}; expected one of {', '.join(INTEGRATORS)}")
    if backend not in BACKENDS:
        raise SimulationSetupError(f"unknown backend {backend!r}; expected one of {', '.join(BACKENDS)}")
    if integrator in IMPLICIT_INTEGRATORS:
        return _make_implicit(system, backend, dt=dt, ctx=ctx, grid=grid, **options)
    known = {"constraints", "drags", "loads", "state", "t0"}
    if integrator == "xpbd":
        return _make_xpbd(system, backend, dt, ctx, grid, known, options)
    if backend == "fragment":
        known |= set(FRAGMENT_OPTIONS)
    unknown = set(options) - known
    if unknown:
        raise SimulationSetupError(f"make_simulation: unknown option(s) {', '.join(sorted(unknown))}")
    if backend == "numpy":
        return NumpySimulation(system, integrator, dt, **options)
    if ctx is None:
        raise SimulationSetupError(f"the {backend} backend needs a GL context (ctx=...)")
    if backend == "fragment":
        if options.get("layout") == "atlas":
            raise SimulationSetupError("layout 'atlas' is a benchmark variant of the foundation pass: the run "
                                       "loop's census reads compact layouts only ('compact' or 'indexed')")
        grid = system.grid if grid is None else grid
        if grid is None:
            raise SimulationSetupError("the fragment backend needs a system built on a node grid "
                                       "(springs.from_grid or springs.cloth) or grid=...")
        from deformgl.sim.backends.fragment import FragmentIntegrator

        return FragmentIntegrator(ctx, system, grid, integrator, dt, **options)
    from deformgl.sim.backends.feedback import FeedbackSimulation

    return FeedbackSimulation(ctx, system, integrator, dt, **options)


def _make_implicit(system: SpringSystem, backend: str, *, dt: float, ctx, grid, **options) -> Simulation:
    """Backward Euler on the fragment or the NumPy backend (:func:`make_simulation`)."""
    known = {"constraints", "drags", "loads", "state", "t0", *IMPLICIT_OPTIONS}
    if backend == "numpy":
        known |= {"solver", "geometric"}
    unknown = set(options) - known
    if unknown:
        raise SimulationSetupError(f"make_simulation: unknown option(s) {', '.join(sorted(unknown))} "
                                   f"for implicit-euler on {backend}")
    try:
        if backend == "numpy":
            from deformgl.sim.implicit import ImplicitNumpySimulation

            return ImplicitNumpySimulation(system, dt, **options)
        if backend == "feedback":
            raise SimulationSetupError("implicit-euler runs on the fragment and numpy backends, not on "
                                       "feedback (its matrix-free product needs the node grid)")
        grid = _fragment_grid(ctx, system, grid)
        from deformgl.sim.backends.implicit_gpu import ImplicitFragment

        return ImplicitFragment(ctx, system, grid, dt, **options)
    except SimulationSetupError:
        raise
    except ValueError as exc:
        if "cg_" in str(exc):
            raise SimulationSetupError(str(exc)) from None
        raise


def _make_xpbd(system: SpringSystem, backend: str, dt: float, ctx, grid, known: set[str],
               options: dict) -> Simulation:
    """XPBD (:mod:`deformgl.sim.xpbd`) on the fragment or NumPy backend."""
    unknown = set(options) - known - set(XPBD_OPTIONS)
    if unknown:
        raise SimulationSetupError(f"make_simulation: unknown option(s) {', '.join(sorted(unknown))} for xpbd")
    if backend == "feedback":
        raise SimulationSetupError("xpbd runs on the fragment and numpy backends, not feedback (its Jacobi sweep "
                                   "gathers per-node neighbour multipliers from textures)")
    try:
        if backend == "numpy":
            from deformgl.sim.xpbd import XpbdNumpy

            return XpbdNumpy(system, dt, **options)
        grid = _fragment_grid(ctx, system, grid)
        from deformgl.sim.backends.xpbd_gpu import XpbdFragment

        return XpbdFragment(ctx, system, grid, dt, **options)
    except SimulationSetupError:
        raise
    except ValueError as exc:
        if str(exc).startswith("xpbd:"):
            raise SimulationSetupError(str(exc)) from None
        raise


def _fragment_grid(ctx, system: SpringSystem, grid):
    """The node grid a fragment-backend solver runs on (``grid`` or the system's); a context and
    a grid are required."""
    if ctx is None:
        raise SimulationSetupError("the fragment backend needs a GL context (ctx=...)")
    grid = system.grid if grid is None else grid
    if grid is None:
        raise SimulationSetupError("the fragment backend needs a system built on a node grid "
                                   "(springs.from_grid or springs.cloth) or grid=...")
    return grid
