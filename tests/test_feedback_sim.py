"""The transform-feedback backend (Movania & Feng 2012) against the float64 reference."""

from __future__ import annotations

import moderngl
import numpy as np
import pytest

from deformgl.sim import integrators as I
from deformgl.sim import scripted, springs
from deformgl.sim.backends.feedback import FeedbackSimulation
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
    return springs.from_grid(grid, **options)


def run(ctx, system, name, dt, steps, **kwargs):
    sim = FeedbackSimulation(ctx, system, name, dt, **kwargs)
    try:
        sim.step(steps)
        return sim.positions().astype(np.float64), sim.velocities().astype(np.float64)
    finally:
        sim.release()


def reference(system, name, dt, steps, state, constraints=None, drags=()):
    s = state
    for k in range(steps):
        s = I.step(system, name, s, dt, k * dt, constraints=constraints, drags=drags)
    return s


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_one_step_matches_reference(ctx, name):
    system = damped_grid()
    dt = 1e-3
    state = I.initial_state(system, dt, v=np.random.default_rng(1).normal(size=(27, 3)))
    x, v = run(ctx, system, name, dt, 1, state=state)
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
    system = damped_grid(4, fixed_nodes=(0, 3, 12, 15), spring_damping=0.2)
    dt = 2e-3
    state = I.initial_state(system, dt, v=np.random.default_rng(2).normal(size=(64, 3)) * 0.2)
    x, _ = run(ctx, system, name, dt, 100, state=state)
    ref = reference(system, name, dt, 100, state)
    assert np.abs(ref.x - state.x).max() > 0.1 * system.spacing  # it really moved
    assert np.abs(x - ref.x).max() <= 1e-3 * system.spacing


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_fixed_nodes_bit_identical(ctx, name):
    system = damped_grid(3, fixed_nodes=(0, 2, 20))
    dt = 1e-3
    state = I.initial_state(system, dt, v=np.random.default_rng(3).normal(size=(27, 3)))
    sim = FeedbackSimulation(ctx, system, name, dt, state=state,
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
    system = damped_grid(3, fixed_nodes=(), spring_damping=0.05)
    dt = 2e-3
    ground = 0.45  # below the sphere: the two never conflict
    sphere = Sphere(centre=(0.3, 0.52, 0.0), radius=0.05)
    constraints = Constraints(ground=ground, spheres=(sphere,))
    v0 = np.tile([0.0, -4.0, 0.0], (27, 1))
    state = I.initial_state(system, dt, v=v0)
    sim = FeedbackSimulation(ctx, system, name, dt, state=state, constraints=constraints)
    s = state
    contacts = sphere_contacts = 0
    try:
        for k in range(10):
            sim.step(1)
            s = I.step(system, name, s, dt, k * dt, constraints=constraints)
            x32 = sim.positions()
            # the GPU works in float32: its ground is float32(0.45), a little below 0.45
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


def test_moving_sphere_and_drags_match_reference(ctx):
    system = damped_grid(3, fixed_nodes=(0,))
    dt = 1e-3
    sphere = Sphere(centre=lambda t: (0.25 + 20.0 * t, 0.6, 0.0), radius=0.08)
    drags = (scripted.Drag(13, lambda t: (0.3, 0.7 + t, 0.0), 30.0),
             scripted.Drag(26, lambda t: (0.5, 0.8, 0.2 - 5.0 * t), 10.0))
    constraints = Constraints(ground=0.5, spheres=(sphere,))
    for name in EXPLICIT_INTEGRATORS:
        state = I.initial_state(system, dt, drags=drags)
        x, v = run(ctx, system, name, dt, 10, state=state, constraints=constraints, drags=drags)
        ref = reference(system, name, dt, 10, state, constraints, drags)
        assert np.abs(x - ref.x).max() <= 1e-5 * np.abs(ref.x).max(), name
        free = reference(system, name, dt, 10, state)  # without the obstacles and the drags
        free_drags = reference(system, name, dt, 10, state, drags=drags)
        assert np.abs(free.x - ref.x).max() > 1e-3 * system.spacing, name
        assert np.abs(free.x - free_drags.x).max() > 1e-4 * system.spacing, name


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_triangle_mesh_matches_reference(ctx, name):
    trimesh = pytest.importorskip("trimesh")
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.5)
    fixed = sphere.vertices[:, 1] > 0.45
    system = springs.from_triangle_mesh(sphere.vertices, sphere.faces, stiffness=40.0,
                                        damping=0.05, mass=0.02, fixed=fixed,
                                        velocity_damping=0.01)
    assert 3 < fixed.sum() < 20
    dt = 1e-3
    n = system.count
    state = I.initial_state(system, dt, v=np.random.default_rng(4).normal(size=(n, 3)) * 0.1)
    x1, _ = run(ctx, system, name, dt, 1, state=state)
    ref1 = I.step(system, name, state, dt, 0.0)
    assert np.abs(x1 - ref1.x).max() <= 1e-5 * np.abs(ref1.x).max()
    x, _ = run(ctx, system, name, dt, 50, state=state)
    ref = reference(system, name, dt, 50, state)
    assert np.abs(x - ref.x).max() <= 1e-3 * system.spacing


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
    system = damped_grid(3)
    sim = FeedbackSimulation(ctx, system, name, 1e-3,
                             constraints=Constraints(ground=0.0, spheres=(Sphere((0, 0, 0), 0.1),)))
    try:
        sim.step(5)
        assert calls == []
        sim.positions()  # the spy does see the explicit accessor
        assert "Texture.read" in calls
    finally:
        sim.release()


def test_generated_source_compiles_only_what_is_used(ctx):
    plain = damped_grid(3, spring_damping=0.0)
    assert not np.any(plain.damping > 0)
    sim = FeedbackSimulation(ctx, plain, "verlet", 1e-3)
    try:
        prog = sim._passes["step"].program
        text = prog.vertex_source.text
        assert "#define NODE_ROW 32" in text
        for absent in ("#define SPRING_DAMPING", "#define CONSTRAINTS", "#define VELOCITY",
                       "#define GROUND"):
            assert absent not in text
        assert "#define SPHERES 0" in text and "#define DRAGS 0" in text
        members = set(prog.gl._members)
        assert {"u_x", "u_x_prev", "u_nodes", "u_springs"} <= members
        assert not members & {"u_ground", "u_spheres", "u_sphere_velocity", "u_state"}
        assert sim.state_bytes_per_node == I.memory_per_node("verlet") == 48
    finally:
        sim.release()

    damped = damped_grid(3)
    sim = FeedbackSimulation(ctx, damped, "rk4", 1e-3,
                             constraints=Constraints(ground=0.0, spheres=(Sphere((0, 0, 0), 1),)))
    try:
        assert set(sim._passes) == {"stage1", "stage2", "stage3", "step"}
        final = sim._passes["step"].program
        for present in ("#define SPRING_DAMPING", "#define CONSTRAINTS", "#define VELOCITY",
                        "#define GROUND", "#define SPHERES 1"):
            assert present in final.vertex_source.text
        assert {"u_ground", "u_spheres", "u_sphere_velocity", "u_stage"} <= set(final.gl._members)
        stage1 = sim._passes["stage1"].program
        assert "#define RK4_STAGE 1" in stage1.vertex_source.text
        assert not set(stage1.gl._members) & {"u_ground", "u_spheres", "u_stage"}
        assert sim.state_bytes_per_node == I.memory_per_node("rk4") == 160
    finally:
        sim.release()


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_bytes_per_node_is_what_is_allocated(ctx, name):
    system = springs.cloth(16, 16, 0.05, k_structural=100.0, k_shear=50.0, k_flexion=10.0)
    sim = FeedbackSimulation(ctx, system, name, 1e-3)
    try:
        assert sim.node_row * sim.rows == 256  # no padding: state bytes are exact per node
        assert sim.state_bytes_per_node == I.memory_per_node(name)
        entries = 2 * system.spring_count  # each spring in the list of both ends
        padded = sim.spring_row * -(-entries // sim.spring_row)
        assert padded - entries < sim.spring_row
        lists = padded * (4 + 16)  # other node (R32I) + parameters (RGBA32F)
        static = 256 * 16 + lists
        assert sim.bytes_per_node == (I.memory_per_node(name) * 256 + static) / 256
    finally:
        sim.release()


def test_release_and_constructor_failure_clean_up(ctx, monkeypatch):
    made: list = []
    original_texture, original_buffer = moderngl.Context.texture, moderngl.Context.buffer

    def texture(self, *args, **kwargs):
        made.append(original_texture(self, *args, **kwargs))
        return made[-1]

    def buffer(self, *args, **kwargs):
        made.append(original_buffer(self, *args, **kwargs))
        return made[-1]
    monkeypatch.setattr(moderngl.Context, "texture", texture)
    monkeypatch.setattr(moderngl.Context, "buffer", buffer)
    system = damped_grid(3)

    def released(obj) -> bool:
        return type(obj.mglo).__name__ == "InvalidObject"

    from deformgl.sim.backends import feedback as feedback_sim

    def broken(*args, **kwargs):
        raise RuntimeError("no program")
    with monkeypatch.context() as m:
        m.setattr(feedback_sim, "Program", broken)
        with pytest.raises(RuntimeError, match="no program"):
            FeedbackSimulation(ctx, system, "midpoint", 1e-3)
    assert len(made) >= 4 and all(released(o) for o in made)
    made.clear()
    sim = FeedbackSimulation(ctx, system, "rk4", 1e-3)
    assert made and not any(released(o) for o in made)
    sim.release()
    assert all(released(o) for o in made)
    with pytest.raises(RuntimeError, match="released"):
        sim.step(1)
    sim.release()  # idempotent


@pytest.mark.parametrize("name", ["semi-implicit", "rk4", "verlet"])
def test_cloth_over_several_texture_rows_matches_reference(ctx, name):
    """64x64 cloth: 4 rows of 1024 nodes, the neighbour lists over 12 rows of 4096 entries."""
    fixed = np.zeros(64 * 64, bool)
    fixed[[0, 63]] = True
    system = springs.cloth(64, 64, 0.02, k_structural=500.0, k_shear=200.0, k_flexion=50.0,
                           damping_structural=0.05, mass=0.01, fixed=fixed,
                           velocity_damping=0.01)
    dt = 1e-3
    state = I.initial_state(system, dt,
                            v=np.random.default_rng(5).normal(size=(system.count, 3)) * 0.1)
    sim = FeedbackSimulation(ctx, system, name, dt, state=state)
    try:
        assert sim.rows == 4 and sim.spring_row == 4096
        assert -(-2 * system.spring_count // sim.spring_row) > 1
        sim.step(3)
        x = sim.positions().astype(np.float64)
    finally:
        sim.release()
    ref = reference(system, name, dt, 3, state)
    assert np.abs(x - ref.x).max() <= 1e-5 * np.abs(ref.x).max()


def test_mesh_springs_example_drops_a_shell_on_the_obstacles(ctx, tmp_path):
    """examples/mesh_springs_example.py: springs on the edges of an icosphere (no grid) on the
    feedback backend land on the sphere and the ground, and are drawn to a PNG."""
    import importlib.util
    from pathlib import Path

    from PIL import Image

    path = Path(__file__).resolve().parent.parent / "examples" / "mesh_springs_example.py"
    spec = importlib.util.spec_from_file_location("mesh_springs_example", path)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    system, _, constraints = example.shell_system()
    assert system.class_counts() == {"structural": 1920, "shear": 0, "flexion": 0}  # the edges
    x = example.run(tmp_path / "shell.png", steps=600)
    assert x[:, 1].min() >= constraints.ground - 1e-6
    sphere = constraints.spheres[0]
    assert np.linalg.norm(x - sphere.centre_at(0.0), axis=1).min() >= sphere.radius * (1 - 1e-5)
    assert x[:, 1].min() < 0.05 * system.spacing + constraints.ground or \
        np.linalg.norm(x - sphere.centre_at(0.0), axis=1).min() < sphere.radius + system.spacing  # it landed
    image = np.asarray(Image.open(tmp_path / "shell.png"))
    assert image.shape == (360, 480, 3) and len(np.unique(image.reshape(-1, 3), axis=0)) > 50


@pytest.mark.parametrize("name", ["euler", "verlet"])
def test_release_leaves_no_renderbuffer_or_framebuffer(ctx, monkeypatch, name):
    from deformgl.gl.resources import is_released

    made: list = []
    for method in ("renderbuffer", "depth_renderbuffer", "framebuffer"):
        original = getattr(moderngl.Context, method)

        def spy(self, *args, _original=original, **kwargs):
            made.append(_original(self, *args, **kwargs))
            return made[-1]
        monkeypatch.setattr(moderngl.Context, method, spy)
    sim = FeedbackSimulation(ctx, damped_grid(3), name, 1e-3)
    sim.step(2)
    assert any(isinstance(o, moderngl.Renderbuffer) for o in made)
    assert all(any(o is owned for owned in sim._owned) for o in made)  # every one is owned
    sim.release()
    assert made and all(is_released(o) for o in made)


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_passes_come_from_the_stage_table(ctx, name):
    from deformgl.sim.stages import spec

    s = spec(name)
    sim = FeedbackSimulation(ctx, damped_grid(3), name, 1e-3)
    try:
        assert list(sim._passes) == [st.name for st in s.stages]
        for st in s.stages:
            p = sim._passes[st.name]
            assert p.slots == len(st.writes)
            assert p.program.vertex_source.files[0] == st.vertex
            assert ("#define VELOCITY" in p.program.vertex_source.text) == s.velocity
    finally:
        sim.release()
