"""XPBD with the cells' volumetric term (issue 27; deformgl/sim/terms/volume/xpbd_form.py): the volume and
barrier constraints are exactly the energies of deformgl/sim/terms/volume/energy.py, XPBD settles to the
force-based static equilibrium at nu = 0.45, small strains at nu = 1/4 are the springs' alone bit
for bit, an inverted block recovers, and the fragment passes match the float64 reference at
nu = 0.25 and 0.45."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from deformgl.grid.nodes import NodeGrid
from deformgl.sim.integrators import State
from deformgl.sim.materials import ElasticMaterial, critical_dt, lattice_system
from deformgl.sim.simulation import make_simulation
from deformgl.sim.springs import cloth, forces
from deformgl.sim.terms.volume.energy import corner_jacobians, inverted_cells
from deformgl.sim.xpbd import XpbdNumpy, XpbdSettings, XpbdSolver, constraint_counts, term_constraints
from test_xpbd import _everything  # loads, a drag, a ground and a sphere: every term of the sweep


def _block(n=3, nu=0.45, e=1.0e4, size=0.1, gravity=(0.0, -9.81, 0.0), **material):
    grid = NodeGrid(np.zeros(3), size / (n - 1), np.ones((n, n, n), bool))
    mat = ElasticMaterial(e, 1000.0, poissons_ratio=nu, **material)
    system, _ = lattice_system(grid, mat, fixed=grid.ijk[:, 1] == 0, gravity=gravity)
    return system, mat


def _crushed(system, amount=0.45, seed=0):
    """Free nodes moved at random by up to ``amount`` spacings: corners below J_b, some inverted."""
    rng = np.random.default_rng(seed)
    x = system.rest_positions + amount * system.spacing * rng.uniform(-1, 1, (system.count, 3))
    return np.where(system.fixed[:, None], system.rest_positions, x)


def _mirrored(system):
    """The block reflected through its fixed base (y -> -y): every cell inverted, every spring at
    its rest length."""
    x = system.rest_positions.copy()
    x[:, 1] *= -1.0
    return x


@pytest.mark.parametrize("nu", [0.25, 0.45])
def test_the_constraints_are_the_cell_energies(nu):
    """A substep solved to convergence is ``M (x - x~) = h^2 grad C^T lambda`` with the
    multipliers of the compliances; as h -> 0 that is ``h^2 f(x)`` with f the springs' and
    volume_forces' force: the constraint potentials are the energies (the difference is O(h^2),
    XPBD's linearisation of the gradients along the substep; measured 1.2e-6 and 1.7e-6)."""
    system, _ = _block((4), nu, gravity=(0.0, 0.0, 0.0))
    cells = system.cells
    x = _crushed(system)
    det, _ = corner_jacobians(cells, x)
    assert (det <= 0).any() and (det < cells.barrier_j).sum() > 10  # barriers act, some cells inverted
    solver = XpbdSolver(system, XpbdSettings(iterations=300))
    (cell_constraints,) = solver.term_constraints
    assert np.allclose(cell_constraints.corner_dets(x), det, rtol=0, atol=1e-12)
    h = 1e-6
    p, _ = solver.substep(x, np.zeros_like(x), h, 0.0)
    f = forces(system, p, np.zeros_like(p), 0.0)
    free = ~system.fixed
    inertia = system.mass[:, None] * (p - x) / h ** 2
    assert np.abs(inertia - f)[free].max() < 1e-5 * np.abs(f[free]).max()
    lam_v, lam_b = solver.term_multipliers[0]
    assert (lam_b > 0).sum() > 10 and np.all(lam_b >= 0)
    assert (nu > 0.25) == bool(np.any(lam_v != 0))  # the volume constraints exist only above 1/4


def test_constraint_counts_add_the_volume_constraints():
    system, _ = _block(3, 0.45)
    springs_only = constraint_counts(dataclasses.replace(system, cells=None))
    assert np.array_equal(constraint_counts(system) - springs_only,
                          np.bincount(system.cells.corners.reshape(-1), minlength=system.count))
    quarter, _ = _block(3, 0.25)
    assert np.array_equal(constraint_counts(quarter), constraint_counts(dataclasses.replace(quarter, cells=None)))
    assert term_constraints(dataclasses.replace(system, cells=None), np.ones(system.count)) == ()


def test_small_strains_at_a_quarter_are_the_springs_alone_bit_for_bit():
    """At nu = 1/4 the volume term is absent and the barrier idle: XPBD is unchanged."""
    system, _ = _block(3, 0.25, mass_damping=3.0)
    with_cells = XpbdNumpy(system, 1.0 / 60.0, iterations=8, substeps=2)
    without = XpbdNumpy(dataclasses.replace(system, cells=None), 1.0 / 60.0, iterations=8, substeps=2)
    with_cells.step(20)
    without.step(20)
    assert np.abs(with_cells.positions() - system.rest_positions).max() > 1e-4
    assert np.array_equal(with_cells.positions(), without.positions())
    assert with_cells.residual == pytest.approx(without.residual, rel=1e-14)  # (a norm over more zeros)
    assert not np.any(with_cells.solver.term_multipliers[0][1])


def _settled(system, material, seconds=3.0):
    """The force-based static equilibrium: damped Verlet on springs.forces, settled."""
    dt = 0.5 * critical_dt(material, system.spacing, "verlet")
    sim = make_simulation(system, "verlet", "numpy", dt=dt)
    sim.step(int(seconds / dt))
    return sim.positions()


def test_settles_to_the_force_based_static_equilibrium_at_045():
    """A clamped block under gravity at nu = 0.45: XPBD (20 sweeps x 8 substeps of 1/30 s) comes
    to rest at the equilibrium of springs.forces (springs + cells) within 1 % of the sag
    (measured 0.2 %); without the cells that equilibrium is 52 % away."""
    system, material = _block(3, 0.45, mass_damping=30.0)
    reference = _settled(system, material)
    springs_only = _settled(dataclasses.replace(system, cells=None), material)
    sag = np.abs(reference - system.rest_positions).max()
    assert np.abs(springs_only - reference).max() > 0.3 * sag  # the term matters here
    weight = np.abs(system.mass[:, None] * system.gravity).max()
    assert np.abs(forces(system, reference, np.zeros_like(reference), 0.0)[~system.fixed]).max() < 1e-9 * weight
    sim = XpbdNumpy(system, 1.0 / 30.0, iterations=20, substeps=8)
    sim.step(30)
    x = sim.positions()
    assert np.abs(x - reference).max() < 0.01 * sag
    residual_force = forces(system, x, np.zeros_like(x), 0.0)[~system.fixed]
    assert np.abs(residual_force).max() < 0.03 * weight  # measured 0.9 %
    assert not inverted_cells(system.cells.corners, system.spacing, x).any()


@pytest.mark.parametrize("nu", [0.25, 0.45])
def test_an_inverted_block_recovers(nu):
    """Large strain: the block's mirror image through its fixed base satisfies every distance
    constraint, so springs alone keep it; the cells' barrier (and at 0.45 the volume
    constraint) turn it back: finite, no cell inverted."""
    system, _ = _block(3, nu, mass_damping=10.0)
    cells = system.cells
    x = _mirrored(system)
    assert inverted_cells(cells.corners, system.spacing, x).all()
    state = State(x, np.zeros_like(x), x.copy())
    springs_only = XpbdNumpy(dataclasses.replace(system, cells=None), 0.02, iterations=20, substeps=2, state=state)
    springs_only.step(20)
    assert inverted_cells(cells.corners, system.spacing, springs_only.positions()).all()
    sim = XpbdNumpy(system, 0.02, iterations=20, substeps=2, state=state)
    sim.step(20)
    y = sim.positions()
    assert np.all(np.isfinite(y)) and not inverted_cells(cells.corners, system.spacing, y).any()
    assert y[:, 1].min() > -1e-9 and y[:, 1].max() > 0.08  # upright again


@pytest.mark.gl
@pytest.mark.parametrize("nu", [0.25, 0.45])
def test_fragment_passes_match_the_float64_reference(ctx, nu):
    """From a crushed state (barriers active, cells inverted) with loads, a drag, the ground and
    a sphere: the GPU's cell pass and gather are the float64 sweep, within the tolerances of
    tests/test_xpbd.py (measured: positions 7e-7 and velocities 1.5e-6 after a step, positions
    8e-7 after 11; the residual 7e-8 at 0.25 and 1.5e-3 at 0.45, where J - 1 of the nearly
    incompressible cells is a few float32 roundings of the read-back positions)."""
    system, _ = _block(4, nu, e=1.0e5, mass_damping=3.0, stiffness_damping=1e-3)
    x0 = _crushed(system)
    state = State(x0, np.zeros_like(x0), x0.copy())
    opts = _everything(system)
    dt = 1.0 / 30.0
    ref = make_simulation(system, "xpbd", "numpy", dt=dt, iterations=12, substeps=2, state=state, **opts)
    with make_simulation(system, "xpbd", "fragment", dt=dt, ctx=ctx, iterations=12, substeps=2, state=state,
                         **opts) as gpu:
        assert len(gpu.term_passes) == 1
        springs_only = make_simulation(dataclasses.replace(system, cells=None), "xpbd", "numpy", dt=dt,
                                       iterations=12, substeps=2, state=state, **opts)
        ref.step(1)
        gpu.step(1)
        springs_only.step(1)
        moved = np.abs(ref.positions() - x0).max()
        assert np.abs(springs_only.positions() - ref.positions()).max() > 0.01 * moved  # the cells act (1e3 x the tolerance)
        assert moved > 1e-3
        assert np.abs(gpu.positions() - ref.positions()).max() / moved < 1e-5
        assert np.abs(gpu.velocities() - ref.velocities()).max() / np.abs(ref.velocities()).max() < 1e-5
        # (both count each spring once; measured within 1e-8 at nu 0.3 and 0.45; a corner at J_b in
        # float32 and not in float64 could move the barriers' share)
        assert gpu.residual == pytest.approx(ref.residual, rel=1e-3)
        ref.step(10)
        gpu.step(10)
        assert np.abs(gpu.positions() - ref.positions()).max() / np.abs(ref.positions() - x0).max() < 1e-4


@pytest.mark.gl
def test_the_gpu_turns_an_inverted_block_back(ctx):
    system, _ = _block(3, 0.45, mass_damping=10.0)
    x = _mirrored(system)
    state = State(x, np.zeros_like(x), x.copy())
    with make_simulation(system, "xpbd", "fragment", dt=0.02, ctx=ctx, iterations=20, substeps=2,
                         state=state) as gpu:
        gpu.step(20)
        y = gpu.positions().astype(np.float64)
    assert np.all(np.isfinite(y)) and not inverted_cells(system.cells.corners, system.spacing, y).any()
    assert y[:, 1].max() > 0.08


@pytest.mark.gl
def test_systems_without_cells_build_no_cell_pass(ctx):
    sheet = cloth(4, 4, 0.05, k_structural=100.0, k_shear=50.0)
    assert sheet.cells is None
    with make_simulation(sheet, "xpbd", "fragment", dt=0.01, ctx=ctx, iterations=4) as gpu:
        assert not gpu.term_passes
        ref = make_simulation(sheet, "xpbd", "numpy", dt=0.01, iterations=4)
        gpu.step(5)
        ref.step(5)
        assert np.abs(gpu.positions() - ref.positions()).max() < 1e-5 * np.abs(ref.positions()).max()
