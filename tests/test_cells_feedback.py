"""The volumetric term of the lattice (any Poisson's ratio, inversion barrier; deformgl/sim/terms/volume/energy.py)
on the transform-feedback backend against the float64 reference, and the cell table it reads."""

from __future__ import annotations

import dataclasses
from typing import cast

import moderngl
import numpy as np
import pytest

from deformgl.grid.nodes import NodeGrid
from deformgl.sim import integrators as I
from deformgl.grid.neighbours import neighbourhood
from deformgl.sim.terms.volume.tables import incident_cells
from deformgl.sim.backends.feedback import FeedbackSimulation
from deformgl.sim.terms.volume.chunks import CELL_SLOTS, volume_feedback
from deformgl.sim.integrators import EXPLICIT_INTEGRATORS
from deformgl.sim.materials import ElasticMaterial, lattice_system
from deformgl.sim.terms.volume.energy import BARRIER_J, CellVolumes, corner_jacobians, volume_forces

EPS32 = 2.0 ** -23


def squashed(nu: float = 0.45):
    """A 4 x 3 x 3 lattice (h = 0.1 m, gel-like E = 10 kPa, 1000 kg/m^3, Poisson's ratio nu)
    clamped at x = 0 under gravity, its far layer pushed 0.8 h towards the clamp and every free
    node jittered by 0.1 h: corners inside the barrier, a few inverted. Returns (system, x)."""
    grid = NodeGrid(np.array([0.2, 0.5, -0.1]), 0.1, np.ones((4, 3, 3), bool))
    material = ElasticMaterial(1e4, 1000.0, poissons_ratio=nu)
    system, _ = lattice_system(grid, material, fixed=grid.ijk[:, 0] == 0)
    x = grid.rest_positions.copy()
    x[grid.ijk[:, 0] == 3, 0] -= 0.8 * grid.spacing
    jitter = np.random.default_rng(0).normal(scale=0.1 * grid.spacing, size=x.shape)
    x += np.where(system.fixed[:, None], 0.0, jitter)
    return system, x


def run(ctx, system, name, dt, steps, state):
    sim = FeedbackSimulation(ctx, system, name, dt, state=state)
    try:
        sim.step(steps)
        return sim.positions().astype(np.float64), sim.velocities().astype(np.float64)
    finally:
        sim.release()


def reference(system, name, dt, steps, state):
    s = state
    for k in range(steps):
        s = I.step(system, name, s, dt, k * dt)
    return s


def refused(system) -> None:
    """Build a simulation of ``system`` with no GL context: only the checks before any GL run."""
    FeedbackSimulation(cast(moderngl.Context, None), system, "rk4", 1e-3)


def test_the_test_body_is_inside_the_barrier():
    system, x = squashed()
    assert system.cells is not None and system.cells.count == 12 and system.cells.volume_modulus > 0
    det, _ = corner_jacobians(system.cells, x)
    assert (det < BARRIER_J).sum() >= 20 and det.min() < 0


# -- the table ----------------------------------------------------------------------------------

def test_the_cell_table_holds_the_neighbourhood_and_the_mask():
    system, _ = squashed()
    n, row = system.count, 16
    rows = -(-n // row)
    form = volume_feedback(system.cells, system.grid)
    assert form.slots == CELL_SLOTS
    img = form.image(row, rows).reshape(rows * row, 4 * CELL_SLOTS)
    assert img.dtype == np.int32 and img.shape == (rows * row, 28)
    assert np.array_equal(img[:n, :27], neighbourhood(system.grid))
    assert np.array_equal(img[:n, 27], incident_cells(system.grid, system.cells))
    assert not img[n:].any()  # padding nodes: no cells
    # the node at grid (1, 1, 1) is a corner of all 8 cells around it; a corner node of 1
    centre = int(system.grid.index[1, 1, 1])
    assert img[centre, 27] == 255 and bin(int(img[0, 27])).count("1") == 1
    assert form.row_limit(16384) == 2048 and form.row_limit(7 * 1024) == 1024


def test_cells_without_a_grid_are_refused_in_one_line():
    system, _ = squashed()
    with pytest.raises(ValueError, match="has cells .* but no node grid") as err:
        refused(dataclasses.replace(system, grid=None))
    assert "\n" not in str(err.value)


def test_cells_that_are_not_the_grids_are_refused():
    system, _ = squashed()
    cells = system.cells
    assert cells is not None
    swapped = cells.corners.copy()
    swapped[3, [1, 2]] = swapped[3, [2, 1]]
    with pytest.raises(ValueError, match="cell 3 .* is not a unit cell of the system's node grid"):
        refused(dataclasses.replace(system, cells=dataclasses.replace(cells, corners=swapped)))
    twice = np.concatenate([cells.corners, cells.corners[:1]])
    with pytest.raises(ValueError, match="more than once"):
        refused(dataclasses.replace(system, cells=dataclasses.replace(cells, corners=twice)))


# -- on the GPU ---------------------------------------------------------------------------------

@pytest.mark.parametrize("nu", [0.25, 0.45])
def test_the_cell_forces_match_volume_forces(ctx, nu):
    """One explicit Euler step from rest: (v' - v_springs')/dt is the cells' acceleration, compared
    with deformgl.sim.terms.volume.energy.volume_forces / m (measured max relative error 3e-7)."""
    system, x = squashed(nu)
    dt = 1e-3
    state = I.initial_state(system, dt, x=x)
    _, v = run(ctx, system, "euler", dt, 1, state)
    _, v_springs = run(ctx, dataclasses.replace(system, cells=None), "euler", dt, 1, state)
    expected = np.where(system.fixed[:, None], 0.0, volume_forces(system.cells, x) / system.mass[:, None])
    got = (v - v_springs) / dt
    assert np.abs(got - expected).max() <= 1e-5 * np.abs(expected).max()
    # both terms act: at nu = 1/4 the barrier alone, which is not small here
    assert np.abs(expected).max() > 0.1 * np.abs(v_springs / dt).max()


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_one_step_matches_the_reference(ctx, name):
    """The bounds of tests/test_feedback_sim.py's one-step test, on a squashed lattice at nu = 0.45
    (measured: x 4e-8 to 1.4e-7, v 3e-7 of the largest; Verlet's v within a few float32 roundings
    of the positions over dt)."""
    system, x = squashed()
    dt = 1e-3
    state = I.initial_state(system, dt, x=x)
    xg, vg = run(ctx, system, name, dt, 1, state)
    ref = I.step(system, name, state, dt, 0.0)
    springs_only = I.step(dataclasses.replace(system, cells=None), name, state, dt, 0.0)
    scale = np.abs(ref.x).max()
    assert np.abs(xg - ref.x).max() <= 1e-5 * scale
    if name == "verlet":
        assert np.abs(vg - ref.v).max() <= 4 * EPS32 * scale / dt
    else:
        assert np.abs(vg - ref.v).max() <= 1e-5 * np.abs(ref.v).max()
    # the cells change the step by far more than the error
    err_v = np.abs(vg - ref.v).max()
    assert np.abs(ref.v - springs_only.v).max() > 100 * err_v
    if name != "euler":  # (explicit Euler's x' does not see this step's forces)
        assert np.abs(ref.x - springs_only.x).max() > 100 * np.abs(xg - ref.x).max()


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_fifty_steps_match_the_reference(ctx, name):
    """The bound of tests/test_feedback_sim.py's hundred-step test, 1e-3 h, after 50 steps of
    1 ms from the squashed state at nu = 0.45 (measured: 2e-6 h to 5e-6 h, Verlet 5e-5 h)."""
    system, x = squashed()
    dt = 1e-3
    state = I.initial_state(system, dt, x=x)
    xg, _ = run(ctx, system, name, dt, 50, state)
    ref = reference(system, name, dt, 50, state)
    springs_only = reference(dataclasses.replace(system, cells=None), name, dt, 50, state)
    h = system.spacing
    assert np.abs(ref.x - springs_only.x).max() > 0.5 * h  # the cells matter
    assert np.abs(xg - ref.x).max() <= 1e-3 * h


def test_systems_without_cells_compile_no_cell_code(ctx):
    system, _ = squashed()
    empty = CellVolumes(np.zeros((0, 8), np.int64), system.spacing, 1.0, 1.0)
    for variant, cells in ((dataclasses.replace(system, cells=None), False),
                           (dataclasses.replace(system, cells=empty), False), (system, True)):
        sim = FeedbackSimulation(ctx, variant, "semi-implicit", 1e-3)
        try:
            assert bool(sim.feedback_terms) is cells and bool(sim.term_textures) is cells
            assert all(("TERM_CELL" in p.program.defines) is cells for p in sim._passes.values())
            assert all(("u_cell_nodes" in p.program.gl) is cells for p in sim._passes.values())  # (compiled)
        finally:
            sim.release()
