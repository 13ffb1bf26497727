"""Stability limits: exact frequency, analytic bounds, measured limits, dt validation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from deformgl.sim import growth, integrators, limits, spectrum
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.integrators import acceleration, initial_state, step
from deformgl.sim.springs import SpringSystem, cloth, from_grid, max_angular_frequency

NO_GRAVITY = (0.0, 0.0, 0.0)


def _block(n: int, **options: object) -> SpringSystem:
    opts = dict(k_structural=100.0, k_shear=50.0, k_flexion=20.0, mass=0.01, gravity=NO_GRAVITY)
    opts.update(options)
    return from_grid(NodeGrid(np.zeros(3), 0.1, np.ones((n, n, n), bool)), **opts)


@pytest.fixture(scope="module")
def small() -> SpringSystem:
    """3x3x3 block, one corner fixed, no gravity: fast runs, a non-trivial spectrum."""
    fixed = np.zeros(27, bool)
    fixed[0] = True
    return _block(3, fixed=fixed)


@pytest.fixture(scope="module")
def small_top(small: SpringSystem) -> spectrum.ExactFrequency:
    return spectrum.exact_frequency(small)


def _damped(c: float) -> SpringSystem:
    fixed = np.zeros(27, bool)
    fixed[0] = True
    return _block(3, fixed=fixed, velocity_damping=c)


def _jacobian_omega(system: SpringSystem) -> float:
    """Brute force: -d(acceleration)/dx by central differences, eig of the free block."""
    x0 = system.rest_positions
    v0 = np.zeros_like(x0)
    free = np.nonzero(~system.fixed)[0]
    dof = (3 * free[:, None] + np.arange(3)).ravel()
    h = 1e-7
    cols = []
    for d in dof:
        e = np.zeros(x0.size)
        e[d] = h
        plus = acceleration(system, x0 + e.reshape(x0.shape), v0, 0.0).ravel()
        minus = acceleration(system, x0 - e.reshape(x0.shape), v0, 0.0).ravel()
        cols.append(-(plus - minus)[dof] / (2 * h))
    lam = np.linalg.eigvals(np.array(cols).T)
    return float(np.sqrt(lam.real.max()))


def test_exact_frequency_matches_a_brute_force_eigen_solve() -> None:
    rng = np.random.default_rng(3)
    fixed = np.zeros(8, bool)
    fixed[[0, 5]] = True
    s = from_grid(NodeGrid(np.zeros(3), 0.2, np.ones((2, 2, 2), bool)), k_structural=70.0,
                  k_shear=30.0, mass=rng.uniform(0.5, 2.0, 8), fixed=fixed, gravity=NO_GRAVITY)
    top = spectrum.exact_frequency(s, method="dense")
    assert top.omega == pytest.approx(_jacobian_omega(s), rel=1e-6)
    # the returned mode is an eigenvector: K phi = w^2 M phi on the free nodes, 0 at fixed ones
    k_phi = spectrum.stiffness_product(s, top.mode)[~fixed]
    m_phi = s.mass[~fixed, None] * top.mode[~fixed]
    np.testing.assert_allclose(k_phi, top.omega ** 2 * m_phi, atol=1e-9 * np.abs(k_phi).max())
    assert np.all(top.mode[fixed] == 0.0)
    assert np.linalg.norm(top.mode[top.node]) == pytest.approx(1.0)
    assert not fixed[top.node] and top.node >= 0


def test_lanczos_matches_the_dense_solve_on_a_medium_system() -> None:
    rng = np.random.default_rng(7)
    fixed = np.zeros(216, bool)
    fixed[:6] = True
    s = _block(6, mass=rng.uniform(0.005, 0.02, 216), fixed=fixed)
    dense = spectrum.exact_frequency(s, method="dense")
    lanczos = spectrum.exact_frequency(s, method="lanczos", tol=1e-10)
    assert lanczos.method == "lanczos" and lanczos.tolerance <= 1e-10
    assert lanczos.omega == pytest.approx(dense.omega, rel=1e-9)
    assert lanczos.omega <= dense.omega * (1 + 1e-12)  # a Rayleigh quotient: never above
    assert lanczos.node == dense.node


@pytest.mark.parametrize("name, factor", [("verlet", 2.0), ("semi-implicit", 2.0),
                                          ("rk4", 2.0 * math.sqrt(2.0))])
def test_undamped_analytic_limits_are_the_closed_forms(small: SpringSystem,
                                                       small_top: spectrum.ExactFrequency,
                                                       name: str, factor: float) -> None:
    exact, _ = limits.exact_limit(small, name)
    assert exact.dt * small_top.omega == pytest.approx(factor, rel=1e-10)
    gersh = limits.gershgorin_limit(small, name)
    assert gersh.dt * max_angular_frequency(small).omega == pytest.approx(factor, rel=1e-10)


def test_damped_forward_euler_limit_is_g_over_w_squared() -> None:
    # |1 + z|^2 = 1 - g dt + w^2 dt^2 <= 1  <=>  dt <= g / w^2 (underdamped mode)
    assert limits.mode_limit("euler", 300.0, 60.0)[0] == pytest.approx(60.0 / 300.0 ** 2, rel=1e-10)


@pytest.mark.parametrize("name", ["verlet", "semi-implicit", "rk4"])
def test_measured_limit_is_within_two_percent_of_the_exact_one(
        small: SpringSystem, small_top: spectrum.ExactFrequency, name: str) -> None:
    exact, _ = limits.exact_limit(small, name)
    measured = growth.measured_limit(small, name, exact.dt, steps=1000, mode=small_top.mode)
    assert measured.unstable_dt / measured.stable_dt <= 1.002
    assert measured.dt == pytest.approx(exact.dt, rel=0.02)


@pytest.mark.parametrize("name", ["euler", "midpoint"])
def test_euler_and_midpoint_undamped_grow_even_at_small_dt(
        small: SpringSystem, small_top: spectrum.ExactFrequency, name: str) -> None:
    dt = 0.05 / small_top.omega
    assert limits.exact_limit(small, name)[0].dt == 0.0
    fit = growth.growth_rate(small, name, dt, steps=1000, mode=small_top.mode)
    # growth per step |R(i 0.05)|: sqrt(1 + 0.05^2) (Euler), sqrt(1 + 0.05^4 / 4) (midpoint)
    y = 0.05
    expected = math.sqrt(1 + y * y) if name == "euler" else math.sqrt(1 + y ** 4 / 4)
    assert not fit.stable
    assert fit.factor == pytest.approx(expected, rel=1e-8)
    # the same run with rk4 is stable: the classifier is not biased to "unstable"
    assert growth.growth_rate(small, "rk4", dt, steps=1000, mode=small_top.mode).stable


@pytest.mark.parametrize("name", ["euler", "midpoint"])
def test_damped_euler_and_midpoint_measured_limit_matches_the_damped_bound(
        small_top: spectrum.ExactFrequency, name: str) -> None:
    s = _damped(2 * 0.1 * 0.01 * small_top.omega)  # zeta 0.1 on the top mode
    exact, _ = limits.exact_limit(s, name)
    assert exact.dt > 0 and exact.formula.startswith("damped")
    measured = growth.measured_limit(s, name, exact.dt, steps=1000, mode=small_top.mode)
    assert measured.dt == pytest.approx(exact.dt, rel=0.02)


@pytest.mark.parametrize("name", ["verlet", "semi-implicit", "rk4"])
def test_half_the_limit_stays_bounded_and_one_and_a_half_grows(
        small: SpringSystem, small_top: spectrum.ExactFrequency, name: str) -> None:
    limit = limits.exact_limit(small, name)[0].dt
    calm = growth.growth_rate(small, name, 0.5 * limit, steps=2000, mode=small_top.mode)
    assert calm.stable and calm.steps == 2000 and not calm.blew_up and calm.peak < 3.0
    wild = growth.growth_rate(small, name, 1.5 * limit, steps=2000, mode=small_top.mode)
    assert not wild.stable and wild.blew_up and wild.factor > 1.1


def test_semi_implicit_energy_oscillates_but_is_judged_stable(
        small: SpringSystem, small_top: spectrum.ExactFrequency) -> None:
    """An energy threshold would refuse this run (energy swings by ~100x); its spectral radius
    is 1 to 1e-7, and 0.3 % above 2/w it grows by more than 1.1 per step."""
    dt = 0.995 * 2.0 / small_top.omega
    x0 = small.rest_positions
    state = initial_state(small, dt, x=x0 + 1e-7 * small_top.mode)
    energies = []
    for n in range(200):
        state = step(small, "semi-implicit", state, dt, n * dt)
        energies.append(growth._energies(small, (state.x - x0)[None], state.v[None])[0])
    assert max(energies) / min(energies) > 10.0
    fit = growth.growth_rate(small, "semi-implicit", dt, steps=1000, mode=small_top.mode)
    assert fit.stable and abs(fit.rate) < 1e-7
    above = growth.growth_rate(small, "semi-implicit", 1.003 * 2.0 / small_top.omega, steps=1000,
                           mode=small_top.mode)
    assert not above.stable and above.factor > 1.1


def test_check_dt_refuses_above_and_accepts_below(small: SpringSystem,
                                                  small_top: spectrum.ExactFrequency) -> None:
    limit = 2.0 / small_top.omega
    assert limits.check_dt(small, "verlet", 0.99 * limit) is None   # above Gershgorin, below exact
    refusal = limits.check_dt(small, "verlet", 1.01 * limit)
    assert refusal is not None and refusal.limit.bound == "exact"
    assert refusal.limit.dt == pytest.approx(limit, rel=1e-10)
    msg = refusal.message
    assert msg.startswith(f"dt {1.01 * limit:.4g} s is above the verlet limit {limit:.4g} s, "
                          f"w = {small_top.omega:.4g} rad/s")
    assert f"node {small_top.node} " in msg and f"spring {small_top.spring}," in msg
    assert "k = 100 N/m" in msg or "k = 50 N/m" in msg or "k = 20 N/m" in msg
    assert "m = 0.01 kg" in msg
    with pytest.raises(Exception, match="above the verlet limit"):
        limits.require_stable_dt(small, "verlet", 1.01 * limit)


def test_check_dt_uses_the_conservative_gershgorin_bound_for_large_systems(
        small: SpringSystem) -> None:
    bound = max_angular_frequency(small)
    g_limit = 2.0 / bound.omega
    assert limits.check_dt(small, "semi-implicit", 0.999 * g_limit, exact_up_to=0, lanczos_up_to=0) is None
    refusal = limits.check_dt(small, "semi-implicit", 1.001 * g_limit, exact_up_to=0, lanczos_up_to=0)
    assert refusal is not None and refusal.limit.bound == "gershgorin"
    assert refusal.limit.node == bound.node and refusal.limit.spring == bound.spring
    assert f"node {bound.node} (spring {bound.spring}," in refusal.message
    assert "gershgorin bound" in refusal.message


def test_check_dt_uses_a_lanczos_estimate_between_dense_and_gershgorin(
        small: SpringSystem, small_top: spectrum.ExactFrequency) -> None:
    """Above exact_up_to free nodes the top frequency is estimated by Lanczos (a Rayleigh
    quotient: never above w_max); the dt must stay LANCZOS_MARGIN below its limit, so nothing
    above the true limit is accepted, and dts between the Gershgorin and the true limit are."""
    limit = 2.0 / small_top.omega
    g_limit = 2.0 / max_angular_frequency(small).omega
    assert g_limit < 0.7 * limit
    assert limits.check_dt(small, "verlet", 0.99 * limit, exact_up_to=0) is None
    refusal = limits.check_dt(small, "verlet", (1.0 - limits.LANCZOS_MARGIN / 2) * limit, exact_up_to=0)
    assert refusal is not None and refusal.limit.bound == "lanczos" and "lanczos bound" in refusal.message
    assert limit * (1 - 2 * limits.LANCZOS_MARGIN) <= refusal.limit.dt <= limit * (1 - limits.LANCZOS_MARGIN) * (1 + 1e-4)
    assert refusal.limit.node == small_top.node


def test_check_dt_refuses_undamped_euler_at_any_dt_and_uses_the_damped_limit(
        small: SpringSystem, small_top: spectrum.ExactFrequency) -> None:
    for name in ("euler", "midpoint"):
        refusal = limits.check_dt(small, name, 1e-9)
        assert refusal is not None and refusal.limit.dt == 0.0
        assert "damping" in refusal.message and "every dt" in refusal.message
    damped = _damped(2 * 0.1 * 0.01 * small_top.omega)
    limit = limits.exact_limit(damped, "euler")[0].dt
    assert limit == pytest.approx(0.2 / small_top.omega, rel=1e-6)  # g / w^2, g = 0.2 w
    assert limits.check_dt(damped, "euler", 0.98 * limit) is None
    assert limits.check_dt(damped, "euler", 1.02 * limit) is not None


def _random_system(seed: int) -> SpringSystem:
    rng = np.random.default_rng(seed)
    grid = NodeGrid(np.zeros(3), 0.1, rng.random((4, 3, 3)) < 0.8)
    n = grid.count
    return from_grid(grid, k_structural=rng.uniform(10, 500), k_shear=rng.uniform(10, 500),
                     k_flexion=rng.uniform(0, 100), damping_structural=rng.uniform(0, 0.05),
                     damping_shear=rng.uniform(0, 0.05), mass=rng.uniform(0.005, 0.05, n),
                     fixed=rng.random(n) < 0.1, velocity_damping=rng.uniform(0, 0.2),
                     gravity=NO_GRAVITY)


@pytest.mark.parametrize("which", ["random 0", "random 1", "random 2", "block", "cloth"])
def test_gershgorin_limit_is_never_above_the_exact_one(which: str) -> None:
    if which == "block":
        s = _block(3)
    elif which == "cloth":
        s = cloth(6, 6, 0.1, k_structural=80.0, k_shear=20.0, velocity_damping=0.3,
                  gravity=NO_GRAVITY)
    else:
        s = _random_system(int(which.split()[1]))
    top = spectrum.exact_frequency(s)
    assert max_angular_frequency(s).omega >= top.omega * (1 - 1e-12)
    for name in integrators.EXPLICIT_INTEGRATORS:
        gersh, exact = limits.gershgorin_limit(s, name).dt, limits.exact_limit(s, name)[0].dt
        assert gersh <= exact * (1 + 1e-9), name


def test_stability_table_row_is_measured_and_formatted() -> None:
    s = _damped(1.0)
    rows = growth.stability_table({"tiny": s}, integrators=("verlet",), steps=300)
    assert [r.integrator for r in rows] == ["verlet"]
    assert rows[0].ratio == pytest.approx(1.0, rel=0.02)
    text = growth.format_stability(rows)
    assert "Gershgorin" in text and "tiny" in text and "verlet" in text


@pytest.mark.parametrize("integrator", ["implicit-euler", "xpbd"])
def test_integrators_without_a_dt_limit_say_so(small: SpringSystem, integrator: str) -> None:
    """dt_limit names why there is none (every name of deformgl.INTEGRATORS is accepted by
    check_dt, which never refuses these)."""
    from deformgl.sim.limits import check_dt, dt_limit

    with pytest.raises(ValueError, match=f"{integrator} has no explicit dt limit"):
        dt_limit(small, integrator)
    assert check_dt(small, integrator, 1.0) is None
