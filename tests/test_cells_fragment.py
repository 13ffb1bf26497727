"""The lattice's volumetric term (deformgl.sim.terms.volume.energy: any Poisson's ratio, the inversion barrier)
on the fragment backend against the float64 reference: shaders/terms/cell_forces.glsl alone
(NodeCellForces), then every integrator and the Verlet fast path on lattices at nu = 0.45,
dense and with holes, and with corners inside the barrier."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from deformgl.grid.nodes import NodeGrid
from deformgl.sim.terms.volume.check_pass import NodeCellForces, check_cells
from deformgl.sim.backends.explicit_gpu import FragmentIntegrator
from deformgl.sim.backends.verlet_pass import FoundationVerlet
from deformgl.sim.integrators import EXPLICIT_INTEGRATORS, initial_state
from deformgl.sim.materials import ElasticMaterial, lattice_system
from deformgl.sim.simulation import NumpySimulation
from deformgl.sim.springs import max_angular_frequency
from deformgl.sim.terms.volume.energy import BARRIER_SCALE, CellVolumes, corner_jacobians, grid_cells, volume_forces

pytestmark = pytest.mark.gl

H = 0.01
#: a holed grid: nodes missing inside, on a face and at corners, so some cells are not full
HOLES = ((0, 0, 0), (2, 1, 3), (3, 3, 5), (1, 2, 4))


def block(shape=(5, 4, 6), holes=()):
    occupied = np.ones(shape, bool)
    for ijk in holes:
        occupied[ijk] = False
    return NodeGrid(np.array([0.3, -0.2, 0.1]), H, occupied)


def material(nu):
    return ElasticMaterial(1e4, 1000.0, poissons_ratio=nu)


def cells_of(grid, nu):
    m = material(nu)
    return CellVolumes(grid_cells(grid.occupied, grid.index), H, m.volume_modulus, BARRIER_SCALE * m.shear_modulus)


def squashed(grid, rng, factor=0.3, noise=0.25):
    """Rest positions squashed along y to ``factor``: every corner Jacobian near ``factor`` < J_b,
    plus noise that inverts some."""
    x = grid.rest_positions.copy()
    x[:, 1] = grid.origin[1] + factor * (x[:, 1] - grid.origin[1])
    return x + rng.uniform(-noise, noise, x.shape) * H


@pytest.mark.parametrize("holes", [(), HOLES], ids=["dense", "holes"])
@pytest.mark.parametrize("nu", [0.25, 0.45])
def test_cell_forces_glsl_matches_volume_forces(ctx, holes, nu):
    """cell_forces (float32) against volume_forces (float64) at the same float32 positions:
    random displacements up to 40 % of h, and a squashed block with corners below J_b and some
    inverted. Measured: at most 2.2e-7 of the largest force."""
    grid = block((4, 5, 6), holes)
    cells = cells_of(grid, nu)
    assert (cells.count < 3 * 4 * 5) == bool(holes)  # holes: some cells are not full
    rng = np.random.default_rng(7)
    layouts = ("compact", "indexed") if not holes else ("compact",)
    for x in (grid.rest_positions + rng.uniform(-0.4, 0.4, (grid.count, 3)) * H, squashed(grid, rng)):
        x32 = x.astype(np.float32).astype(np.float64)
        det, _ = corner_jacobians(cells, x32)
        assert np.sum(det < cells.barrier_j) > 50 and np.sum(det <= 0) > 3  # the barrier acts, some inverted
        ref = volume_forces(cells, x32)
        for layout in layouts:
            with NodeCellForces(ctx, cells, grid, layout=layout) as gpu:
                assert gpu.layout.dense == (layout == "compact" and not holes)
                f = gpu.forces(x32).astype(np.float64)
            assert np.abs(f - ref).max() <= 2e-6 * np.abs(ref).max()
    # a node in no full cell gets no force; every other node of a holed grid some
    if holes:
        with NodeCellForces(ctx, cells, grid) as gpu:
            f = gpu.forces(squashed(grid, rng))
        in_cells = np.zeros(grid.count, bool)
        in_cells[cells.corners.reshape(-1)] = True
        assert np.all(f[~in_cells] == 0.0) and np.all(np.abs(f[in_cells]).max(axis=1) > 0)


def lattice(holes, nu=0.45):
    grid = block(holes=holes)
    system, _ = lattice_system(grid, material(nu), fixed=grid.ijk[:, 1] == grid.shape[1] - 1)
    return system, grid


def run_both(ctx, system, grid, name, dt, steps, x0, **kwargs):
    state = initial_state(system, dt, x=x0)
    sim = FragmentIntegrator(ctx, system, grid, name, dt, state=state, **kwargs)
    try:
        fast = sim.fast is not None
        sim.step(steps)
        x = sim.positions().astype(np.float64)
    finally:
        sim.release()
    ref = NumpySimulation(system, name, dt, state=state)
    ref.step(steps)
    return x, ref.state.x, fast


@pytest.mark.parametrize("holes", [(), HOLES], ids=["dense", "holes"])
@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_every_integrator_matches_numpy_at_nu_045(ctx, name, holes):
    """A hanging lattice at nu = 0.45 under gravity from a perturbed start, 100 steps at 0.3 of
    the stability limit: within the 1e-3 h of the springs' GPU-vs-NumPy tests
    (tests/test_fragment_integrators.py; measured 1e-5 h, Verlet 2e-4 h), and the volumetric term
    matters (the springs alone end 0.1 h away)."""
    system, grid = lattice(holes)
    assert system.cells is not None and system.cells.volume_modulus > 0
    dt = 0.3 / max_angular_frequency(system).omega
    x0 = grid.rest_positions + np.random.default_rng(1).uniform(-0.1, 0.1, (grid.count, 3)) * H
    x0[system.fixed] = grid.rest_positions[system.fixed]
    x, ref, fast = run_both(ctx, system, grid, name, dt, 100, x0)
    assert fast == (name == "verlet")  # Verlet keeps the foundation's fast path with cells
    assert np.abs(ref - x0).max() > 0.1 * H  # it moved
    err = np.abs(x - ref).max()
    assert err <= 1e-3 * H
    springs = NumpySimulation(dataclasses.replace(system, cells=None), name, dt,
                              state=initial_state(system, dt, x=x0))
    springs.step(100)
    assert np.abs(springs.state.x - ref).max() > 100 * err


@pytest.mark.parametrize("holes", [(), HOLES], ids=["dense", "holes"])
@pytest.mark.parametrize("name", ["verlet", "semi-implicit", "rk4"])
def test_corners_inside_the_barrier(ctx, name, holes):
    """From a squashed start (the corner Jacobians of all but the pinned top layer's cells below
    J_b, some inverted) at nu = 0.25 (the barrier alone) and 0.45: the barrier pushes the block
    back up as in the reference."""
    for nu in (0.25, 0.45):
        system, grid = lattice(holes, nu)
        x0 = squashed(grid, np.random.default_rng(3))
        x0[system.fixed] = grid.rest_positions[system.fixed]
        det, _ = corner_jacobians(system.cells, x0)
        below = np.mean(det < system.cells.barrier_j)
        assert below > 0.5 and np.sum(det <= 0) > 10
        dt = 0.2 / max_angular_frequency(system).omega
        x, ref, _ = run_both(ctx, system, grid, name, dt, 30, x0)
        assert np.abs(x - ref).max() <= 1e-3 * H  # measured 1e-5 h, Verlet 2e-4 h
        after, _ = corner_jacobians(system.cells, ref)
        assert np.mean(after < system.cells.barrier_j) < below - 0.2  # it really un-squashed


@pytest.mark.parametrize("variant", [dict(layout="indexed"), dict(weight_texture=True)],
                         ids=lambda v: "+".join(f"{k}={x}" for k, x in v.items()))
def test_foundation_pass_variants_carry_the_cells(ctx, variant):
    """The Verlet fast path's other data paths (the neighbour table instead of strides, the weight
    texture instead of the levels code) run the volumetric term as the default pass does: 50 steps
    from a squashed start agree bit for bit."""
    system, grid = lattice((), 0.45)
    assert system.grid is grid
    x0 = squashed(grid, np.random.default_rng(5))
    x0[system.fixed] = grid.rest_positions[system.fixed]
    state = initial_state(system, 1e-4, x=x0)
    out = []
    for kwargs in ({}, variant):
        sim = FoundationVerlet.for_system(ctx, system, 1e-4, state=state, **kwargs)
        try:
            assert sim.textures.hood_diagonals is None or kwargs.get("layout") == "indexed"
            sim.step(50)
            out.append(sim.positions())
        finally:
            sim.release()
    assert np.abs(out[0] - x0).max() > 0.1 * H
    np.testing.assert_array_equal(out[1], out[0])


def test_generated_source_and_tables_follow_the_terms(ctx):
    """nu = 1/4 compiles the barrier alone and fetches nothing besides the springs; nu = 0.45 adds
    the centre term and, off dense grids, the body-diagonal table; springs alone compile no cell
    code."""
    for holes in ((), HOLES):
        for nu in (0.25, 0.45):
            system, grid = lattice(holes, nu)
            for name in ("verlet", "semi-implicit"):
                sim = FragmentIntegrator(ctx, system, grid, name, 1e-4)
                try:
                    program = sim.fast.verlet.program if sim.fast else sim.passes["step"]
                    text = program.fragment_source.text.split("#line")[0]  # the injected defines
                    assert "#define TERM_CELL" in text and "#define CELL_BARRIER" in text
                    assert ("#define CELL_CENTRE" in text) == (nu > 0.25)
                    members = set(program.members)
                    assert ("u_cell_kappa" in members) == (nu > 0.25)
                    assert ("u_hood_diagonals" in members) == (nu > 0.25 and bool(holes))
                finally:
                    sim.release()
            plain = FragmentIntegrator(ctx, dataclasses.replace(system, cells=None), grid, "verlet", 1e-4)
            try:
                assert "#define CELL" not in plain.fast.verlet.program.fragment_source.text.split("#line")[0]
                assert not {m for m in plain.fast.verlet.program.members if m.startswith("u_cell")}
            finally:
                plain.release()


def test_refusals(ctx):
    system, grid = lattice(())
    shifted = CellVolumes(system.cells.corners[:, [1, 0, 2, 3, 4, 5, 6, 7]], H, 1.0, 1.0)
    with pytest.raises(ValueError, match="is not a unit cell of the system's node grid"):
        check_cells(grid, shifted)
    with pytest.raises(ValueError, match="is not a unit cell of the system's node grid"):
        FragmentIntegrator(ctx, dataclasses.replace(system, cells=shifted), grid, "euler", 1e-4)
    twice = CellVolumes(np.concatenate([system.cells.corners[:1], system.cells.corners]), H, 1.0, 1.0)
    with pytest.raises(ValueError, match="listed more than once"):
        check_cells(grid, twice)
