"""The five integrators: convergence order, stability limits, physics facts, constraints."""

import numpy as np
import pytest

from deformgl.grid.nodes import NodeGrid
from deformgl.sim.integrators import (EXPLICIT_INTEGRATORS, Constraints, Drag, Sphere, State, initial_state,
                                  memory_per_node, run_until_converged, simulate, step)
from deformgl.sim.springs import STRUCTURAL, SpringSystem, cloth, from_grid, from_triangle_mesh

G = 9.81
H = 0.05


# --- convergence order -------------------------------------------------------------------

def small_3d_system(damped: bool) -> tuple[SpringSystem, np.ndarray]:
    """2x2x2 nodes, one fixed, unequal masses, gravity; damped: every velocity-dependent force."""
    grid = NodeGrid(np.zeros(3), 0.1, np.ones((2, 2, 2), bool))
    fixed = np.zeros(8, bool)
    fixed[0] = True
    c = 1.0 if damped else 0.0
    s = from_grid(grid, k_structural=4.0, k_shear=2.0, mass=0.01 * (1 + np.arange(8) / 8),
                  fixed=fixed, damping_structural=0.02 * c, damping_shear=0.01 * c,
                  velocity_damping=0.01 * c, wind=(1.0, 0.0, 0.5), wind_drag=0.005 * c)
    v0 = np.random.default_rng(1).normal(scale=0.2, size=(8, 3))
    return s, v0


T_END = 0.5
# Steps per T_END. The highest angular frequency of the linearised problem is 33 rad/s (bound
# 57), so w*dt <= 0.4 at 40 steps: every method but forward Euler is in its asymptotic range
# there (measured local slopes within 0.1-0.25 of the order from the first halving on, within
# 0.06 from the second). Forward Euler amplifies every mode by (1 + w^2 dt^2)^(n/2), which
# swamps its O(dt) error unless w*dt is small: slope 1.78 from 40 to 80 steps, 1.03 from 320 on.
STEPS = {"euler": (320, 640, 1280, 2560), "semi-implicit": (40, 80, 160, 320),
         "midpoint": (80, 160, 320, 640), "rk4": (40, 80, 160, 320), "verlet": (40, 80, 160, 320)}
# Verlet's velocity is the backward difference (x - x_prev)/dt, first-order accurate: with
# velocity-dependent forces (damping, wind) its global order is 1, not 2 (integrators.py).
ORDER = {"undamped": {"euler": 1, "semi-implicit": 1, "midpoint": 2, "rk4": 4, "verlet": 2},
         "damped": {"euler": 1, "semi-implicit": 1, "midpoint": 2, "rk4": 4, "verlet": 1}}


@pytest.fixture(scope="module", params=["undamped", "damped"])
def smooth_problem(request):
    s, v0 = small_3d_system(request.param == "damped")
    n = 3000  # RK4 reference: error ~ (320/3000)^4 of the smallest RK4 error below, ~1e-12
    ref = simulate(s, "rk4", T_END / n, n, state=initial_state(s, T_END / n, v=v0)).x
    return request.param, s, v0, ref


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_convergence_order(smooth_problem, name):
    kind, s, v0, ref = smooth_problem
    dts, errors = [], []
    for n in STEPS[name]:
        dt = T_END / n
        x = simulate(s, name, dt, n, state=initial_state(s, dt, v=v0)).x
        dts.append(dt)
        errors.append(np.abs(x - ref).max())
    slope = np.polyfit(np.log(dts), np.log(errors), 1)[0]
    assert abs(slope - ORDER[kind][name]) <= 0.25, f"{kind} {name}: slope {slope:.3f}, {errors}"
    assert errors[-1] > 1e-11, "errors must stay above the reference's own error"


# --- stability of an undamped spring ------------------------------------------------------

def pinned_spring(k: float = 40.0, m: float = 0.1) -> SpringSystem:
    """Node 0 fixed, node 1 free at rest length 1 along x: w = sqrt(k/m), linear along x."""
    return SpringSystem(rest_positions=np.array([[0.0, 0, 0], [1.0, 0, 0]]), mass=np.full(2, m),
                        fixed=np.array([True, False]), i=np.array([0]), j=np.array([1]),
                        rest_length=np.ones(1), stiffness=np.array([k]), damping=np.zeros(1),
                        spring_class=np.array([STRUCTURAL]), gravity=np.zeros(3))


def amplitude_history(name: str, w_dt: float, steps: int, amplitude: float = 1e-6) -> np.ndarray:
    """|x - L| / amplitude of the free node per step, stopping at 1e3 (a blow-up)."""
    s = pinned_spring()
    dt = w_dt / np.sqrt(40.0 / 0.1)
    x0 = s.rest_positions + [[0, 0, 0], [amplitude, 0, 0]]  # tiny: the spring stays linear
    state = initial_state(s, dt, x=x0)
    out = []
    for n in range(steps):
        state = step(s, name, state, dt, n * dt)
        out.append(abs(state.x[1, 0] - 1.0) / amplitude)
        if out[-1] > 1e3:
            break
    return np.array(out)


@pytest.mark.parametrize("name, bounded, unbounded", [("semi-implicit", 1.9, 2.1),
                                                      ("verlet", 1.9, 2.1), ("rk4", 2.7, 2.9)])
def test_stability_limit(name, bounded, unbounded):
    # Limits (STYLE.md, docs/EQUATIONS.md): symplectic Euler and Verlet w dt < 2, RK4 < 2.83.
    calm = amplitude_history(name, bounded, 5000)  # ~1500 periods at w dt = 1.9
    assert len(calm) == 5000 and calm.max() < 10.0, f"{name} at w dt = {bounded}: {calm.max()}"
    wild = amplitude_history(name, unbounded, 2000)
    assert wild[-1] > 1e3, f"{name} at w dt = {unbounded} stayed bounded ({wild.max()})"


@pytest.mark.parametrize("name, w_dt", [("euler", 0.05), ("euler", 0.5), ("euler", 1.9),
                                        ("midpoint", 0.5)])
def test_unstable_at_any_step(name, w_dt):
    # Forward Euler grows by sqrt(1 + (w dt)^2) per step, midpoint by (1 + (w dt)^4/4)^(1/2):
    # without damping no step size is stable (STYLE.md). 0.05 needs ~5500 steps to reach 1e3.
    amp = amplitude_history(name, w_dt, 8000)
    assert amp[-1] > 1e3, f"{name} at w dt = {w_dt}: {amp.max()}"


# --- physics facts ------------------------------------------------------------------------

def hanging_cloth(**options) -> SpringSystem:
    """A 5x5 cloth at non-round coordinates, two corners fixed."""
    fixed = np.zeros(25, bool)
    fixed[[0, 4]] = True
    kw = dict(k_structural=20.0, k_shear=5.0, k_flexion=1.0, mass=0.01, fixed=fixed,
              velocity_damping=0.002, origin=(0.013, 0.3, -0.071))
    kw.update(options)
    return cloth(5, 5, H, **kw)


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_rest_state_is_an_exact_equilibrium(name):
    grid = NodeGrid(np.array([0.1, 0.2, 0.3]), H, np.ones((3, 3, 3), bool))
    s = from_grid(grid, k_structural=30.0, k_shear=10.0, k_flexion=4.0, damping_structural=0.1,
                  velocity_damping=0.01, mass=0.01, gravity=(0.0, 0.0, 0.0))
    state = simulate(s, name, 1e-3, 30)
    np.testing.assert_array_equal(state.x, s.rest_positions)
    np.testing.assert_array_equal(state.v, 0.0)


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_fixed_nodes_bit_identical(name):
    s = hanging_cloth()
    sphere = Sphere(centre=s.rest_positions[0], radius=0.02)  # would push the fixed node
    drag = Drag(node=24, target=lambda t: [0.3, 0.0, 0.3 + t], stiffness=1.0)
    state = simulate(s, name, 1e-3, 200, constraints=Constraints(ground=0.35, spheres=(sphere,)),
                     drags=(drag,))
    np.testing.assert_array_equal(state.x[s.fixed], s.rest_positions[s.fixed])
    np.testing.assert_array_equal(state.v[s.fixed], 0.0)
    assert np.abs(state.x[~s.fixed] - s.rest_positions[~s.fixed]).max() > 0.04


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_free_fall(name):
    # Constant acceleration, v0 = 0: midpoint and RK4 are exact (they integrate quadratics
    # exactly) and so is Verlet started from x_prev = x0 - dt v0 + dt^2/2 a0 (the exact x(-dt)).
    # Forward Euler lags by g t dt / 2, semi-implicit Euler leads by g t dt / 2, both exactly.
    # Tolerance 1e-12 m: rounding of ~300 float64 additions of values ~0.1, and spring forces
    # of ~1e-17 m length errors of the rigidly translated cloth.
    s = hanging_cloth(fixed=None, velocity_damping=0.0)
    dt, n = 1e-3, 300
    t = n * dt
    drop = simulate(s, name, dt, n).x - s.rest_positions
    lag = {"euler": 0.5 * G * t * dt, "semi-implicit": -0.5 * G * t * dt}.get(name, 0.0)
    np.testing.assert_allclose(drop[:, 1], -0.5 * G * t * t + lag, rtol=0, atol=1e-12)
    np.testing.assert_allclose(drop[:, [0, 2]], 0.0, atol=1e-12)


def test_verlet_started_without_the_acceleration_term_is_first_order():
    # x_prev = x0 (no dt^2/2 a0) starts Verlet with velocity -a dt/2: the drop is 1/2 g t (t + dt).
    s = hanging_cloth(fixed=None, velocity_damping=0.0)
    dt, n = 1e-3, 300
    x0 = s.rest_positions
    state = simulate(s, "verlet", dt, n, state=State(x0, np.zeros_like(x0), x0.copy()))
    np.testing.assert_allclose(state.x[:, 1] - x0[:, 1], -0.5 * G * (n * dt) * (n + 1) * dt,
                               atol=1e-12)


def test_spring_list_forces_equal_the_grid_neighbour_sum():
    """The one float64 reference (springs.forces over the spring list) equals Mosegaard & Sørensen
    2005, eq. 1 written independently over each node's 18 grid neighbours (the form of the
    fragment pass), on a deformed random grid with per-class stiffness."""
    from deformgl.grid.nodes import REST_LENGTH_UNITS
    from deformgl.sim.springs import forces

    rng = np.random.default_rng(7)
    occ = rng.random((5, 4, 4)) < 0.8
    occ[:, 0, :] = True
    grid = NodeGrid(np.array([0.2, -0.1, 0.3]), H, occ)
    s = from_grid(grid, k_structural=60.0, k_shear=15.0, mass=0.01, gravity=(0.0, 0.0, 0.0))
    x = grid.rest_positions + rng.normal(scale=0.1 * H, size=(grid.count, 3))
    nb = grid.neighbours
    xj = x[np.where(nb >= 0, nb, np.arange(grid.count)[:, None])]
    d = x[:, None, :] - xj
    length = np.linalg.norm(d, axis=-1, keepdims=True)
    k = np.where(np.arange(18) < 6, 60.0, 15.0)[None, :, None]
    rest = (H * REST_LENGTH_UNITS)[None, :, None]
    eq1 = np.sum(np.where((nb >= 0)[..., None], k * (rest - length) * d / length, 0.0), axis=1)
    assert np.abs(eq1).max() > 1e-3
    np.testing.assert_allclose(forces(s, x, np.zeros_like(x), 0.0), eq1, rtol=0, atol=1e-12)


# --- constraints and drags ----------------------------------------------------------------

def outside(x, sphere, t):
    return np.linalg.norm(x - sphere.centre_at(t), axis=1) >= sphere.radius * (1 - 1e-12)


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_nothing_below_the_ground_or_inside_a_sphere_after_any_step(name):
    s = cloth(6, 6, H, k_structural=20.0, k_shear=5.0, mass=0.01, velocity_damping=0.002,
              origin=(0.0, 0.1, 0.0))
    sphere = Sphere(centre=(0.12, 0.0, 0.13), radius=0.08)  # clear of the ground (no conflict)
    cons = Constraints(ground=-0.1, spheres=(sphere,))
    dt = 1e-3
    state = initial_state(s, dt)
    touched_ground = touched_sphere = False
    for n in range(250):
        state = step(s, name, state, dt, n * dt, constraints=cons)
        assert state.x[:, 1].min() >= -0.1, f"step {n}: below the ground"
        assert outside(state.x, sphere, (n + 1) * dt).all(), f"step {n}: inside the sphere"
        touched_ground |= bool(np.any(state.x[:, 1] == -0.1))
        dist = np.linalg.norm(state.x - sphere.centre_at(0.0), axis=1)
        touched_sphere |= bool(np.any(np.abs(dist - 0.08) < 1e-12))
    assert touched_ground and touched_sphere, "both obstacles must have been hit"
    assert np.all(np.isfinite(state.x))


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_a_node_resting_on_the_ground_builds_up_no_speed(name):
    # One springless node dropped 1 cm onto the ground and left there for 1 s: the contact
    # removes the velocity into the ground (Verlet: the projection does), else v -> -g t.
    s = cloth(1, 1, H, k_structural=1.0, k_shear=1.0, mass=0.01)
    assert s.spring_count == 0
    dt = 1e-3
    state = simulate(s, name, dt, 1000, constraints=Constraints(ground=-0.01))
    assert -0.01 <= state.x[0, 1] <= -0.01 + G * dt * dt
    assert abs(state.v[0, 1]) <= G * dt * (1 + 1e-12)


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_moving_sphere_pushes_nodes(name):
    # No gravity: a cloth at rest at y = 0; a sphere rises through its middle at 1 m/s.
    s = cloth(5, 5, H, k_structural=20.0, k_shear=5.0, mass=0.01, velocity_damping=0.01,
              gravity=(0.0, 0.0, 0.0))
    middle = 12
    centre0 = s.rest_positions[middle] - [0.0, 0.25, 0.0]
    sphere = Sphere(centre=lambda t: centre0 + [0.0, t, 0.0], radius=0.15)
    dt, n = 1e-3, 200  # the sphere's top reaches the cloth at t = 0.1, then pushes it 0.1 up
    state = initial_state(s, dt)
    for k in range(n):
        state = step(s, name, state, dt, k * dt, constraints=Constraints(spheres=(sphere,)))
        assert outside(state.x, sphere, (k + 1) * dt).all()
    top = sphere.centre_at(n * dt)[1] + 0.15
    np.testing.assert_allclose(state.x[middle], [2 * H, top, 2 * H], atol=1e-9)
    np.testing.assert_allclose(state.v[middle, 1], 1.0, atol=1e-6 if name != "euler" else 0.05)
    assert top == pytest.approx(0.1)


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_drag_target_is_followed(name):
    # A free cloth, no gravity, one corner dragged 0.3 along x and 0.1 up in 0.5 s, then held.
    # Damping c/m = 10/s: forward Euler needs w^2 dt < c/m here to damp its high modes.
    s = cloth(4, 4, H, k_structural=10.0, k_shear=2.5, mass=0.01, velocity_damping=0.1,
              gravity=(0.0, 0.0, 0.0))
    start = s.rest_positions[0].copy()
    shift = np.array([0.3, 0.1, 0.0])
    path = lambda t: start + min(t / 0.5, 1.0) * shift
    state = simulate(s, name, 1e-3, 1500, drags=(Drag(node=0, target=path, stiffness=20.0),))
    assert np.linalg.norm(state.x[0] - path(1.5)) < 0.01 * H
    # the cloth came along in one piece (trailing and turning about the corner: air drag)
    moved = (state.x - s.rest_positions) @ shift / np.linalg.norm(shift)
    assert moved.mean() > 0.3 * np.linalg.norm(shift)
    reach = np.linalg.norm(s.rest_positions - start, axis=1).max()
    assert np.linalg.norm(state.x - state.x[0], axis=1).max() < 1.05 * reach


# --- convergence stop, memory ------------------------------------------------------------

def kicked(s: SpringSystem, dt: float) -> State:
    """A start with random velocities: a start at rest would pass the per-step test at once."""
    v0 = np.random.default_rng(0).normal(scale=0.3, size=(s.count, 3))
    return initial_state(s, dt, v=v0)


def step_moved(state: State) -> float:
    return float(np.linalg.norm(state.x - state.x_prev, axis=1).max())


def test_damped_system_converges_and_really_stops():
    s = hanging_cloth(velocity_damping=0.05)
    dt = 1e-3
    limit = 0.001 * H  # the default threshold: 0.001 * spacing
    start = kicked(s, dt)
    state, steps = run_until_converged(s, "semi-implicit", dt, max_steps=5000, state=start)
    assert 100 < steps < 5000
    assert step_moved(state) < limit
    before = simulate(s, "semi-implicit", dt, steps - 1, state=start)
    assert step_moved(before) >= limit, "it stops at the first step below the threshold"
    np.testing.assert_array_equal(step(s, "semi-implicit", before, dt, (steps - 1) * dt).x,
                                  state.x)

    _, later = run_until_converged(s, "semi-implicit", dt, max_steps=5000, state=start,
                                   patience=30)
    assert later >= steps + 29


def test_undamped_system_runs_to_max_steps():
    s = hanging_cloth(velocity_damping=0.0)
    dt = 1e-3
    final, steps = run_until_converged(s, "verlet", dt, max_steps=2000, state=kicked(s, dt))
    assert steps == 2000
    assert step_moved(final) >= 0.001 * H and np.all(np.isfinite(final.x))


def test_memory_per_node():
    sizes = {name: memory_per_node(name) for name in EXPLICIT_INTEGRATORS}
    assert sizes == {"verlet": 48, "euler": 64, "semi-implicit": 64, "midpoint": 96, "rk4": 160}
    with pytest.raises(ValueError, match="unknown integrator"):
        memory_per_node("leapfrog")
    with pytest.raises(ValueError, match="unknown integrator"):
        step(pinned_spring(), "leapfrog", initial_state(pinned_spring(), 0.01), 0.01, 0.0)


def test_triangle_mesh_system_steps_and_keeps_its_rest_state():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) * H
    s = from_triangle_mesh(v, [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]], stiffness=10.0,
                           mass=0.01, gravity=(0.0, 0.0, 0.0))
    for name in EXPLICIT_INTEGRATORS:
        np.testing.assert_array_equal(simulate(s, name, 1e-3, 10).x, v)
