"""The five integrators on the fragment backend (grid topology) against the float64 reference."""

from __future__ import annotations

import moderngl
import numpy as np
import pytest

from deformgl.sim import integrators as I
from deformgl.sim import springs
from deformgl.grid.neighbours import grid_neighbours
from deformgl.sim.backends.explicit_gpu import FragmentIntegrator
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.integrators import EXPLICIT_INTEGRATORS, Constraints, Sphere

EPS32 = 2.0 ** -23


def damped_grid(n: int = 3, *, spring_damping: float = 0.1, fixed_nodes=(0,), **extra):
    grid = NodeGrid(np.array([0.2, 0.5, -0.1]), 0.1, np.ones((n, n, n), bool))
    fixed = np.zeros(grid.count, bool)
    fixed[list(fixed_nodes)] = True
    options = dict(k_structural=50.0, k_shear=20.0, k_flexion=10.0,
                   damping_structural=spring_damping, damping_shear=spring_damping / 2,
                   damping_flexion=spring_damping / 4, mass=0.1, fixed=fixed,
                   velocity_damping=0.02, wind=(1.0, 0.0, 0.5), wind_drag=0.01)
    options.update(extra)
    return springs.from_grid(grid, **options), grid


def run(ctx, system, grid, name, dt, steps, **kwargs):
    sim = FragmentIntegrator(ctx, system, grid, name, dt, **kwargs)
    try:
        sim.step(steps)
        return sim.positions().astype(np.float64), sim.velocities().astype(np.float64)
    finally:
        sim.release()


def reference(system, name, dt, steps, state, constraints=None):
    s = state
    for k in range(steps):
        s = I.step(system, name, s, dt, k * dt, constraints=constraints)
    return s


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_one_step_matches_reference(ctx, name):
    system, grid = damped_grid()
    dt = 1e-3
    state = I.initial_state(system, dt, v=np.random.default_rng(1).normal(size=(27, 3)))
    x, v = run(ctx, system, grid, name, dt, 1, state=state)
    ref = I.step(system, name, state, dt, 0.0)
    scale = np.abs(ref.x).max()
    assert np.abs(x - ref.x).max() <= 1e-5 * scale
    # the step itself is resolved, not just the start position
    assert np.abs(ref.x - state.x).max() > 1e3 * np.abs(x - ref.x).max()
    if name == "verlet":
        # (x' - x)/dt of float32 positions: a few roundings of the positions over dt
        assert np.abs(v - ref.v).max() <= 4 * EPS32 * scale / dt
    else:
        assert np.abs(v - ref.v).max() <= 1e-5 * np.abs(ref.v).max()


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_hundred_steps_of_a_damped_scene(ctx, name):
    system, grid = damped_grid(4, fixed_nodes=(0, 3, 12, 15), spring_damping=0.2)
    dt = 2e-3
    state = I.initial_state(system, dt, v=np.random.default_rng(2).normal(size=(64, 3)) * 0.2)
    x, _ = run(ctx, system, grid, name, dt, 100, state=state)
    ref = reference(system, name, dt, 100, state)
    assert np.abs(ref.x - state.x).max() > 0.1 * system.spacing  # it really moved
    assert np.abs(x - ref.x).max() <= 1e-3 * system.spacing


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_fixed_nodes_bit_identical(ctx, name):
    system, grid = damped_grid(3, fixed_nodes=(0, 2, 20))
    dt = 1e-3
    state = I.initial_state(system, dt, v=np.random.default_rng(3).normal(size=(27, 3)))
    sim = FragmentIntegrator(ctx, system, grid, name, dt, state=state,
                             constraints=Constraints(ground=0.55))
    try:
        for _ in range(3):
            sim.step(7)
            x, v = sim.positions(), sim.velocities()
            assert np.array_equal(x[system.fixed], state.x[system.fixed].astype(np.float32))
            assert np.all(v[system.fixed] == 0.0)
            assert not np.array_equal(x[~system.fixed],
                                      state.x[~system.fixed].astype(np.float32))
    finally:
        sim.release()


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_ground_and_sphere_after_every_step(ctx, name):
    """A block falls onto the ground and a sphere: never below / inside after any step, and the
    same contact handling (projection, velocity rule) as the reference."""
    system, grid = damped_grid(3, fixed_nodes=(), spring_damping=0.05)
    dt = 2e-3
    ground = 0.45  # below the sphere: the two never conflict
    sphere = Sphere(centre=(0.3, 0.52, 0.0), radius=0.05)
    constraints = Constraints(ground=ground, spheres=(sphere,))
    v0 = np.tile([0.0, -4.0, 0.0], (27, 1))
    state = I.initial_state(system, dt, v=v0)
    sim = FragmentIntegrator(ctx, system, grid, name, dt, state=state, constraints=constraints)
    s = state
    contacts = sphere_contacts = 0
    try:
        for k in range(10):
            sim.step(1)
            s = I.step(system, name, s, dt, k * dt, constraints=constraints)
            x32 = sim.positions()
            assert np.all(x32[:, 1] >= np.float32(ground))
            x = x32.astype(np.float64)
            dist = np.linalg.norm(x - sphere.centre_at(0.0), axis=1)
            assert np.all(dist >= sphere.radius * (1 - 4 * EPS32))
            assert np.abs(x - s.x).max() <= 1e-5 * np.abs(s.x).max()
            contacts += int(np.sum(s.x[:, 1] == ground))
            on_sphere = np.linalg.norm(s.x - sphere.centre_at(0.0), axis=1) - sphere.radius
            sphere_contacts += int(np.sum(np.abs(on_sphere) < 1e-12))
            if name != "verlet":
                v = sim.velocities().astype(np.float64)
                assert np.abs(v - s.v).max() <= 1e-4 * np.abs(s.v).max()
    finally:
        sim.release()
    assert contacts > 0 and sphere_contacts > 0  # both obstacles were reached


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_cloth_with_flexion_matches_reference(ctx, name):
    """A 20x20 cloth (structural, shear and flexion springs, two pinned corners) over 30 steps:
    the flexion neighbours at distance 2 take part (without them the result differs)."""
    n = 20
    fixed = np.zeros(n * n, bool)
    fixed[[0, n * (n - 1)]] = True
    system = springs.cloth(n, n, 0.05, k_structural=500.0, k_shear=200.0, k_flexion=50.0,
                           damping_structural=0.05, damping_flexion=0.02, mass=0.01,
                           fixed=fixed, velocity_damping=0.01)
    grid = NodeGrid(np.zeros(3), 0.05, np.ones((n, 1, n), bool))
    assert system.class_counts()["flexion"] == 2 * n * (n - 2)
    dt = 1e-3
    state = I.initial_state(system, dt, v=np.random.default_rng(5).normal(size=(n * n, 3)) * 0.1)
    x1, _ = run(ctx, system, grid, name, dt, 1, state=state)
    ref1 = I.step(system, name, state, dt, 0.0)
    assert np.abs(x1 - ref1.x).max() <= 1e-5 * np.abs(ref1.x).max()
    x, _ = run(ctx, system, grid, name, dt, 30, state=state)
    ref = reference(system, name, dt, 30, state)
    assert np.abs(x - ref.x).max() <= 1e-3 * system.spacing
    no_flex = springs.cloth(n, n, 0.05, k_structural=500.0, k_shear=200.0,
                            damping_structural=0.05, mass=0.01, fixed=fixed,
                            velocity_damping=0.01)
    other = reference(no_flex, name, dt, 30, state)
    assert np.abs(other.x - ref.x).max() > 100 * np.abs(x - ref.x).max()


def test_flexion_neighbours_never_bridge_a_hole():
    occupied = np.ones((5, 1, 1), bool)
    occupied[2] = False  # nodes 0 1 _ 3 4 along x
    grid = NodeGrid(np.zeros(3), 1.0, occupied)
    nb = grid_neighbours(grid, True)
    assert nb.shape == (4, 24)
    # +x flexion (column 18): node 0 -> the node at x=2 is absent; node 1 -> x=3 is bridging
    assert list(nb[:, 18]) == [-1, -1, -1, -1]
    full = NodeGrid(np.zeros(3), 1.0, np.ones((4, 1, 1), bool))
    assert list(grid_neighbours(full, True)[:, 18]) == [2, 3, -1, -1]
    assert list(grid_neighbours(full, True)[:, 19]) == [-1, -1, 0, 1]


def test_rejects_systems_that_are_not_the_grids(ctx):
    system, grid = damped_grid(3)
    other = NodeGrid(grid.origin, grid.spacing, np.ones((3, 3, 4), bool))
    with pytest.raises(ValueError, match="nodes"):
        FragmentIntegrator(ctx, system, other, "euler", 1e-3)
    mesh = springs.from_triangle_mesh(grid.rest_positions, [[0, 1, 3], [1, 4, 3]] * 1,
                                      stiffness=10.0)
    with pytest.raises(ValueError, match="not those of the grid"):
        FragmentIntegrator(ctx, mesh, grid, "euler", 1e-3)
    with pytest.raises(ValueError, match="integrator"):
        FragmentIntegrator(ctx, system, grid, "leapfrog", 1e-3)


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_no_read_back_while_stepping(ctx, name, monkeypatch):
    calls: list[str] = []

    def spy(cls, method):
        original = getattr(cls, method)

        def wrapper(self, *args, **kwargs):
            calls.append(f"{cls.__name__}.{method}")
            return original(self, *args, **kwargs)
        monkeypatch.setattr(cls, method, wrapper)

    for cls, method in ((moderngl.Buffer, "read"), (moderngl.Buffer, "read_into"),
                        (moderngl.Texture, "read"), (moderngl.Texture, "read_into"),
                        (moderngl.Framebuffer, "read"), (moderngl.Framebuffer, "read_into")):
        spy(cls, method)
    system, grid = damped_grid(3)
    sim = FragmentIntegrator(ctx, system, grid, name, 1e-3, constraints=Constraints(
        ground=0.0, spheres=(Sphere((0, 0, 0), 0.1),)))
    try:
        sim.step(5)
        assert calls == []
        sim.positions()  # the spy does see the explicit accessor
        assert "Texture.read" in calls
    finally:
        sim.release()


def test_generated_source_compiles_only_what_is_used(ctx):
    plain, grid = damped_grid(3, spring_damping=0.0, k_flexion=0.0)
    assert not np.any(plain.damping > 0)
    sim = FragmentIntegrator(ctx, plain, grid, "verlet", 1e-3)
    try:
        prog = sim.passes["step"]
        text = prog.fragment_source.text
        assert "#define VERLET" in text and "#define NB_LAYERS 5" in text and "#define DENSE" in text
        assert "#define NB_COUNT 18" in text and "#define SPHERES 0" in text
        for absent in ("#define SPRING_DAMPING", "#define CONSTRAINTS", "#define VELOCITY",
                       "#define GROUND", "#define EULER", "#define RK4_STAGE"):
            assert absent not in text
        members = set(prog.gl._members)
        assert {"u_x", "u_x_prev", "u_node", "u_offsets", "u_k"} <= members  # a full block: dense
        assert not members & {"u_ground", "u_spheres", "u_sphere_velocity", "u_v", "u_c", "u_neighbours"}
        assert sim.state_bytes_per_node == I.memory_per_node("verlet") == 48
    finally:
        sim.release()

    damped, grid = damped_grid(3)
    sim = FragmentIntegrator(ctx, damped, grid, "rk4", 1e-3, constraints=Constraints(
        ground=0.0, spheres=(Sphere((0, 0, 0), 1),)))
    try:
        assert set(sim.passes) == {"stage1", "stage2", "stage3", "step"}
        final = sim.passes["step"]
        for present in ("#define SPRING_DAMPING", "#define CONSTRAINTS", "#define VELOCITY",
                        "#define GROUND", "#define SPHERES 1", "#define RK4_FINAL",
                        "#define NB_LAYERS 6", "#define NB_COUNT 24"):
            assert present in final.fragment_source.text
        assert {"u_ground", "u_spheres", "u_sphere_velocity", "u_xs", "u_sum_x",
                "u_c"} <= set(final.gl._members)
        stage1 = sim.passes["stage1"]
        assert "#define RK4_STAGE 1" in stage1.fragment_source.text
        assert not set(stage1.gl._members) & {"u_ground", "u_spheres", "u_xs", "u_sum_x"}
        assert sim.state_bytes_per_node == I.memory_per_node("rk4") == 160
    finally:
        sim.release()


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_bytes_per_node_is_what_is_allocated(ctx, name):
    system = springs.cloth(16, 16, 0.05, k_structural=100.0, k_shear=50.0, k_flexion=10.0)
    grid = NodeGrid(np.zeros(3), 0.05, np.ones((16, 1, 16), bool))
    sim = FragmentIntegrator(ctx, system, grid, name, 1e-3)
    try:
        assert sim.layout.size == (16, 16)  # no padding: state bytes are exact per node
        assert sim.state_bytes_per_node == I.memory_per_node(name)
        assert sim.dense  # a full sheet: neighbours by offsets, the node data only
        assert sim.bytes_per_node == I.memory_per_node(name) + 16
    finally:
        sim.release()
    occupied = np.ones((16, 1, 16), bool)
    occupied[0, 0, 0] = False  # a missing corner: the neighbour table comes back
    holed = NodeGrid(np.zeros(3), 0.05, occupied)
    system = springs.from_grid(holed, k_structural=100.0, k_shear=50.0, k_flexion=10.0)
    sim = FragmentIntegrator(ctx, system, holed, name, 1e-3)
    try:
        assert not sim.dense
        w, h = sim.layout.size
        static = (16 + 6 * 16) * w * h / holed.count  # node data + 6 neighbour layers (24 neighbours)
        assert sim.bytes_per_node == pytest.approx(I.memory_per_node(name) * w * h / holed.count + static)
    finally:
        sim.release()


def test_release_and_constructor_failure_clean_up(ctx, monkeypatch):
    made: list = []
    original_texture, original_array = moderngl.Context.texture, moderngl.Context.texture_array

    def texture(self, *args, **kwargs):
        made.append(original_texture(self, *args, **kwargs))
        return made[-1]

    def texture_array(self, *args, **kwargs):
        made.append(original_array(self, *args, **kwargs))
        return made[-1]
    monkeypatch.setattr(moderngl.Context, "texture", texture)
    monkeypatch.setattr(moderngl.Context, "texture_array", texture_array)
    system, grid = damped_grid(3)

    def released(obj) -> bool:
        return type(obj.mglo).__name__ == "InvalidObject"

    from deformgl.sim.backends import explicit_gpu as fragment_integrators

    def broken(*args, **kwargs):
        raise RuntimeError("no program")
    with monkeypatch.context() as m:
        m.setattr(fragment_integrators, "Program", broken)
        with pytest.raises(RuntimeError, match="no program"):
            FragmentIntegrator(ctx, system, grid, "midpoint", 1e-3)
    assert len(made) == 7 and all(released(o) for o in made)  # node data + 6 midpoint states (dense: no neighbour texture)
    made.clear()
    sim = FragmentIntegrator(ctx, system, grid, "rk4", 1e-3)
    sim.step(1)
    assert made and not any(released(o) for o in made)
    fbos = list(sim._fbos.values())
    assert fbos
    sim.release()
    assert all(released(o) for o in made + fbos)
    with pytest.raises(RuntimeError, match="released"):
        sim.step(1)
    sim.release()  # idempotent


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_moving_sphere_matches_reference(ctx, name):
    """A sphere rising into a resting block: centres at t + dt and the obstacle-velocity rule."""
    system, grid = damped_grid(3, fixed_nodes=(), spring_damping=0.05)
    dt = 2e-3
    sphere = Sphere(centre=lambda t: (0.3, 0.38 + 2.0 * t, 0.0), radius=0.05)
    constraints = Constraints(spheres=(sphere,))
    state = I.initial_state(system, dt)
    sim = FragmentIntegrator(ctx, system, grid, name, dt, state=state, constraints=constraints)
    try:
        sim.step(20)
        x, v = sim.positions().astype(np.float64), sim.velocities().astype(np.float64)
    finally:
        sim.release()
    ref = reference(system, name, dt, 20, state, constraints)
    free = reference(system, name, dt, 20, state)
    assert np.abs(free.x - ref.x).max() > 1e-2 * system.spacing  # the sphere pushed
    scale = np.abs(ref.x).max()
    assert np.abs(x - ref.x).max() <= 1e-5 * scale
    err = np.abs(v - ref.v).max(axis=1)
    if name == "verlet":
        assert err.max() <= 4 * EPS32 * scale / dt
    else:
        # a node grazing the sphere within float32 rounding of its surface may be in contact
        # for one precision and not the other; every other node matches closely
        gap = np.abs(np.linalg.norm(ref.x - sphere.centre_at(20 * dt), axis=1) - sphere.radius)
        grazing = gap < 1e-5 * scale
        assert np.sum(grazing) <= 3
        assert err[~grazing].max() <= 1e-4 * np.abs(ref.v).max()


@pytest.mark.parametrize("name", ["verlet", "rk4"])
def test_dense_grids_find_neighbours_by_arithmetic_with_the_same_result(ctx, monkeypatch, name):
    """A full block (and a sheet, with flexion) gives bit-identical steps with the neighbour
    texture and with node-number offsets; a grid with a hole keeps the texture."""
    from deformgl.grid.nodes import CompactLayout

    system, grid = damped_grid(4)
    results = {}
    for dense in (True, False):
        monkeypatch.setattr(CompactLayout, "dense", property(lambda self, d=dense: d and self.count == self.index.size))
        sim = FragmentIntegrator(ctx, system, grid, name, 1e-3)
        try:
            assert sim.dense is dense and (sim.tex_neighbours is None) is dense
            sim.step(20)
            results[dense] = sim.positions()
        finally:
            sim.release()
    np.testing.assert_array_equal(results[True], results[False])
    assert np.abs(results[True] - system.rest_positions).max() > 0  # it moved
    monkeypatch.undo()
    occupied = np.ones((4, 4, 4), bool)
    occupied[1, 1, 1] = False
    holed = NodeGrid(np.zeros(3), 0.1, occupied)
    from deformgl.sim.springs import from_grid

    sim = FragmentIntegrator(ctx, from_grid(holed, k_structural=10.0, k_shear=10.0, mass=0.01), holed, name, 1e-3,
                             path="general")
    try:
        assert not sim.dense and sim.tex_neighbours is not None
    finally:
        sim.release()


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_passes_and_rotation_come_from_the_stage_table(ctx, name):
    from deformgl.sim.stages import spec

    s = spec(name)
    system, grid = damped_grid(3)
    sim = FragmentIntegrator(ctx, system, grid, name, 1e-3)
    try:
        assert list(sim.passes) == [st.name for st in s.stages]
        assert len(sim.pool) == len(s.buffers)
        roles = list(sim.roles)
        sim.step(1)
        assert sim.roles == s.rotate(roles)
        sim.step(1)
        assert sim.roles == s.rotate(s.rotate(roles))
        # what plays x is what the last stage wrote its positions into
        assert sim.position_slot()[0] is sim.pool[sim.roles[s.buffers.index("x")]]
    finally:
        sim.release()
