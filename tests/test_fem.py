"""The calibrated lattice against continuum elasticity (issue 12, item 3): the patch test, a
uniaxial block, the static solver, scale invariance, and convergence to hexahedral FEM
(scikit-fem, the optional 'fem' extra) with the cantilever's targets."""

from __future__ import annotations

import math

import numpy as np
import pytest

from deformgl.bench.fem import (MATERIAL, WORKLOADS, face_weights, lattice_case, lattice_value,
                                stiffness_matrix, static_displacement)
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.materials import ElasticMaterial, lattice_stiffness, lattice_system
from deformgl.sim.springs import forces, from_grid

CANTILEVER = WORKLOADS["cantilever"]


def block(n, h=0.01, material=MATERIAL, **kw):
    grid = NodeGrid(np.zeros(3), h, np.ones((n, n, n), bool))
    system, _ = lattice_system(grid, material, gravity=(0.0, 0.0, 0.0), **kw)
    return grid, system


def test_stiffness_matrix_is_the_jacobian_of_the_spring_forces():
    grid, system = block(3)
    rng = np.random.default_rng(1)
    du = 1e-9 * rng.standard_normal((system.count, 3))  # h = 0.01: the nonlinear terms ~ 1e-7
    x0 = system.rest_positions
    df = forces(system, x0 + du, np.zeros_like(x0), 0.0) - forces(system, x0, np.zeros_like(x0), 0.0)
    k_du = stiffness_matrix(system) @ du.ravel()
    np.testing.assert_allclose(-k_du, df.ravel(), rtol=0, atol=1e-6 * np.abs(k_du).max())


@pytest.mark.parametrize("strain", ["xx", "shear", "random"])
def test_patch_test_a_uniform_strain_gives_the_stress_of_the_elasticity_tensor(strain):
    """Virial stress of the block's internal forces under an affine displacement equals
    C : eps with C11 = 3k/h, C12 = C44 = k/h (lambda = mu = k/h), k = 2 E h / 5."""
    n, h = 5, 0.01
    grid, system = block(n, h)
    eps = {"xx": np.diag([1.0, 0.0, 0.0]),
           "shear": np.array([[0, 1.0, 0], [1.0, 0, 0], [0, 0, 0]]) / 2,
           "random": (lambda a: (a + a.T) / 2)(np.random.default_rng(3).standard_normal((3, 3)))}[strain]
    eps = 1e-7 * eps
    x0 = system.rest_positions
    x = x0 + x0 @ eps.T
    f = forces(system, x, np.zeros_like(x), 0.0)
    volume = ((n - 1) * h) ** 3
    sigma = -(x.T @ f) / volume                      # the virial (Cauchy) stress, tension positive
    k = lattice_stiffness(MATERIAL, h)
    assert k == pytest.approx(0.4 * MATERIAL.youngs_modulus * h)
    lam = mu = k / h
    expected = lam * np.trace(eps) * np.eye(3) + 2 * mu * eps
    np.testing.assert_allclose(sigma, expected, rtol=0, atol=1e-5 * np.abs(expected).max())
    if strain == "xx":  # C11 and C12 by name
        assert sigma[0, 0] / eps[0, 0] == pytest.approx(3 * k / h, rel=1e-5)
        assert sigma[1, 1] / eps[0, 0] == pytest.approx(k / h, rel=1e-5)
    if strain == "shear":  # C44: sigma_xy = C44 * gamma_xy = C44 * 2 eps_xy
        assert sigma[0, 1] / (2 * eps[0, 1]) == pytest.approx(k / h, rel=1e-5)


def uniaxial(n, h=0.01, p=1.0e4, material=MATERIAL):
    """A block on three symmetry planes (rollers) under a pressure on its top face: E and nu
    (tests/test_volume.py uses it at nu > 1/4)."""
    grid, system = block(n, h, material)
    ijk = grid.ijk
    hold = np.zeros((system.count, 3), bool)
    for axis in range(3):
        hold[:, axis] = ijk[:, axis] == 0
    f = np.zeros((system.count, 3))
    top, area = face_weights(grid, 1, 1)
    f[top, 1] = -p * area
    u = static_displacement(system, f, hold)
    size = (n - 1) * h
    strain_y = (area * u[top, 1]).sum() / area.sum() / size
    side, a2 = face_weights(grid, 0, 1)
    strain_x = (a2 * u[side, 0]).sum() / a2.sum() / size
    return -p / strain_y, -strain_x / strain_y


@pytest.mark.parametrize("n", [2, 3, 6])
def test_a_uniaxial_block_has_the_materials_youngs_modulus_and_poissons_ratio_a_quarter(n):
    """Exact at any resolution (the patch test: the affine field is the lattice's solution)."""
    e, nu = uniaxial(n)
    assert e == pytest.approx(MATERIAL.youngs_modulus, rel=1e-9)
    assert nu == pytest.approx(0.25, rel=1e-9)


def test_the_static_solve_is_what_a_damped_run_settles_to():
    """The 2-across cantilever, critically damped (mass damping 2 w1), run with the NumPy
    backend to 0.6 s: its tip equals the static solve's to 0.1 % (the springs are nonlinear;
    the tip moves 0.8 % of the length)."""
    from deformgl.sim.materials import critical_dt
    from deformgl.sim.simulation import make_simulation

    material = ElasticMaterial(MATERIAL.youngs_modulus, MATERIAL.density, mass_damping=70.0)
    case = lattice_case(CANTILEVER, 2, material)
    static = lattice_value(case)
    dt = 0.5 * critical_dt(material, case.spacing)
    steps = int(0.6 / dt)
    with make_simulation(case.system, "verlet", "numpy", dt=dt) as sim:
        sim.step(steps)
        u = sim.positions() - case.system.rest_positions
    assert lattice_value(case, u) == pytest.approx(static, rel=1e-3)


def test_the_static_solve_refuses_a_body_that_is_not_held():
    grid, system = block(3)
    from deformgl.errors import DeformglError

    with pytest.raises(DeformglError, match="singular"):
        static_displacement(system, np.ones((system.count, 3)))


def test_the_same_cantilever_at_any_scale_deforms_by_the_physical_factor():
    """E and rho fixed, every length x s: the weight grows as s^3, the bending stiffness E I / L^3
    as s, so the tip moves s^2 as far (tip / L grows as s)."""
    base = lattice_value(lattice_case(CANTILEVER, 3))
    for s in (0.01, 100.0):
        tip = lattice_value(lattice_case(CANTILEVER, 3, scale=s))
        assert tip / base == pytest.approx(s * s, rel=1e-6)
        assert (tip / s) / base == pytest.approx(s, rel=1e-6)


def test_the_lattice_is_resolution_independent_in_mass():
    for n in (2, 5, 9):
        case = lattice_case(CANTILEVER, n)
        assert case.system.mass.sum() == pytest.approx(MATERIAL.density * 1.0 * 0.1 * 0.1, rel=1e-12)


# ---- against FEM (the 'fem' extra) --------------------------------------------------------------

@pytest.fixture(scope="module")
def cantilever_fem():
    from deformgl.bench.fem import fem_reference

    return fem_reference(CANTILEVER, (1, 2, 4))


@pytest.mark.fem
@pytest.mark.slow
def test_fem_converges_and_lies_between_euler_bernoulli_and_timoshenko(cantilever_fem):
    """L/a = 10: the clamped 3D beam is stiffer than Timoshenko's (the clamp holds the root's
    section against shear warping) and softer than Euler-Bernoulli's; within 1 % of both."""
    from deformgl.bench.fem import beam_theory, observed_order

    value, err, results = cantilever_fem
    assert err < 1e-3                       # FEM itself converged to 0.1 %
    assert observed_order(results) > 1.5
    eb, timo = beam_theory(CANTILEVER)
    assert eb < value < timo
    assert value / eb == pytest.approx(1.0, abs=0.01)
    assert value / timo == pytest.approx(1.0, abs=0.01)


@pytest.mark.fem
@pytest.mark.slow
def test_the_lattice_converges_to_fem_at_second_order(cantilever_fem):
    from studies.accuracy import fitted_order

    fem, _, _ = cantilever_fem
    across = (2, 3, 4, 5, 9)
    cases = [lattice_case(CANTILEVER, n) for n in across]
    ratios = [lattice_value(c) / fem for c in cases]
    errors = [abs(r - 1) for r in ratios]
    assert all(a > b for a, b in zip(errors, errors[1:]))        # monotone in h
    assert errors[-1] < 0.02                                      # 9 across: within 2 %
    assert fitted_order([c.spacing for c in cases], errors) > 1.5
    # the first measurement: 0.54, 0.81, 0.90, 0.94, 0.984 x FEM
    np.testing.assert_allclose(ratios, [0.54, 0.81, 0.90, 0.94, 0.984], atol=0.006)


@pytest.mark.fem
@pytest.mark.slow
def test_at_17_nodes_across_the_tip_is_within_half_a_percent_of_fem(cantilever_fem):
    fem, _, _ = cantilever_fem
    assert lattice_value(lattice_case(CANTILEVER, 17)) / fem == pytest.approx(1.0, abs=0.005)


@pytest.mark.fem
@pytest.mark.slow
def test_the_uncalibrated_lattice_misses_the_target(cantilever_fem):
    """k = 0.4 E h on every spring and m = rho h^3 on every node, no cell weighting: the
    boundary is too stiff and too heavy, and the 9-across tip misses the 2 % target."""
    fem, _, _ = cantilever_fem

    def uniform(grid, fixed, gravity):
        h = grid.spacing
        k = lattice_stiffness(MATERIAL, h)
        return from_grid(grid, k_structural=k, k_shear=k, mass=MATERIAL.density * h ** 3,
                         fixed=fixed, gravity=gravity)
    calibrated = lattice_value(lattice_case(CANTILEVER, 9)) / fem
    uncalibrated = lattice_value(lattice_case(CANTILEVER, 9, build=uniform)) / fem
    assert abs(calibrated - 1) < 0.02
    assert abs(uncalibrated - 1) > 0.02


@pytest.mark.fem
def test_block_and_twist_converge_to_fem():
    from deformgl.bench.fem import fem_reference

    for name, meshes in (("block", (2, 4)), ("twist", (2, 4))):
        w = WORKLOADS[name]
        fem, _, _ = fem_reference(w, meshes)
        errors = [abs(lattice_value(lattice_case(w, n)) / fem - 1) for n in (3, 5, 9)]
        assert errors[0] > errors[1] > errors[2], (name, errors)
        assert errors[2] < (0.01 if name == "block" else 0.06), (name, errors)  # twist: 5.6 %
    assert math.isfinite(fem)


def test_the_fragment_backend_settles_on_the_static_solve_too(ctx):
    """The GPU (float32, per-spring stiffness and mass damping) on the coarsest cantilever."""
    from deformgl.sim.materials import critical_dt
    from deformgl.sim.simulation import make_simulation

    material = ElasticMaterial(MATERIAL.youngs_modulus, MATERIAL.density, mass_damping=70.0)
    case = lattice_case(CANTILEVER, 2, material)
    dt = 0.5 * critical_dt(material, case.spacing, barrier=False)  # (float32 Verlet: no smaller, ACCURACY 4)
    with make_simulation(case.system, "verlet", "fragment", dt=dt, ctx=ctx) as sim:
        sim.step(int(0.6 / dt))
        u = sim.positions().astype(np.float64) - case.system.rest_positions
    assert lattice_value(case, u) == pytest.approx(lattice_value(case), rel=2e-3)


@pytest.mark.fem
@pytest.mark.slow
def test_the_accuracy_study_prints_the_table_and_writes_its_files(tmp_path, capsys):
    import json

    from studies.accuracy import main

    assert main(["--quick", "--quiet", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "fitted order" in out and "Euler-Bernoulli" in out and "nu" in out
    data = json.loads((tmp_path / "accuracy.json").read_text())
    nine = next(r for r in data["rows"] if r["workload"] == "cantilever" and r["across"] == 9)
    assert 0.98 < nine["ratio"] < 0.99            # against the quick (2-across) FEM
    assert (tmp_path / "accuracy.csv").read_text().startswith("workload,across,spacing")
