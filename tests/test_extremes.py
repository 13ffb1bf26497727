"""The extremes, each with its defined outcome: stable and finite, or refused / detected with a
clear message; never silent garbage.

* stiffness 1e-3 .. 1e6 N/m and mass 1e-6 .. 1e3 kg, spacing 1e-4 .. 0.1 m: at half the exact
  limit the GPU runs the same dimensionless motion (the top eigenmode, damped) for every scale;
* dt at 0.5x and 1.5x the limit, every integrator: decays at 0.5x; at 1.5x ``check_dt`` refuses
  it and, run anyway, the GPU census counts the blown-up nodes;
* grids from 2x2x2 to the texture limit, one-node-thin sheets;
* a mesh 1e6 from the origin (float32 keeps ~7 digits: recentring is what makes it work, shown
  by the same run without it) and a mesh whose grid spacing is 1e-4.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

from deformgl.sim import integrators as I
from deformgl.sim.census import NodeCensus
from deformgl.sim.backends.explicit_gpu import FragmentIntegrator
from deformgl.sim.backends.feedback import FeedbackSimulation
from deformgl.grid.nodes import CompactLayout, NodeGrid
from deformgl.scene.pipeline import build_scene_model, render_scene
from deformgl.scene.schema import load_scene
from deformgl.sim.springs import SpringSystem, cloth, from_grid
from deformgl.sim.limits import check_dt, dt_limit, spectral_radius
from deformgl.sim.spectrum import exact_frequency

SCENES = Path(__file__).resolve().parent.parent / "scenes"
ZETA = 0.1  # damping ratio of the top mode
AMPLITUDE = 0.1  # initial top-mode amplitude, grid spacings


def block(k: float, m: float, h: float, *, shape=(4, 4, 4), origin=(0.0, 0.0, 0.0), zeta: float = ZETA) -> SpringSystem:
    """A block of nodes, bottom layer fixed, no gravity, damped to ``zeta`` on its top mode."""
    grid = NodeGrid(np.asarray(origin, np.float64), h, np.ones(shape, bool))
    fixed = grid.ijk[:, 1] == 0
    opts = dict(k_structural=k, k_shear=k, mass=m, fixed=fixed, gravity=(0.0, 0.0, 0.0))
    w = exact_frequency(from_grid(grid, **opts)).omega
    return from_grid(grid, velocity_damping=2.0 * zeta * m * w, **opts), grid


def top_mode_start(system: SpringSystem, h: float, dt: float) -> I.State:
    mode = exact_frequency(system).mode
    return I.initial_state(system, dt, x=system.rest_positions + AMPLITUDE * h * mode)


def run_fragment(ctx, system, grid, integrator, dt, steps) -> np.ndarray:
    sim = FragmentIntegrator(ctx, system, grid, integrator, dt, state=top_mode_start(system, grid.spacing, dt))
    try:
        sim.step(steps)
        return sim.positions().astype(np.float64)
    finally:
        sim.release()


def run_backend(ctx, backend, system, grid, dt, steps) -> np.ndarray:
    """Verlet from rest on the fragment or feedback backend: final positions, float64."""
    sim = (FragmentIntegrator(ctx, system, grid, "verlet", dt) if backend == "fragment"
           else FeedbackSimulation(ctx, system, "verlet", dt))
    try:
        sim.step(steps)
        return sim.positions().astype(np.float64)
    finally:
        sim.release()


@pytest.fixture(scope="module")
def base_motion(ctx):
    """The dimensionless motion (displacement / h after 60 steps at half the limit) of the base
    block, k = 10 N/m, m = 0.01 kg, h = 0.1 m, per integrator."""
    out = {}
    for name in ("verlet", "rk4"):
        system, grid = block(10.0, 0.01, 0.1)
        dt = 0.5 * dt_limit(system, name, exact=True).dt
        out[name] = (run_fragment(ctx, system, grid, name, dt, 60) - system.rest_positions) / 0.1
    return out


@pytest.mark.parametrize("k, m, h", [
    (1e-3, 1e-2, 0.1), (1e6, 1e-2, 0.1),  # stiffness extremes
    (10.0, 1e-6, 0.1), (10.0, 1e3, 0.1),  # mass extremes
    (1e-3, 1e3, 0.1), (1e6, 1e-6, 0.1),  # w from 1e-3 to 1e6 rad/s
    (10.0, 1e-2, 1e-4), (1e6, 1e-6, 1e-4),  # tiny spacing
])
@pytest.mark.parametrize("name", ["verlet", "rk4"])
def test_stiffness_mass_and_spacing_extremes_run_the_same_dimensionless_motion(ctx, base_motion, k, m, h, name):
    """w = sqrt(k/m) spans 1e-3 .. 1e6 rad/s and the limit dt 1e-6 .. 1e3 s; at half the limit the
    float32 GPU run is the base block's motion scaled, to float32 rounding; it decays."""
    system, grid = block(k, m, h)
    limit = dt_limit(system, name, exact=True)
    assert check_dt(system, name, 0.5 * limit.dt) is None
    x = run_fragment(ctx, system, grid, name, 0.5 * limit.dt, 60)
    assert np.isfinite(x).all()
    motion = (x - system.rest_positions) / h
    assert np.abs(motion - base_motion[name]).max() <= 2e-4  # spacings; float32 positions
    assert np.abs(motion).max() < AMPLITUDE  # damped: smaller than at the start
    fixed = system.fixed
    np.testing.assert_array_equal(x[fixed].astype(np.float32), system.rest_positions[fixed].astype(np.float32))


@pytest.mark.parametrize("name", I.EXPLICIT_INTEGRATORS)
def test_half_the_limit_decays_and_one_and_a_half_is_refused_and_detected(ctx, name):
    system, grid = block(10.0, 0.01, 0.1)
    limit = dt_limit(system, name, exact=True)
    assert limit.dt > 0  # damped: even forward Euler and midpoint have a limit
    x = run_fragment(ctx, system, grid, name, 0.5 * limit.dt, 200)
    assert np.isfinite(x).all() and np.abs(x - system.rest_positions).max() < AMPLITUDE * 0.1
    refusal = check_dt(system, name, 1.5 * limit.dt)
    assert refusal is not None and f"node {refusal.limit.node}" in refusal.message
    assert f"{name} limit" in refusal.message
    # run anyway: the top mode grows by rho per step; where rho is large the census sees it pass
    # 1000 box lengths; forward Euler's rho at 1.5x is 1.015: its growth saturates near a spacing
    # (the springs' geometric nonlinearity detunes the mode), so the test sees it grow 5x instead
    w = exact_frequency(system).omega
    rho = float(spectral_radius(name, w, 2.0 * ZETA * w, 1.5 * limit.dt))
    assert rho > 1.0
    steps = min(1000, math.ceil(math.log(1e6) / math.log(rho)) + 5)
    dt = 1.5 * limit.dt
    sim = FragmentIntegrator(ctx, system, grid, name, dt, state=top_mode_start(system, 0.1, dt))
    try:
        _, row, slots, slot = sim.position_slot()
        with NodeCensus(ctx, count=sim.count, row=row, slots=slots) as census:
            texture = sim.position_slot()[0]
            assert census.bad(texture, 1000 * 0.3, slot=slot) == 0
            sim.step(steps)
            texture, _, _, slot = sim.position_slot()
            if rho > 1.1:
                assert census.bad(texture, 1000 * 0.3, slot=slot) > 0
            else:
                grown = np.abs(sim.positions() - system.rest_positions).max() / (AMPLITUDE * 0.1)
                assert np.isfinite(grown) and grown > 5.0
    finally:
        sim.release()


@pytest.mark.parametrize("backend", ["fragment", "feedback"])
def test_the_smallest_grid_2x2x2_runs_like_the_reference(ctx, backend):
    grid = NodeGrid(np.zeros(3), 0.1, np.ones((2, 2, 2), bool))
    fixed = grid.ijk[:, 1] == 0
    system = from_grid(grid, k_structural=10.0, k_shear=10.0, mass=0.01, fixed=fixed,
                       gravity=(0.0, -9.81, 0.0), velocity_damping=0.02)
    dt = 0.5 * dt_limit(system, "verlet", exact=True).dt
    ref = I.simulate(system, "verlet", dt, 300).x
    x = run_backend(ctx, backend, system, grid, dt, 300)
    assert np.abs(ref - system.rest_positions).max() > 0.01 * 0.1  # it sagged
    assert np.abs(x - ref).max() <= 1e-4 * 0.1
    np.testing.assert_array_equal(x[fixed], system.rest_positions[fixed].astype(np.float32))


def test_grids_up_to_the_texture_limit_and_one_node_beyond_it_is_refused(ctx):
    """The compact layout fills a max x max texture exactly and refuses one node more, naming the
    limit (checked at a small limit: llvmpipe's 16384^2 texels x 16 bytes x 3 states would be 13
    GB); the real limit is read from the context."""
    limit = int(ctx.info["GL_MAX_TEXTURE_SIZE"])
    assert limit >= 4096
    full = NodeGrid(np.zeros(3), 0.1, np.ones((64, 1, 64), bool))
    layout = CompactLayout.for_grid(full, 64)
    assert layout.size == (64, 64)
    over = np.ones((64, 1, 65), bool)
    over[1:, :, 64] = False  # 4097 nodes
    with pytest.raises(ValueError, match=r"4097 nodes need more than 64x64 texels \(the GL texture limit\)"):
        CompactLayout.for_grid(NodeGrid(np.zeros(3), 0.1, over), 64)
    big = NodeGrid(np.zeros(3), 0.1, np.ones((512, 1, 512), bool))
    assert CompactLayout.for_grid(big, limit).size == (512, 512)


@pytest.mark.parametrize("backend", ["foundation", "fragment", "feedback"])
def test_every_backend_runs_at_the_texture_limit_and_refuses_beyond_it(ctx, monkeypatch, backend):
    """With the context's texture limit lowered to 64 (the real 16384 would need 2^28 nodes), the
    largest sheet that fits steps like the reference and one row more is refused with GLError
    naming the limit: for the fragment backends 64x64 nodes fill the node texture exactly; for
    transform feedback the spring lists (2 entries per spring) fill their 64x64 texture first."""
    from deformgl.errors import GLError
    from deformgl.sim.simulation import make_simulation

    real = dict(ctx.info)
    monkeypatch.setattr(type(ctx), "info", property(lambda self: {**real, "GL_MAX_TEXTURE_SIZE": 64}))
    assert ctx.info["GL_MAX_TEXTURE_SIZE"] == 64

    nz = 64 if backend != "feedback" else 16

    def make(nx):
        grid = NodeGrid(np.zeros(3), 0.05, np.ones((nx, 1, nz), bool))
        fixed = grid.ijk[:, 2] == 0
        system = from_grid(grid, k_structural=10.0, k_shear=10.0, mass=1e-3, fixed=fixed,
                           gravity=(0.0, -9.81, 0.0), velocity_damping=1e-3)
        dt = 0.5 * dt_limit(system, "verlet", exact=False).dt
        if backend == "foundation":  # the fragment backend's Verlet fast path
            return system, dt, lambda: make_simulation(system, "verlet", "fragment", ctx=ctx, dt=dt,
                                                       path="foundation")
        if backend == "fragment":
            return system, dt, lambda: FragmentIntegrator(ctx, system, grid, "verlet", dt, path="general")
        return system, dt, lambda: FeedbackSimulation(ctx, system, "verlet", dt)

    fits = 64
    if backend == "feedback":  # the largest sheet whose spring-list entries fit 64 x 64 texels
        fits = max(nx for nx in range(2, 64) if 2 * make(nx)[0].spring_count <= 64 * 64)
        assert 2 * make(fits + 1)[0].spring_count > 64 * 64
    system, dt, build = make(fits)
    sim = build()
    try:
        sim.step(20)
        x = sim.positions().astype(np.float64)
    finally:
        sim.release()
    assert np.isfinite(x).all() and np.abs(x - system.rest_positions).max() > 0
    ref = I.simulate(system, "verlet", dt, 20).x  # every path starts from the same (Taylor) state
    assert np.abs(x - ref).max() <= 1e-4 * 0.05
    _, _, build = make(fits + 1)
    with pytest.raises(GLError, match="texture limit"):
        build()


@pytest.mark.parametrize("backend", ["fragment", "feedback"])
def test_one_node_thin_sheet_is_stable_and_matches_the_reference(ctx, backend):
    n, h = 12, 0.05
    fixed = np.zeros(n * n, bool)
    fixed[[0, n - 1]] = True
    system = cloth(n, n, h, k_structural=20.0, k_shear=20.0, k_flexion=2.0, mass=1e-3, fixed=fixed,
                   gravity=(0.0, -9.81, 0.0), velocity_damping=1e-3)
    grid = NodeGrid(np.zeros(3), h, np.ones((n, 1, n), bool))
    assert np.allclose(grid.rest_positions, system.rest_positions)
    dt = 0.5 * dt_limit(system, "verlet", exact=False).dt
    ref = I.simulate(system, "verlet", dt, 200).x
    x = run_backend(ctx, backend, system, grid, dt, 200)
    assert np.abs(ref - system.rest_positions).max() > h  # it fell a spacing or more
    assert np.abs(x - ref).max() <= 1e-3 * h


def test_far_from_the_origin_float32_needs_the_recentring(ctx):
    """The block at 1e6 m: without recentring, float32 positions (ulp 0.0625 m at 1e6) cannot hold
    a 0.1 m spacing's motion; the pipeline recentres, so the run is exact again."""
    system, grid = block(10.0, 0.01, 0.1)
    dt = 0.5 * dt_limit(system, "verlet", exact=True).dt
    moved = {}
    for name, origin in (("near", (0.0, 0.0, 0.0)), ("far", (1e6, -1e6, 1e6))):
        s, _ = block(10.0, 0.01, 0.1, origin=origin, zeta=0.01)
        sim = FeedbackSimulation(ctx, s, "verlet", dt, state=top_mode_start(s, 0.1, dt))
        try:
            sim.step(20)
            moved[name] = sim.positions().astype(np.float64) - s.rest_positions
        finally:
            sim.release()
    assert np.abs(moved["near"]).max() > 1e-3  # it moves ...
    assert np.abs(moved["far"] - moved["near"]).max() > 0.1 * 0.1  # ... and at 1e6 float32 garbles it


def _scene_with_mesh(tmp_path: Path, mesh: trimesh.Trimesh, name: str, gravity_scale: float = 1.0) -> Path:
    mesh_path = tmp_path / f"{name}.obj"
    mesh.export(mesh_path)
    text = (SCENES / "jelly_springs.toml").read_text().replace('path = "assets/jelly_block.obj"', f'path = "{mesh_path}"')
    text = text.replace("steps = 300", "steps = 150").replace("show_grid = true", "show_grid = false")
    text = text.replace("gravity = [0.0, -9.81, 0.0]", f"gravity = [0.0, {-9.81 * gravity_scale!r}, 0.0]")
    text = text.replace("force = [0.004, 0.0, 0.0]", f"force = [{0.004 * gravity_scale!r}, 0.0, 0.0]")
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def jelly_image(ctx, tmp_path_factory):
    mesh = trimesh.load(SCENES / "assets" / "jelly_block.obj", force="mesh")
    path = _scene_with_mesh(tmp_path_factory.mktemp("near"), mesh, "near")
    return mesh, render_scene(ctx, load_scene(path))


def test_a_mesh_1e6_from_the_origin_renders_like_the_one_at_the_origin(ctx, jelly_image, tmp_path):
    mesh, near = jelly_image
    far_mesh = mesh.copy()
    far_mesh.apply_translation((1e6, -1e6, 1e6))
    scene = load_scene(_scene_with_mesh(tmp_path, far_mesh, "far"))
    built = build_scene_model(scene)
    np.testing.assert_allclose(built.centre, np.asarray(mesh.bounds).mean(axis=0) + (1e6, -1e6, 1e6), rtol=0, atol=1e-6)
    assert np.abs(built.grid.rest_positions).max() < 1.0  # what reaches float32 is near the origin
    far = render_scene(ctx, scene)
    diff = np.abs(far.astype(int) - near.astype(int))
    assert diff.mean() < 0.05 and (diff.max(axis=2) > 8).mean() < 1e-3  # a few edge pixels may round


def test_a_grid_spacing_of_1e_4_runs_the_same_scene_scaled(ctx, jelly_image, tmp_path):
    """The jelly scaled to a grid spacing of 1.2e-4 m with gravity and pull scaled alike: the same
    dimensionless scene, so the same image (the camera frames the box)."""
    mesh, near = jelly_image
    spacing = build_scene_model(load_scene(_scene_with_mesh(tmp_path, mesh, "unit"))).grid.spacing
    scale = 1.2e-4 / spacing
    small = mesh.copy()
    small.apply_scale(scale)
    scene = load_scene(_scene_with_mesh(tmp_path, small, "small", gravity_scale=scale))
    built = build_scene_model(scene)
    assert built.grid.spacing == pytest.approx(1.2e-4)
    # mass and stiffness unchanged: same w, same dt limit; force per node scaled with the size
    image = render_scene(ctx, scene)
    diff = np.abs(image.astype(int) - near.astype(int))
    assert diff.mean() < 0.05 and (diff.max(axis=2) > 8).mean() < 1e-3  # a few edge pixels may round


@pytest.mark.parametrize("layout", ["compact", "indexed"])
def test_a_nan_node_spreads_only_to_its_springs_on_dense_and_indexed_grids(ctx, layout):
    """Absent neighbours read the node itself (d = 0), never an unrelated node across a row
    wrap, so a NaN reaches exactly the nodes connected to it, the same on both lookups."""
    from deformgl.sim.backends.verlet_pass import FoundationVerlet

    grid = NodeGrid(np.zeros(3), 0.1, np.ones((3, 4, 3), bool))
    system = from_grid(grid, k_structural=10.0, k_shear=10.0, mass=0.01, gravity=(0.0, 0.0, 0.0))
    sim = FoundationVerlet.for_system(ctx, system, 1e-3, layout=layout)
    try:
        bad = int(grid.index[1, 0, 1])
        state = sim.read_state()
        state[bad, 0] = np.nan
        textures = sim.textures
        image = textures.layout.scatter(grid.ijk, state)
        for t in textures.state[:2]:
            t.write(np.ascontiguousarray(image, np.float32).tobytes())
        sim.step(1)
        nan = ~np.isfinite(sim.positions()).all(axis=1)
    finally:
        sim.release()
    expected = np.zeros(grid.count, bool)
    expected[bad] = True
    expected[grid.neighbours[bad][grid.neighbours[bad] >= 0]] = True
    np.testing.assert_array_equal(nan, expected)
