"""The lattice's volumetric term and inversion barrier (issue 27): forces are the energy's
gradient, the patch test at any Poisson's ratio, a uniaxial block gives (E, nu) exactly, the
barrier acts only below J_b and pushes an inverted cell back, the inversion census, and the
material's checks."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from deformgl.bench.fem import stiffness_matrix
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.materials import ElasticMaterial, critical_dt, lattice_system
from deformgl.sim.springs import forces, max_angular_frequency
from deformgl.sim.terms.volume.energy import (BARRIER_J, CellVolumes, corner_jacobians, describe_inverted,
                                              inverted_cells, rest_product, volume_energy, volume_forces)
from test_fem import uniaxial  # a block on three symmetry planes under a top-face pressure: E and nu

NUS = (0.25, 0.3, 0.45, 0.49)


def block(shape=(3, 3, 3), h=0.01, nu=0.45, e=1.0e4, occupied=None, **kw):
    occ = np.ones(shape, bool) if occupied is None else occupied
    grid = NodeGrid(np.zeros(3), h, occ)
    system, _ = lattice_system(grid, ElasticMaterial(e, 1000.0, poissons_ratio=nu), gravity=(0.0, 0.0, 0.0), **kw)
    return grid, system


def crushed(system, amount=0.45, seed=0):
    """Positions with every node moved at random by up to ``amount`` h: corners below J_b and
    some inverted."""
    rng = np.random.default_rng(seed)
    return system.rest_positions + amount * system.spacing * rng.uniform(-1, 1, (system.count, 3))


@pytest.mark.parametrize("nu", [0.25, 0.45])
def test_the_cell_forces_are_the_negative_gradient_of_the_cell_energy(nu):
    _, system = block((3, 4, 3), nu=nu)
    cells = system.cells
    x = crushed(system)
    det, _ = corner_jacobians(cells, x)
    assert (det < cells.barrier_j).any() and (det > cells.barrier_j).any()  # both branches are exercised
    f = volume_forces(cells, x)
    rng = np.random.default_rng(1)
    for _ in range(4):
        d = rng.standard_normal(x.shape)
        eps = 1e-7 * system.spacing
        slope = (volume_energy(cells, x + eps * d) - volume_energy(cells, x - eps * d)) / (2 * eps)
        assert -np.sum(f * d) == pytest.approx(slope, rel=1e-5, abs=1e-9 * np.abs(f).max())


@pytest.mark.parametrize("nu", NUS)
@pytest.mark.parametrize("strain", ["xx", "shear", "random"])
def test_patch_test_a_uniform_strain_gives_the_stress_of_lambda_and_mu_at_any_nu(nu, strain):
    """The springs (lambda = mu = k/h with k = mu h) plus the centre term (kappa = lambda - mu)
    are the isotropic tensor of (E, nu) under any uniform strain."""
    n, h = 5, 0.01
    _, system = block((n, n, n), h, nu)
    eps = {"xx": np.diag([1.0, 0.0, 0.0]), "shear": np.array([[0, 1.0, 0], [1.0, 0, 0], [0, 0, 0]]) / 2,
           "random": (lambda a: (a + a.T) / 2)(np.random.default_rng(3).standard_normal((3, 3)))}[strain]
    eps = 1e-7 * eps
    x0 = system.rest_positions
    x = x0 + x0 @ eps.T
    sigma = -(x.T @ forces(system, x, np.zeros_like(x), 0.0)) / ((n - 1) * h) ** 3
    m = system.material
    expected = m.lame_lambda * np.trace(eps) * np.eye(3) + 2 * m.shear_modulus * eps
    np.testing.assert_allclose(sigma, expected, rtol=0, atol=1e-5 * np.abs(expected).max())


@pytest.mark.parametrize("nu", NUS)
def test_a_uniaxial_block_has_the_materials_youngs_modulus_and_poissons_ratio(nu):
    """A block on three symmetry planes under a top-face pressure: E and nu exactly (the
    affine field is the lattice's solution), through the rest stiffness of springs + cells."""
    material = ElasticMaterial(1.0e4, 1000.0, poissons_ratio=nu)
    youngs, poisson = uniaxial(4, 0.01, 1.0e3, material)
    assert youngs == pytest.approx(material.youngs_modulus, rel=1e-9)
    assert poisson == pytest.approx(nu, rel=1e-9)


def test_the_rest_stiffness_is_the_jacobian_of_the_cell_forces():
    _, system = block((3, 3, 4), nu=0.49)
    x0 = system.rest_positions
    du = 1e-9 * np.random.default_rng(2).standard_normal(x0.shape)
    df = volume_forces(system.cells, x0 + du) - volume_forces(system.cells, x0)
    kdu = rest_product(system.cells, du)
    np.testing.assert_allclose(-kdu, df, rtol=0, atol=1e-6 * np.abs(kdu).max())
    no_cells = dataclasses.replace(system, cells=None)
    k_cells = stiffness_matrix(system) - stiffness_matrix(no_cells)
    np.testing.assert_allclose(k_cells @ du.ravel(), kdu.ravel(), rtol=0, atol=1e-9 * np.abs(kdu).max())


def test_at_a_quarter_small_strains_see_no_cell_force_and_the_springs_alone_are_unchanged():
    _, system = block((4, 4, 4), nu=0.25)
    assert system.cells.volume_modulus == 0.0 and system.cells.barrier_modulus > 0
    x = system.rest_positions + 0.05 * system.spacing * np.random.default_rng(4).uniform(-1, 1, (system.count, 3))
    det, _ = corner_jacobians(system.cells, x)
    assert det.min() > BARRIER_J
    assert not volume_forces(system.cells, x).any()
    springs_only = dataclasses.replace(system, cells=None)
    v = np.zeros_like(x)
    np.testing.assert_array_equal(forces(system, x, v, 0.0), forces(springs_only, x, v, 0.0))


def test_an_inverted_cell_is_pushed_back_and_its_energy_is_finite():
    """One cell mirrored through its x = h/2 plane: every spring keeps its length (no spring
    force), but the barrier's force points back towards the unmirrored cell."""
    _, system = block((2, 2, 2), nu=0.25)
    x0 = system.rest_positions
    x = x0.copy()
    x[:, 0] = system.spacing - x0[:, 0]                   # the mirror image
    assert inverted_cells(system.cells.corners, system.spacing, x).all()
    v = np.zeros_like(x)
    springs_only = dataclasses.replace(system, cells=None)
    np.testing.assert_allclose(forces(springs_only, x, v, 0.0), 0.0, atol=1e-12)
    f = forces(system, x, v, 0.0)
    assert np.isfinite(volume_energy(system.cells, x)) and volume_energy(system.cells, x) > 0
    # the nodes now at small x (they were at large x) are pushed towards larger x, and back
    low = x[:, 0] < system.spacing / 2
    assert (f[low, 0] > 0).all() and (f[~low, 0] < 0).all()


def test_the_census_counts_and_names_the_inverted_cells():
    grid, system = block((4, 3, 3), nu=0.25)
    x = system.rest_positions.copy()
    assert describe_inverted(system.cells, x, grid.ijk) == (0, "")
    node = grid.index[1, 1, 1]
    x[node, 0] += 1.5 * system.spacing                     # through its +x neighbours' corner planes
    count, phrase = describe_inverted(system.cells, x, grid.ijk)
    assert count == int(inverted_cells(system.cells.corners, system.spacing, x).sum()) > 0
    assert phrase.startswith(f"{count} of {system.cells.count} cells inverted (first: the cell at grid (")
    x[0, 1] = np.nan
    assert inverted_cells(system.cells.corners, system.spacing, x)[0]


def test_only_full_cells_carry_the_term():
    occ = np.ones((3, 3, 3), bool)
    occ[2, 2, 2] = False
    _, system = block(occupied=occ)
    assert system.cells.count == 7
    assert not np.isin(np.flatnonzero(~occ.ravel()), system.cells.corners).any()


@pytest.mark.parametrize("nu", [0.1, 0.2499, 0.5, 0.6, float("nan")])
def test_a_poissons_ratio_the_lattice_cannot_give_is_refused(nu):
    with pytest.raises(ValueError, match="poissons_ratio must be"):
        ElasticMaterial(1e4, 1000.0, poissons_ratio=nu)


@pytest.mark.parametrize("nu", NUS)
def test_the_critical_dt_is_the_gershgorin_bound_of_the_built_system(nu):
    """The material's formula (springs 36 mu, centre term 12 kappa, the barrier's envelope
    (sqrt(3) + 3)^2 kappa_b per rho h^2) equals the Gershgorin bound the dt check computes on a
    built block's interior node."""
    material = ElasticMaterial(2.0e4, 1100.0, poissons_ratio=nu)
    grid = NodeGrid(np.zeros(3), 0.004, np.ones((5, 5, 5), bool))
    system, _ = lattice_system(grid, material)
    omega = max_angular_frequency(system, barrier=True).omega
    assert critical_dt(material, 0.004) == pytest.approx(2.0 / omega, rel=1e-9)


def test_the_p_wave_speed_and_lame_constants():
    m = ElasticMaterial(1.0e4, 1000.0, poissons_ratio=0.45)
    assert m.shear_modulus == pytest.approx(1.0e4 / 2.9)
    assert m.lame_lambda == pytest.approx(1.0e4 * 0.45 / (1.45 * 0.1))
    assert m.volume_modulus == pytest.approx(m.lame_lambda - m.shear_modulus)
    assert m.wave_speed() == pytest.approx(np.sqrt((m.lame_lambda + 2 * m.shear_modulus) / 1000.0))
    quarter = ElasticMaterial(1.0e4, 1000.0)
    assert quarter.volume_modulus == 0.0 and quarter.wave_speed() == pytest.approx(np.sqrt(6 * 1.0e4 / 5 / 1000.0))


def test_cell_volumes_check_their_constants():
    with pytest.raises(ValueError, match="barrier_j"):
        CellVolumes(np.zeros((0, 8)), 0.01, 0.0, 1.0, barrier_j=1.5)
    with pytest.raises(ValueError, match="volume_modulus"):
        CellVolumes(np.zeros((0, 8)), 0.01, -1.0, 1.0)
