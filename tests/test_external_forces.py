"""Loads (scripted per-node forces) and scripted drags on both GPU backends and the reference."""

from __future__ import annotations

import numpy as np
import pytest

from deformgl.sim import integrators as I
from deformgl.sim import scripted, springs
from deformgl.sim.backends.feedback import FeedbackSimulation
from deformgl.sim.backends.explicit_gpu import FragmentIntegrator
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.integrators import EXPLICIT_INTEGRATORS

BACKENDS = ("fragment", "feedback")


def block(n=3, **extra):
    grid = NodeGrid(np.array([0.2, 0.5, -0.1]), 0.1, np.ones((n, n, n), bool))
    fixed = np.zeros(grid.count, bool)
    fixed[:n * n] = True  # the x = 0 face
    options = dict(k_structural=50.0, k_shear=20.0, k_flexion=10.0, damping_structural=0.05,
                   mass=0.1, fixed=fixed, velocity_damping=0.02)
    options.update(extra)
    return springs.from_grid(grid, **options), grid


def make(ctx, backend, system, grid, name, dt, **kwargs):
    if backend == "fragment":
        return FragmentIntegrator(ctx, system, grid, name, dt, **kwargs)
    return FeedbackSimulation(ctx, system, name, dt, **kwargs)


def loads_of(system):
    top = system.rest_positions[:, 1] > 0.65
    far = system.rest_positions[:, 0] > 0.35
    return (scripted.Load(top, lambda t: (0.4 * min(t / 0.005, 1.0), 0.0, 0.0)),
            scripted.Load(far, lambda t: (0.0, 0.0, -0.3 if t >= 0.004 else 0.0)))


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_loads_and_drags_match_reference(ctx, backend, name):
    system, grid = block(wind=(1.0, 0.0, 0.5), wind_drag=0.01)
    dt = 1e-3
    loads = loads_of(system)
    drags = (scripted.Drag(20, lambda t: (0.45, 0.8 + 3.0 * t, 0.0), 40.0),)
    state = I.initial_state(system, dt, drags=drags, loads=loads)
    sim = make(ctx, backend, system, grid, name, dt, drags=drags, loads=loads, state=state)
    try:
        sim.step(12)
        x = sim.positions().astype(np.float64)
    finally:
        sim.release()
    ref = I.simulate(system, name, dt, 12, state=state, drags=drags, loads=loads)
    assert np.abs(x - ref.x).max() <= 1e-5 * np.abs(ref.x).max()
    # the loads and the drag moved the result, so the comparison covers them
    unloaded = I.simulate(system, name, dt, 12, state=state, drags=drags)
    undragged = I.simulate(system, name, dt, 12, state=state, loads=loads)
    assert np.abs(unloaded.x - ref.x).max() > 1e-3 * system.spacing
    assert np.abs(undragged.x - ref.x).max() > 1e-3 * system.spacing


@pytest.mark.parametrize("backend", BACKENDS)
def test_drag_target_is_followed(ctx, backend):
    """A node grabbed by a stiff drag follows its target to within the static sag m g / k_d
    and the pull of its springs, once the target stops."""
    system, grid = block(velocity_damping=0.5, k_flexion=0.0)
    node = int(np.argmax(system.rest_positions[:, 0] + system.rest_positions[:, 1]))
    start = system.rest_positions[node]
    end = start + np.array([0.05, 0.04, 0.0])
    drag = scripted.Drag(node, lambda t: start + (end - start) * min(t / 0.1, 1.0), 2000.0)
    dt = 0.5 / springs.max_angular_frequency(system).omega / np.sqrt(1 + 2000.0 / 50.0)
    sim = make(ctx, backend, system, grid, "semi-implicit", dt, drags=(drag,))
    try:
        sim.step(int(0.4 / dt))
        x = sim.positions().astype(np.float64)
    finally:
        sim.release()
    ref = I.simulate(system, "semi-implicit", dt, int(0.4 / dt), drags=(drag,))
    miss = np.linalg.norm(x[node] - end)
    assert miss < 0.15 * np.linalg.norm(end - start)       # it followed
    assert np.linalg.norm(x[node] - ref.x[node]) < 1e-4      # and agrees with the reference
    assert np.linalg.norm(x[node] - start) > 0.8 * np.linalg.norm(end - start)


@pytest.mark.parametrize("backend", BACKENDS)
def test_features_compiled_only_when_used(ctx, backend):
    system, grid = block()
    sim = make(ctx, backend, system, grid, "euler", 1e-3)
    try:
        text = _source(sim)
        assert "#define LOADS 0" in text and "#define DRAGS 0" in text
        assert "#define WIND" not in text
        assert not set(_members(sim)) & {"u_load", "u_drag_node", "u_drag_target", "u_wind"}
    finally:
        sim.release()
    windy, grid = block(wind=(1.0, 0.0, 0.0), wind_drag=0.1)
    sim = make(ctx, backend, windy, grid, "euler", 1e-3, loads=loads_of(windy),
               drags=(scripted.Drag(5, lambda t: (0, 0, 0), 1.0),))
    try:
        text = _source(sim)
        assert "#define LOADS 2" in text and "#define DRAGS 1" in text and "#define WIND" in text
        assert {"u_load", "u_drag_node", "u_drag_target", "u_wind"} <= set(_members(sim))
    finally:
        sim.release()


def test_too_many_loads_and_bad_drag_node_are_refused(ctx):
    system, grid = block()
    mask = np.ones(system.count, bool)
    five = tuple(scripted.Load(mask, lambda t: (0, 0, 0)) for _ in range(5))
    with pytest.raises(ValueError, match="at most 4"):
        FragmentIntegrator(ctx, system, grid, "verlet", 1e-3, loads=five)
    with pytest.raises(ValueError, match="at most 4"):
        FeedbackSimulation(ctx, system, "verlet", 1e-3, loads=five)
    with pytest.raises(ValueError, match="drag node"):
        FragmentIntegrator(ctx, system, grid, "verlet", 1e-3,
                           drags=(scripted.Drag(system.count, lambda t: (0, 0, 0), 1.0),))


def _step_program(sim):
    return sim.passes["step"] if isinstance(sim, FragmentIntegrator) else sim._passes["step"].program


def _source(sim):
    p = _step_program(sim)
    return p.fragment_source.text if isinstance(sim, FragmentIntegrator) else p.vertex_source.text


def _members(sim):
    return _step_program(sim).gl._members


PER_KG_CASES = [("fragment", "verlet", {"path": "foundation"}), ("fragment", "verlet", {"path": "foundation", "block": (1, 2, 2)}),
                ("fragment", "semi-implicit", {}), ("fragment", "rk4", {}), ("feedback", "verlet", {}),
                ("fragment", "xpbd", {}), ("fragment", "implicit-euler", {})]


@pytest.mark.parametrize("backend, name, options", PER_KG_CASES,
                         ids=[f"{b}-{n}{'-blocked' if 'block' in o else ''}" for b, n, o in PER_KG_CASES])
def test_loads_per_kg_scale_with_each_nodes_mass_on_every_backend(ctx, backend, name, options):
    """A load given per kilogram (a material scene's pull, spread over its material) puts
    force(t) m_i on node i: each GPU backend matches the NumPy reference of the same integrator
    with unequal masses, and the result differs from the same load per node."""
    from deformgl.sim.simulation import make_simulation
    grid = NodeGrid(np.array([0.2, 0.5, -0.1]), 0.1, np.ones((4, 4, 4), bool))
    mass = 0.05 + 0.1 * (np.arange(grid.count) % 5)   # unequal masses
    system = springs.from_grid(grid, k_structural=50.0, k_shear=20.0, mass=mass,
                               fixed=grid.ijk[:, 0] == 0, velocity_damping=0.02)
    top = system.rest_positions[:, 1] > 0.75
    per_kg = (scripted.Load(top, lambda t: (4.0 * min(t / 0.005, 1.0), 0.0, 1.0), per_kg=True),)
    per_node = (scripted.Load(top, lambda t: (4.0 * min(t / 0.005, 1.0), 0.0, 1.0)),)
    dt, steps = 1e-3, 15

    def run(backend_, loads, **extra):
        with make_simulation(system, name, backend_, dt=dt, ctx=ctx, grid=grid, loads=loads, **extra) as sim:
            sim.step(steps)
            return np.asarray(sim.positions(), np.float64)

    ref = run("numpy", per_kg)
    x = run(backend, per_kg, **options)
    assert np.abs(x - ref).max() <= 2e-5 * np.abs(ref).max()
    assert np.abs(run("numpy", per_node) - ref).max() > 1e-3 * system.spacing


def test_per_node_and_per_kg_loads_on_one_node_are_refused():
    grid = NodeGrid(np.zeros(3), 0.1, np.ones((2, 2, 2), bool))
    every = np.ones(grid.count, bool)
    with pytest.raises(ValueError, match="per node and a load per kilogram"):
        scripted.load_groups((scripted.Load(every, lambda t: (1, 0, 0)),
                             scripted.Load(every, lambda t: (1, 0, 0), per_kg=True)), grid.count)
