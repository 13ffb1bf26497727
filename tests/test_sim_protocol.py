"""One Simulation interface: all three backends implement it, make_simulation builds them, the
one run (deformgl.sim.run.run) guards and stops each of them the same way."""

from __future__ import annotations

import numpy as np
import pytest

from deformgl.errors import ArgumentError, DeformglError
from deformgl.grid.nodes import NodeGrid
from deformgl.sim import integrators as I
from deformgl.sim import springs
from deformgl.sim.backends.feedback import FeedbackSimulation
from deformgl.sim.backends.explicit_gpu import FragmentIntegrator
from deformgl.sim.guards import BlowUp
from deformgl.sim.integrators import EXPLICIT_INTEGRATORS
from deformgl.sim.run import RunResult, run
from deformgl.sim.simulation import (BACKENDS, NumpySimulation, Simulation, SimulationSetupError,
                                     make_simulation)


def small_system(n: int = 3):
    grid = NodeGrid(np.array([0.2, 0.5, -0.1]), 0.1, np.ones((n, n, n), bool))
    fixed = np.zeros(grid.count, bool)
    fixed[0] = True
    system = springs.from_grid(grid, k_structural=50.0, k_shear=20.0, mass=0.1, fixed=fixed,
                               velocity_damping=0.02, damping_structural=0.1, damping_shear=0.05)
    return system, grid


def build(ctx, backend, integrator="verlet", dt=1e-3, **options):
    system, grid = small_system()
    return make_simulation(system, integrator, backend, dt=dt, ctx=ctx, grid=grid, **options)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("integrator", EXPLICIT_INTEGRATORS)
def test_every_backend_is_a_simulation_and_matches_the_float64_reference(ctx, backend, integrator):
    dt, steps = 1e-3, 5
    state = I.initial_state(small_system()[0], dt, v=np.random.default_rng(2).normal(size=(27, 3)))
    with build(ctx, backend, integrator, dt, state=state) as sim:
        assert isinstance(sim, Simulation)
        assert (sim.backend, sim.integrator, sim.dt, sim.count) == (backend, integrator, dt, 27)
        assert sim.time == 0.0
        sim.step(steps)
        assert sim.time == pytest.approx(steps * dt)
        x, v = sim.positions(), sim.velocities()
        assert x.shape == v.shape == (27, 3)
        assert (sim.position_slot() is None) == (backend == "numpy")
        assert (sim.bytes_per_node > 0) == (backend != "numpy")
        ref = I.simulate(sim.system, integrator, dt, steps, state=state)
    scale = np.abs(ref.x).max()
    assert np.abs(x - ref.x).max() <= 1e-5 * scale
    if backend == "numpy":
        np.testing.assert_array_equal(x, ref.x)
        np.testing.assert_array_equal(v, ref.v)


def test_make_simulation_returns_the_backend_classes(ctx):
    for backend, cls in (("fragment", FragmentIntegrator), ("feedback", FeedbackSimulation),
                         ("numpy", NumpySimulation)):
        sim = build(ctx, backend)
        try:
            assert type(sim) is cls
        finally:
            sim.release()


@pytest.mark.parametrize("kwargs, words", [
    (dict(integrator="leapfrog"), "unknown integrator 'leapfrog'"),
    (dict(backend="cuda"), "unknown backend 'cuda'"),
    (dict(backend="fragment", grid=None, mesh=True), "needs a system built on a node grid"),
    (dict(backend="feedback", ctx=None), "needs a GL context"),
    (dict(backend="numpy", colour="red"), "unknown option"),
])
def test_make_simulation_refuses_with_a_deformgl_error(ctx, kwargs, words):
    system, grid = small_system()
    args = dict(integrator="verlet", backend="fragment", ctx=ctx, grid=grid) | kwargs
    if args.pop("mesh", False):  # springs along triangle edges: no node grid
        system = springs.from_triangle_mesh(system.rest_positions[:3], [[0, 1, 2]], stiffness=1.0)
    with pytest.raises(SimulationSetupError, match=words) as info:
        make_simulation(system, args.pop("integrator"), args.pop("backend"), dt=1e-3, **args)
    assert isinstance(info.value, DeformglError)


@pytest.mark.parametrize("backend", BACKENDS)
def test_the_run_loop_watches_every_backend_and_names_the_step(ctx, backend):
    # stiff springs, dt far above the limit: every backend blows up, the watch says when
    system, grid = small_system()
    stiff = springs.from_grid(grid, k_structural=5e4, k_shear=5e4, mass=0.1, fixed=system.fixed)
    sim = make_simulation(stiff, "euler", backend, dt=0.05, ctx=ctx, grid=grid)
    try:
        with pytest.raises(BlowUp) as info:  # (unstable=None: no dt check, the watch alone)
            run(sim, 400, unstable=None, check_every=10, limit=10.0, grid=grid, source="test.toml")
        assert info.value.step % 10 == 0 or backend == "numpy"
        assert "test.toml" in str(info.value)
    finally:
        sim.release()


@pytest.mark.parametrize("backend", BACKENDS)
def test_the_run_loop_stops_each_backend_at_the_same_converged_step(ctx, backend):
    # a damped system at rest under no load never moves: converged at the first test
    system, grid = small_system()
    quiet = springs.from_grid(grid, k_structural=50.0, k_shear=20.0, mass=0.1, fixed=system.fixed,
                              gravity=(0.0, 0.0, 0.0))
    with make_simulation(quiet, "semi-implicit", backend, dt=1e-3, ctx=ctx, grid=grid) as sim:
        done = run(sim, 100, unstable=None, check_every=0, limit=10.0, grid=grid, converge=(1e-9, 20))
        assert (done.steps, done.converged) == (20, True)
    with make_simulation(system, "semi-implicit", backend, dt=1e-3, ctx=ctx, grid=grid) as sim:
        done = run(sim, 40, unstable=None, converge=(0.0, 20))
        assert (done.steps, done.converged) == (40, False)
        assert sim.time == pytest.approx(0.04)


def test_the_stage_table_describes_every_integrator_once():
    from deformgl.sim.stages import SPECS, spec

    assert tuple(SPECS) == EXPLICIT_INTEGRATORS
    for name, s in SPECS.items():
        assert s.bytes_per_node == I.memory_per_node(name)
        for stage in s.stages:
            assert not set(stage.reads) & set(stage.writes), (name, stage)  # ping-pong
            assert set(stage.reads) | set(stage.writes) <= set(s.buffers)
    assert spec("rk4").limit_factor == pytest.approx(2.83, abs=0.01)
    with pytest.raises(ValueError, match="unknown integrator"):
        spec("leapfrog")


@pytest.mark.parametrize("backend", ["fragment", "feedback"])
def test_a_constructor_failing_half_way_releases_what_it_made(ctx, backend, monkeypatch):
    import moderngl

    made = []
    real = moderngl.Context.texture

    def counting(self, *a, **k):
        t = real(self, *a, **k)
        made.append(t)
        if len(made) == 2:
            raise RuntimeError("out of texture memory")
        return t

    monkeypatch.setattr(moderngl.Context, "texture", counting)
    with pytest.raises(RuntimeError, match="out of texture memory"):
        build(ctx, backend)
    assert made and type(made[0].mglo).__name__ == "InvalidObject"  # released


def test_each_backend_takes_the_options_of_its_constructor():
    """make_simulation dispatches; the options a backend x integrator takes are its class's keyword
    arguments, and any other is refused in one line naming it, the integrator and the backend."""
    system, grid = small_system()
    with pytest.raises(SimulationSetupError, match=r"unknown option\(s\) 'cg_iterations' for verlet on the feedback "
                                                  r"backend, which takes constraints, drags, loads, state, t0$") as info:
        make_simulation(system, "verlet", "feedback", dt=1e-3, cg_iterations=3)
    assert isinstance(info.value, ArgumentError) and "\n" not in str(info.value)
    with pytest.raises(SimulationSetupError, match=r"'path' for implicit-euler on the numpy backend, which takes .*solver"):
        make_simulation(system, "implicit-euler", "numpy", dt=1e-3, path="general")
    with pytest.raises(SimulationSetupError, match=r"'cg_tolerance' for xpbd on the numpy backend, which takes .*omega"):
        make_simulation(system, "xpbd", "numpy", dt=1e-3, cg_tolerance=0.0)
    with pytest.raises(SimulationSetupError, match="dt must be a number > 0"):
        make_simulation(system, "verlet", "numpy", dt=0.0)
    with make_simulation(system, "xpbd", "numpy", dt=1e-3, iterations=3, omega=1.0) as sim:
        sim.step(1)
