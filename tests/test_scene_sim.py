"""A scene's physics on every integrator and backend: same function, constraints, convergence."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from deformgl.sim import integrators as I
from deformgl.errors import SimulationError
from deformgl.sim.integrators import EXPLICIT_INTEGRATORS
from deformgl.scene.pipeline import NodeState, build_scene_model
from deformgl.scene.schema import load_scene
from deformgl.scene.spec import Converge, Safety
from deformgl.scene.physics import SceneBox, simulate_scene, scene_constraints, scene_drags, scene_loads, scene_system

SCENES = Path(__file__).resolve().parent.parent / "scenes"

EXTENDED = '''
[physics.springs]
structural = { damping = 0.001 }
flexion = { stiffness = 2.0, damping = 0.0005 }

[physics.ground]
at = 0.02

[[physics.sphere]]
path = [[1.3, 0.5, 0.5], [0.8, 0.5, 0.5]]
times = [0.0, 0.05]
radius = 0.2

[[physics.drag]]
path = [[0.0, 1.0, 0.0], [-0.2, 1.1, -0.1]]
times = [0.0, 0.05]
stiffness = 0.5
'''


@pytest.fixture(scope="module")
def extended_scene(tmp_path_factory):
    """The jelly with every extended feature: classes, spring damping, flexion, wind, ground,
    a moving sphere, a drag; and its pull (a load)."""
    text = (SCENES / "jelly_springs.toml").read_text()
    text = text.replace('path = "assets/jelly_block.obj"', f'path = "{SCENES / "assets" / "jelly_block.obj"}"')
    text = text.replace("[[physics.fixed]]", "wind = [0.5, 0.0, 0.2]\nwind_drag = 0.0002\n\n[[physics.fixed]]", 1)
    text = text.replace("steps = 300", "steps = 120") + EXTENDED
    path = tmp_path_factory.mktemp("scene") / "jelly_extended.toml"
    path.write_text(text)
    scene = load_scene(path)
    return scene, build_scene_model(scene)


def run(ctx, scene, built, **physics):
    """Run with physics overrides; these tests compare backends, forward Euler and midpoint
    included, at dts above those two's damped limits (slowly growing runs), so the dt check is
    set to run anyway (test_safety.py tests the check)."""
    physics.setdefault("safety", Safety(unstable="run"))
    scene = dataclasses.replace(scene, physics=dataclasses.replace(scene.physics, **physics))
    return simulate_scene(ctx, scene, built.grid, scene_system(built.grid, scene.physics, built.bbox),
                     scene_loads(built.grid, scene.physics, built.bbox), SceneBox(*built.bbox), progress=False)


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_every_backend_runs_the_same_scene(ctx, extended_scene, name):
    scene, built = extended_scene
    ref = run(ctx, scene, built, integrator=name, backend="numpy")
    h = built.grid.spacing
    moved = np.abs(ref.positions - built.grid.rest_positions).max()
    assert moved > 0.1 * h  # something happened
    for backend in ("fragment", "feedback"):
        gpu = run(ctx, scene, built, integrator=name, backend=backend)
        assert gpu.steps == ref.steps == 120
        assert np.abs(gpu.positions - ref.positions).max() <= 1e-3 * h, backend
        assert gpu.bytes_per_node > 0


def test_constraints_fixed_nodes_and_drag_hold_in_the_scene(ctx, extended_scene):
    scene, built = extended_scene
    box = SceneBox(*built.bbox)
    constraints = scene_constraints(scene.physics, box)
    for backend in ("fragment", "feedback"):
        out = run(ctx, scene, built, integrator="semi-implicit", backend=backend)
        fixed = built.system.fixed
        x = out.positions
        assert x[~fixed, 1].min() >= constraints.ground - 1e-6  # fixed nodes stay where they are
        assert x[fixed, 1].min() < constraints.ground  # (some start below the ground)
        sphere = constraints.spheres[0]
        gap = np.linalg.norm(x[~fixed] - sphere.centre_at(out.time), axis=1) - sphere.radius
        assert gap.min() >= -1e-5 * sphere.radius and gap.min() < 0.05 * sphere.radius  # touched
        assert np.array_equal(x[fixed].astype(np.float32), built.grid.rest_positions[fixed].astype(np.float32))
    # the drag grabbed the node nearest to its first point
    (drag,) = scene_drags(built.grid, scene.physics, box)
    start = box.world((0.0, 1.0, 0.0))
    assert drag.node == int(np.argmin(np.linalg.norm(built.grid.rest_positions - start, axis=1)))
    np.testing.assert_allclose(drag.target(1.0), box.world((-0.2, 1.1, -0.1)))


def test_convergence_stop_is_counted_on_the_gpu(ctx, extended_scene, monkeypatch):
    """The displacement criterion: all three backends stop at the same check; the GPU ones read
    no state while stepping."""
    scene, built = extended_scene
    settle = dict(integrator="semi-implicit", steps=4000, damping=0.02,
                  converge=Converge("displacement", threshold=0.001, every=10))
    ref = run(ctx, scene, built, backend="numpy", **settle)
    assert ref.converged and ref.steps < 4000
    import moderngl

    reads = []
    original = moderngl.Texture.read
    monkeypatch.setattr(moderngl.Texture, "read", lambda self, *a, **k: reads.append(self) or original(self, *a, **k))
    for backend in ("fragment", "feedback"):
        reads.clear()
        out = run(ctx, scene, built, backend=backend, **settle)
        assert out.converged and abs(out.steps - ref.steps) <= 10, (backend, out.steps, ref.steps)
        assert len(reads) == 1  # the final positions only
    capped = run(ctx, scene, built, backend="fragment", **{**settle, "steps": 50})
    assert capped.converged is False and capped.steps == 50


def test_divergence_is_an_error_naming_a_node(ctx, extended_scene):
    scene, built = extended_scene
    with pytest.raises(SimulationError, match=r"blew up: at step 100 .* first node \d+ \(grid \(.*\)\) at"):
        run(ctx, scene, built, integrator="euler", backend="feedback", dt=0.05, steps=200)


def test_plain_scenes_draw_from_the_verlet_fast_path(ctx, monkeypatch):
    """A scene the foundation pass models runs on it by itself and is drawn from its state
    texture (packed normals): nothing is read back. Any other integrator or backend reads the
    positions once and drives the node textures."""
    import moderngl

    scene = load_scene(SCENES / "jelly_springs.toml").with_overrides(steps=3)
    built = build_scene_model(scene)
    reads = []
    original = moderngl.Texture.read
    monkeypatch.setattr(moderngl.Texture, "read", lambda self, *a, **k: reads.append(self) or original(self, *a, **k))
    state = NodeState(ctx, scene, built, progress=False)
    try:
        assert state.sim is not None and state.sim.fast is not None and state.sim.packed_normals
        assert state.run is not None and state.run.positions is None and state.run.steps == 3
        assert state.position_texture is state.sim.fast.position_texture
        assert reads == []
    finally:
        state.release()
    for override in (dict(integrator="rk4"), dict(backend="feedback"), dict(backend="numpy")):
        state = NodeState(ctx, scene.with_overrides(**override), built, progress=False)
        try:
            assert state.sim is None and state.driven is not None and state.run.positions is not None
        finally:
            state.release()


def test_verlet_fast_path_and_the_general_verlet_stage_are_the_same_function(ctx):
    """On the jelly scene (pull loads, fixed nodes, damping) the fragment backend's two Verlet
    paths compute the same steps from the same state (the default: the reference's Taylor start)."""
    from deformgl.sim.simulation import make_simulation

    scene = load_scene(SCENES / "jelly_springs.toml")
    built = build_scene_model(scene)
    ph = scene.physics
    x = {}
    for path in ("foundation", "general"):
        sim = make_simulation(built.system, "verlet", "fragment", ctx=ctx, dt=ph.dt, loads=built.loads, path=path)
        try:
            assert (sim.fast is not None) is (path == "foundation")
            sim.step(100)
            x[path] = sim.positions().astype(np.float64)
        finally:
            sim.release()
    x0 = built.grid.rest_positions
    assert np.abs(x["foundation"] - x0).max() > 0.05 * built.grid.spacing
    # float32 rounding only: 100 steps, ~1e-5 h
    assert np.abs(x["general"] - x["foundation"]).max() <= 1e-4 * built.grid.spacing
    ref = I.simulate(built.system, "verlet", ph.dt, 100, loads=built.loads).x
    assert np.abs(x["foundation"] - ref).max() <= 1e-4 * built.grid.spacing


def test_cloth_scene_builds_a_sheet_with_pinned_corners():
    scene = load_scene(SCENES / "cloth_64.toml")
    built = build_scene_model(scene)
    assert built.grid.occupied.shape == (64, 1, 64) and built.grid.count == 4096
    assert built.system.fixed.sum() == 4
    corners = built.grid.ijk[built.system.fixed]
    assert {(int(i), int(k)) for i, _, k in corners} == {(0, 0), (0, 63), (63, 0), (63, 63)}
    np.testing.assert_allclose(built.grid.spacing, 1.0 / 63)
    assert scene.physics.class_stiffness() == (50.0, 50.0, 5.0)


@pytest.mark.parametrize("n", [256, 1024, 2048])
def test_finer_cloths_are_the_same_cloth(n):
    """Mass per node ~ h^2, damping ~ h^2 (global) and ~ h (springs), dt ~ h, same end time."""
    base = load_scene(SCENES / "cloth_64.toml").physics
    fine = load_scene(SCENES / f"cloth_{n}.toml").physics
    r = n / 64
    assert fine.mass * n * n == pytest.approx(base.mass * 64 * 64, rel=1e-3)
    assert fine.dt * r == pytest.approx(base.dt) and fine.steps == base.steps * r
    assert fine.class_stiffness() == base.class_stiffness()
    assert fine.structural.damping * r == pytest.approx(base.structural.damping, rel=1e-3)
    built = build_scene_model(load_scene(SCENES / f"cloth_{n}.toml"))
    assert built.system.fixed.sum() == 4
