"""Implicit Euler with the lattice's full cells (issue 27): the cells' Hessian
(:mod:`deformgl.sim.terms.volume.hessian`) against the energy's derivatives, the NumPy backend reaching
the static equilibrium at nu = 0.45, the GPU backend against the NumPy one at nu = 0.25 and 0.45,
a squashed block kept un-inverted by the barrier, and the Gauss-Newton choice measured against
the eigenvalue projection and the exact Hessian."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from deformgl.bench.fem import WORKLOADS, lattice_case
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.terms.volume.hessian import cell_matrix, cell_product
from deformgl.sim.integrators import State
from deformgl.sim.materials import ElasticMaterial, lattice_system
from deformgl.sim.simulation import make_simulation
from deformgl.sim.springs import forces
from deformgl.sim.scripted import Load
from deformgl.sim.terms.volume.energy import BARRIER_J, cell_state, corner_jacobians, inverted_cells, volume_forces

H = 0.02  # m, the small blocks' spacing


def _material(nu: float, mass_damping: float = 1.0) -> ElasticMaterial:
    return ElasticMaterial(3.0e3, 1060.0, mass_damping=mass_damping, poissons_ratio=nu)


def _shaken(nu: float, across: int = 3):
    """The soft cantilever of tests/test_implicit.py at ``nu``, every free node moved by 0.15 h
    (seeded): some corners inside the barrier."""
    mat = ElasticMaterial(3.0e3, 1060.0, mass_damping=1.0, stiffness_damping=1e-3, poissons_ratio=nu)
    case = lattice_case(WORKLOADS["cantilever"], across, mat)
    s = case.system
    x0 = s.rest_positions + 0.15 * case.spacing * np.random.default_rng(5).normal(size=(s.count, 3))
    x0[s.fixed] = s.rest_positions[s.fixed]
    return s, x0


def _squash(nu: float, barrier: bool = True):
    """A 4x4x4-node block clamped at its bottom, half of its top pushed down by 0.2 N a node
    (5 to 20 times a pushed node's weight), no gravity."""
    grid = NodeGrid(np.zeros(3), H, np.ones((4, 4, 4), bool))
    ijk = grid.ijk
    s, _ = lattice_system(grid, _material(nu, 2.0), fixed=ijk[:, 1] == 0, gravity=(0.0, 0.0, 0.0))
    if not barrier:
        s = dataclasses.replace(s, cells=dataclasses.replace(s.cells, barrier_modulus=0.0))
    return s, (Load((ijk[:, 1] == 3) & (ijk[:, 0] >= 2), lambda t: (0.0, -0.2, 0.0)),)


def test_cell_hessian_is_the_energy_second_derivative():
    """The exact Hessian is the central difference of volume_forces (centre term and barriers);
    the Gauss-Newton part and the projection are positive semidefinite; the matrix-free product
    (the GPU's twin) is the assembled matrix's."""
    grid = NodeGrid(np.zeros(3), H, np.ones((3, 3, 2), bool))
    s, _ = lattice_system(grid, _material(0.45))
    x = s.rest_positions + 0.3 * H * np.random.default_rng(1).normal(size=(s.count, 3))
    cells, n = s.cells, s.count
    det, _ = corner_jacobians(cells, x)
    assert (det < cells.barrier_j).sum() >= 5                       # barriers in play
    k = np.zeros((3 * n, 3 * n))
    step = 1e-7 * H
    for i in range(3 * n):
        plus, minus = x.copy().ravel(), x.copy().ravel()
        plus[i] += step
        minus[i] -= step
        k[:, i] = -(volume_forces(cells, plus.reshape(-1, 3)) - volume_forces(cells, minus.reshape(-1, 3))).ravel() / (2 * step)
    full = cell_matrix(cells, x, n, "full").toarray()
    assert np.abs(full - k).max() <= 1e-6 * np.abs(k).max()
    gauss = cell_matrix(cells, x, n, "gauss-newton").toarray()
    eigen = cell_matrix(cells, x, n, "eigen").toarray()
    scale = np.abs(full).max()
    assert np.linalg.eigvalsh(full).min() < -0.1 * scale            # the exact Hessian is indefinite
    assert np.linalg.eigvalsh(gauss).min() >= -1e-12 * scale
    assert np.linalg.eigvalsh(eigen).min() >= -1e-12 * scale
    assert np.abs(eigen - eigen.T).max() <= 1e-12 * scale
    y = np.random.default_rng(1).normal(size=(n, 3))
    for kind, matrix in (("gauss-newton", gauss), ("full", full)):
        product = cell_product(cells, x, y, kind).ravel()
        assert np.abs(product - matrix @ y.ravel()).max() <= 1e-12 * np.abs(matrix @ y.ravel()).max()


@pytest.mark.parametrize("stretch", [1.1, 0.9])
def test_geometric_part_is_indefinite_wherever_it_is_not_zero(stretch):
    """One cell stretched uniformly (F = s I, J = s^3): the exact centre block's lowest eigenvalue
    is -V kappa |J - 1| s / (2 h^2) (the flips for J > 1, the twists for J < 1; B B^T = I / (2 h^2)),
    whatever the Gauss-Newton part: the reason "projected" keeps only that part."""
    grid = NodeGrid(np.zeros(3), H, np.ones((2, 2, 2), bool))
    s, _ = lattice_system(grid, _material(0.45))
    cells = dataclasses.replace(s.cells, barrier_modulus=0.0)
    x = stretch * s.rest_positions
    full = cell_matrix(cells, x, 8, "full").toarray()
    j = stretch ** 3
    expected = -cells.volume * cells.volume_modulus * abs(j - 1) * stretch / (2 * H * H)
    assert np.linalg.eigvalsh(full).min() == pytest.approx(expected, rel=1e-9)
    assert np.linalg.eigvalsh(cell_matrix(cells, x, 8).toarray()).min() >= -1e-9 * abs(expected)


def _cantilever(nu: float):
    grid = NodeGrid(np.zeros(3), H, np.ones((5, 3, 3), bool))
    s, _ = lattice_system(grid, _material(nu), fixed=grid.ijk[:, 0] == 0)
    return s


@pytest.mark.parametrize("options", [{"solver": "direct"}, {"cg_iterations": 40}])
def test_numpy_reaches_the_static_equilibrium_at_nu_045(options):
    """A 5x3x3-node block clamped at one end, under gravity, sagging 3/4 of its length: 80 steps
    of dt = 1/30 s end where springs.forces (cells included) is zero; the volume changes less
    than at nu = 1/4."""
    spread = {}
    for nu in (0.25, 0.45):
        s = _cantilever(nu)
        sim = make_simulation(s, "implicit-euler", "numpy", dt=1 / 30, **options)
        sim.step(80)
        x = sim.positions()
        f = forces(s, x, np.zeros_like(x), sim.t)
        assert np.abs(f[~s.fixed]).max() <= 1e-5 * (s.mass.max() * 9.81)   # measured 1.4e-6, 7.5e-7
        assert np.abs(sim.velocities()).max() <= 1e-4 * H
        assert x[:, 1].min() < -0.05                                        # a large deflection
        j, _ = cell_state(s.cells, x)
        spread[nu] = np.abs(j - 1).max()
    assert spread[0.45] < 0.5 * spread[0.25]                                # measured 0.091 vs 0.26


@pytest.mark.parametrize("nu", [0.25, 0.45])
@pytest.mark.parametrize("preconditioner", ["jacobi", "block-jacobi"])
def test_gpu_matches_numpy_with_cells(ctx, nu, preconditioner):
    """The tolerances of tests/test_implicit.py (1e-5 of dv, 1e-3 of the residual), on a body
    with corners inside the barrier (and at nu = 0.45 the centre term)."""
    s, x0 = _shaken(nu)
    assert (corner_jacobians(s.cells, x0)[0] < s.cells.barrier_j).sum() > 20
    opts = dict(dt=1 / 60, state=State(x0, np.zeros_like(x0), x0), cg_iterations=6, cg_preconditioner=preconditioner)
    ref = make_simulation(s, "implicit-euler", "numpy", **opts)
    springs_only = make_simulation(dataclasses.replace(s, cells=None), "implicit-euler", "numpy", **opts)
    springs_only.step()
    with make_simulation(s, "implicit-euler", "fragment", ctx=ctx, **opts) as gpu:
        for k in range(3):
            ref.step()
            gpu.step()
            assert np.abs(gpu.velocity_change() - ref.dv).max() <= 1e-5 * np.abs(ref.dv).max()   # measured <= 5e-6
            assert gpu.residual() == pytest.approx(ref.last_report.residual, rel=1e-3)
            if k == 0:   # the cells change the step (so the comparison sees them)
                assert np.abs(springs_only.dv - ref.dv).max() > 0.05 * np.abs(ref.dv).max()


def test_squashed_block_stays_finite_and_uninverted(ctx):
    """Corners go deep into the barrier (J_c down to 0.17) and no cell inverts, on both backends,
    at dt = 1/30 s; without the barrier the same push inverts cells."""
    s, loads = _squash(0.25)
    opts = dict(dt=1 / 30, loads=loads, cg_iterations=30)
    ref = make_simulation(s, "implicit-euler", "numpy", **opts)
    with make_simulation(s, "implicit-euler", "fragment", ctx=ctx, **opts) as gpu:
        lowest = {"numpy": 1.0, "fragment": 1.0}
        for _ in range(20):
            ref.step()
            gpu.step()
            for name, sim in (("numpy", ref), ("fragment", gpu)):
                x = sim.positions().astype(np.float64)
                assert np.all(np.isfinite(x))
                assert not inverted_cells(s.cells.corners, H, x).any()
                lowest[name] = min(lowest[name], corner_jacobians(s.cells, x)[0].min())
        assert lowest["numpy"] < BARRIER_J - 0.1 and lowest["fragment"] < BARRIER_J - 0.1  # inside the barrier
        assert np.abs(gpu.positions() - ref.positions()).max() <= 1e-5 * H      # measured 2.7e-7
    soft, loads = _squash(0.25, barrier=False)
    bare = make_simulation(soft, "implicit-euler", "numpy", **{**opts, "loads": loads})
    bare.step(20)
    assert inverted_cells(soft.cells.corners, H, bare.positions()).sum() >= 5


def test_gauss_newton_against_projection_and_exact_hessian():
    """The choice of the cells' Hessian, measured (direct solves): the exact Hessian ("full")
    inverts and blows up the squashed block at nu = 1/4 (which "projected" keeps whole, above);
    the eigenvalue projection ("eigen") reaches the static equilibrium in fewer steps than the
    Gauss-Newton part ("projected") at nu = 0.45 (residual after 40 steps: 2.0e-4 vs 9.1e-4 of
    the largest node weight)."""
    s, loads = _squash(0.25)
    exact = make_simulation(s, "implicit-euler", "numpy", dt=1 / 30, loads=loads, solver="direct", geometric="full")
    exact.step(30)
    assert inverted_cells(s.cells.corners, H, exact.positions()).any()
    residual = {}
    s = _cantilever(0.45)
    for geometric in ("projected", "eigen"):
        sim = make_simulation(s, "implicit-euler", "numpy", dt=1 / 30, solver="direct", geometric=geometric)
        sim.step(40)
        x = sim.positions()
        residual[geometric] = np.abs(forces(s, x, np.zeros_like(x), sim.t)[~s.fixed]).max() / (s.mass.max() * 9.81)
    assert residual["eigen"] < 0.5 * residual["projected"] < 2e-3


def test_springs_only_systems_have_no_cell_passes(ctx):
    from deformgl.sim.backends.implicit_passes import pass_defines
    from deformgl.sim.springs import from_grid

    grid = NodeGrid(np.zeros(3), H, np.ones((3, 3, 3), bool))
    s = from_grid(grid, k_structural=10.0, k_shear=5.0, fixed=grid.ijk[:, 1] == 0)
    assert s.cells is None
    with make_simulation(s, "implicit-euler", "fragment", ctx=ctx, dt=1 / 60, cg_iterations=5) as gpu:
        assert gpu.tex_hood is None
        gpu.step(2)
        ref = make_simulation(s, "implicit-euler", "numpy", dt=1 / 60, cg_iterations=5)
        ref.step(2)
        assert np.abs(gpu.positions() - ref.positions()).max() <= 1e-6
    from deformgl.sim.terms.glsl import pass_terms

    def term_defines(system):
        return pass_terms(system.terms, "implicit", "test", grid, implicit=True).defines()

    defines = pass_defines(s, flexion=False, weights=False, drags=0, loads=0, constraints=None,
                           term_defines=term_defines(s))
    assert not any("TERM_CELL" in d for d in defines.values())
    for nu, terms in ((0.25, {"CELL_BARRIER"}), (0.45, {"CELL_CENTRE", "CELL_BARRIER"})):
        lattice, _ = lattice_system(grid, _material(nu))
        with_cells = pass_defines(lattice, flexion=False, weights=False, drags=0, loads=0, constraints=None,
                                  term_defines=term_defines(lattice))
        assert [name for name, d in with_cells.items() if "TERM_CELL" in d] == ["SETUP", "WARM", "INIT", "MATVEC", "TRUE_RESIDUAL"]
        assert {k for k in ("CELL_CENTRE", "CELL_BARRIER") if with_cells["MATVEC"].get(k)} == terms
