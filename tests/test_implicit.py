"""Implicit (backward) Euler: the float64 reference against a direct solve and FEM statics, the
GPU backend against the reference, stability far above the explicit limit, constraints, loads,
drags, and the report of an unconverged solve (issue 15)."""

from __future__ import annotations

import numpy as np
import pytest

from deformgl.bench.fem import MATERIAL, WORKLOADS, lattice_case, lattice_value
from deformgl.sim.implicit import implicit_step
from deformgl.sim.integrators import Constraints, initial_state
from deformgl.sim.limits import check_dt, dt_limit
from deformgl.sim.materials import ElasticMaterial, critical_dt
from deformgl.sim.simulation import SimulationSetupError, make_simulation
from deformgl.sim.scripted import Drag, Load

TISSUE = ElasticMaterial(3.0e3, 1060.0, mass_damping=1.0, stiffness_damping=1e-3)


def _case(material=TISSUE, across=3):
    return lattice_case(WORKLOADS["cantilever"], across, material)


def test_cg_converges_to_the_direct_solve():
    s = _case(MATERIAL).system
    st = initial_state(s, 1e-3)
    direct, dv_d, _ = implicit_step(s, st, 1e-3, 0.0, solver="direct")
    cg, dv_c, report = implicit_step(s, st, 1e-3, 0.0, iterations=300, tolerance=1e-12, check_every=1)
    assert report.within_tolerance and report.residual <= 1e-12 and 0 < report.iterations < 300
    assert np.abs(dv_c - dv_d).max() <= 1e-9 * np.abs(dv_d).max()
    assert np.abs(cg.x - direct.x).max() <= 1e-12


def test_block_jacobi_is_the_inverse_of_the_node_blocks():
    from deformgl.sim.implicit import assemble, pcg, preconditioner

    case = _case(MATERIAL)
    s = case.system
    st = initial_state(s, 1 / 60)
    st.x[:] = s.rest_positions + 0.2 * case.spacing * np.random.default_rng(3).normal(size=st.x.shape)
    lin = assemble(s, st.x, st.v, 0.0, 1 / 60)
    p = preconditioner(lin.matrix, "block-jacobi").toarray()
    a = lin.matrix.toarray()
    for node in (0, 7, lin.matrix.shape[0] // 3 - 1):
        sl = slice(3 * node, 3 * node + 3)
        assert np.abs(a[sl, sl] - a[sl, sl].T).max() <= 1e-12 * np.abs(a[sl, sl]).max()
        assert np.abs(a[sl, sl][0, 1]) > 1e-3 * a[sl, sl][0, 0]            # the blocks do couple x y z
        assert np.allclose(p[sl, sl] @ a[sl, sl], np.eye(3), atol=1e-12)
        assert np.count_nonzero(p[sl, :]) <= 9
    jacobi = preconditioner(lin.matrix, "jacobi").diagonal()
    assert np.allclose(jacobi, 1 / a.diagonal())
    x, report = pcg(lin.matrix, lin.rhs, np.zeros_like(lin.rhs), iterations=500, tolerance=1e-11, check_every=1,
                    preconditioner_kind="block-jacobi")
    assert report.within_tolerance and np.abs(lin.matrix @ x - lin.rhs).max() <= 1e-8 * np.abs(lin.rhs).max()
    with pytest.raises(SimulationSetupError, match="cg_preconditioner"):
        make_simulation(s, "implicit-euler", "numpy", dt=0.01, cg_preconditioner="ilu")


@pytest.mark.parametrize("preconditioner", ["jacobi", "block-jacobi", "multigrid"])
def test_gpu_matches_numpy_at_fixed_iterations(ctx, preconditioner):
    """One step and the warm-started next ones at a fixed iteration count, each preconditioner,
    on a deformed body (the blocks' off-diagonals matter)."""
    case = _case()
    s = case.system
    x0 = s.rest_positions + 0.15 * case.spacing * np.random.default_rng(5).normal(size=(s.count, 3))
    x0[s.fixed] = s.rest_positions[s.fixed]
    from deformgl.sim.integrators import State

    opts = dict(dt=1 / 60, state=State(x0, np.zeros_like(x0), x0), cg_iterations=6, cg_preconditioner=preconditioner)
    ref = make_simulation(s, "implicit-euler", "numpy", **opts)
    with make_simulation(s, "implicit-euler", "fragment", ctx=ctx, **opts) as gpu:
        for _ in range(3):
            ref.step()
            gpu.step()
            assert np.abs(gpu.velocity_change() - ref.dv).max() <= 1e-5 * np.abs(ref.dv).max()
            assert gpu.residual() == pytest.approx(ref.last_report.residual, rel=1e-3)
    swapped = "jacobi" if preconditioner == "block-jacobi" else "block-jacobi"
    other = make_simulation(s, "implicit-euler", "numpy", **{**opts, "cg_preconditioner": swapped})
    other.step()
    first = make_simulation(s, "implicit-euler", "numpy", **opts)
    first.step()
    assert np.abs(other.dv - first.dv).max() > 1e-4 * np.abs(first.dv).max()   # a different iteration


def test_scaled_warm_start_keeps_truncated_cg_on_the_equilibrium():
    """Truncated CG (5 iterations at dt = 1/60 s) on the 1 MPa block, 9 across, settling from rest:
    starting each solve from the last dv as it is drifts many sags away; its best multiple
    (the default) and a zero start stay on the equilibrium (bench trade --stiff's finding)."""
    import math

    from deformgl.bench.trade_stiff import stiff_cases
    from deformgl.sim.implicit import warm_start

    case = stiff_cases(cases=((1.0e6, 9),))[0]
    error = {}
    for warm in ("previous", "scaled", "zero"):
        sim = make_simulation(case.system, "implicit-euler", "numpy", dt=1 / 60, cg_iterations=5, cg_warm_start=warm)
        sim.step(18)
        error[warm] = np.max(np.linalg.norm(sim.positions() - case.static, axis=1)) / case.spacing / case.sag
    assert error["previous"] > 1.0 and error["scaled"] < 1e-3 and error["zero"] < 0.05
    # the scaled start is the A-norm-best multiple: never worse than zero or the previous dv
    rng = np.random.default_rng(2)
    a = sp_random_spd(rng, 30)
    b, prev = rng.normal(size=30), rng.normal(size=30)
    x = np.linalg.solve(a.toarray(), b)

    def energy(x0):
        return float((x0 - x) @ (a @ (x0 - x)))

    s0 = warm_start(a, b, prev)
    assert energy(s0) <= min(energy(prev), energy(0 * prev)) + 1e-12
    assert not math.isclose(energy(s0), energy(prev))


def sp_random_spd(rng, n):
    import scipy.sparse as sp

    m = rng.normal(size=(n, n))
    return sp.csr_matrix(m @ m.T + n * np.eye(n))


@pytest.mark.parametrize("warm", ["previous", "zero"])
def test_gpu_matches_numpy_with_each_warm_start(ctx, warm):
    case = _case()
    s = case.system
    opts = dict(dt=1 / 60, cg_iterations=4, cg_warm_start=warm)
    ref = make_simulation(s, "implicit-euler", "numpy", **opts)
    with make_simulation(s, "implicit-euler", "fragment", ctx=ctx, **opts) as gpu:
        for _ in range(3):
            ref.step()
            gpu.step()
            assert np.abs(gpu.velocity_change() - ref.dv).max() <= 1e-5 * np.abs(ref.dv).max()
    with pytest.raises(SimulationSetupError, match="cg_warm_start"):
        make_simulation(s, "implicit-euler", "numpy", dt=0.01, cg_warm_start="last")


def test_gpu_matches_numpy_one_step(ctx):
    case = _case()
    s = case.system
    loads = (Load(case.grid.rest_positions[:, 0] > 0.9, lambda t: (0.0, 0.01, 0.0)),)
    drags = (Drag(100, lambda t: (0.5, 0.08, 0.05), 0.5),)
    opts = dict(dt=1 / 60, loads=loads, drags=drags, constraints=Constraints(ground=-0.02), cg_iterations=5)
    ref = make_simulation(s, "implicit-euler", "numpy", **opts)
    with make_simulation(s, "implicit-euler", "fragment", ctx=ctx, **opts) as gpu:
        for _ in range(2):   # the second step runs from the warm start on both sides
            ref.step()
            gpu.step()
            dv = gpu.velocity_change()
            assert np.abs(dv - ref.dv).max() <= 1e-5 * np.abs(ref.dv).max()
            assert np.abs(gpu.positions() - ref.positions()).max() <= 1e-5 * case.spacing
            assert gpu.residual() == pytest.approx(ref.last_report.residual, rel=1e-3)  # 2 scalar reads
        assert np.array_equal(gpu.positions()[s.fixed], s.rest_positions[s.fixed].astype(np.float32))
        assert np.all(gpu.velocities()[s.fixed] == 0.0)


def test_stable_far_above_the_explicit_limit_and_settles():
    case = _case(MATERIAL)
    s = case.system
    dt = 100 * critical_dt(MATERIAL, case.spacing, barrier=False)
    assert dt_limit(s, "verlet", exact=False).dt < dt / 50 and check_dt(s, "implicit-euler", dt) is None
    sim = make_simulation(s, "implicit-euler", "numpy", dt=dt, solver="direct")
    sim.step(300)
    x = sim.positions()
    assert np.all(np.isfinite(x))
    assert np.abs(sim.velocities()).max() < 1e-3 * case.spacing / dt


def test_static_limit_is_the_lattice_static_solve():
    case = _case(MATERIAL)
    s = case.system
    static = lattice_value(case)
    sim = make_simulation(s, "implicit-euler", "numpy", dt=1 / 60, cg_iterations=200)
    sim.step(60)
    sag = lattice_value(case, sim.positions() - s.rest_positions)
    assert sag == pytest.approx(static, rel=2e-3)   # the FEM tolerance of docs/ACCURACY.md is 2 %


def test_truncated_cg_needs_the_scaled_warm_start_not_the_geometric_term():
    """The stiff cantilever at dt = 1/60 s: started from the last dv as it is, 50 CG iterations a
    step drift far from the statics (the sign flips) even with the projected geometric term; from
    the scaled start every variant of the term (projected, full, dropped) reaches the lattice's
    static solve at 100 iterations, as the direct solve does."""
    case = _case(MATERIAL)
    s, static = case.system, lattice_value(case)

    def sag(**options):
        sim = make_simulation(s, "implicit-euler", "numpy", dt=1 / 60, **options)
        sim.step(60)
        return lattice_value(case, sim.positions() - s.rest_positions) / static

    assert sag(cg_iterations=50, cg_warm_start="previous") < 0.0
    for geometric in ("projected", "full", "none"):
        assert sag(cg_iterations=100, geometric=geometric) == pytest.approx(1.0, abs=1e-3)
    assert sag(solver="direct") == pytest.approx(1.0, rel=2e-3)


def test_ground_load_and_drag(ctx):
    case = _case()
    s = case.system
    tip = case.grid.rest_positions[:, 0] > 0.9
    drag = Drag(int(np.flatnonzero(tip)[0]), lambda t: (1.0, 0.3, 0.05), 50.0)
    up = (Load(tip, lambda t: (0.0, 0.5, 0.0)),)
    with make_simulation(s, "implicit-euler", "fragment", ctx=ctx, dt=1 / 60, cg_iterations=30,
                         constraints=Constraints(ground=-0.01)) as fall:
        fall.step(60)
        assert fall.positions()[:, 1].min() >= -0.01 - 1e-6
    free = make_simulation(s, "implicit-euler", "numpy", dt=1 / 60, solver="direct")
    free.step(30)
    lifted = make_simulation(s, "implicit-euler", "numpy", dt=1 / 60, loads=up, solver="direct")
    lifted.step(30)
    assert lifted.positions()[tip, 1].mean() > free.positions()[tip, 1].mean() + 0.05
    dragged = make_simulation(s, "implicit-euler", "numpy", dt=1 / 60, drags=(drag,), solver="direct")
    dragged.step(30)
    assert dragged.positions()[drag.node, 1] > free.positions()[drag.node, 1] + 0.05


def test_unconverged_solve_is_reported(ctx):
    s = _case(MATERIAL).system
    with make_simulation(s, "implicit-euler", "fragment", ctx=ctx, dt=1 / 60, cg_iterations=3,
                         cg_tolerance=1e-6, cg_check_every=1) as gpu:
        gpu.step(2)
        assert gpu.unconverged == 2 and gpu.last_report.residual > 1e-6
        assert "did not reach the tolerance" in gpu.solver_note()
    ref = make_simulation(s, "implicit-euler", "numpy", dt=1 / 60, cg_iterations=300, cg_tolerance=1e-6)
    ref.step(2)
    assert ref.solver_note() is None and ref.last_report.within_tolerance


def test_setup_errors():
    s = _case().system
    with pytest.raises(SimulationSetupError, match="not on feedback"):
        make_simulation(s, "implicit-euler", "feedback", dt=0.01, ctx=object())
    with pytest.raises(SimulationSetupError, match="cg_iterations"):
        make_simulation(s, "implicit-euler", "numpy", dt=0.01, cg_iterations=0)
    with pytest.raises(SimulationSetupError, match="unknown option"):
        make_simulation(s, "implicit-euler", "numpy", dt=0.01, path="general")


def test_scene_keys(tmp_path):
    from deformgl.errors import DeformglError
    from deformgl.scene.schema import load_scene

    from pathlib import Path

    mesh = Path(__file__).resolve().parents[1] / "scenes" / "assets" / "jelly_block.obj"
    base = tmp_path / "s.toml"
    head = f'[mesh]\npath = "{mesh.as_posix()}"\n'
    base.write_text(head + '[physics]\nintegrator = "implicit-euler"\n[physics.implicit]\niterations = 7\ntolerance = 1e-4\n')
    scene = load_scene(base)
    assert scene.physics.integrator == "implicit-euler"
    assert scene.physics.implicit.options() == {"cg_iterations": 7, "cg_tolerance": 1e-4,
                                                "cg_preconditioner": "jacobi"}
    base.write_text(head + '[physics.implicit]\npreconditioner = "block-jacobi"\n')
    assert load_scene(base).physics.implicit.options()["cg_preconditioner"] == "block-jacobi"
    base.write_text(head + '[physics.implicit]\niterations = 0\n')
    with pytest.raises(DeformglError, match="physics.implicit.iterations"):
        load_scene(base)
    base.write_text(head + '[physics.implicit]\npreconditioner = "ilu"\n')
    with pytest.raises(DeformglError, match=r"s\.toml: physics\.implicit\.preconditioner: .*block-jacobi") as err:
        load_scene(base)
    assert "\n" not in str(err.value)


@pytest.fixture(scope="module")
def stiff_rows(ctx):
    """The quick stiff study of the 1 MPa block at 5 across (cases, rows)."""
    from deformgl.bench.trade_stiff import stiff_cases, stiff_study

    cases = stiff_cases(quick=True, cases=((1.0e6, 5),))
    return cases, stiff_study(ctx, quick=True, cases=cases)


def test_stiff_study_quick(stiff_rows):
    from deformgl.bench.trade_stiff import QUICK_ITERATIONS, QUICK_MULTIGRID, QUICK_XPBD, format_stiff

    cases, rows = stiff_rows
    assert cases and cases[0].omega1 > 100.0 and cases[0].linear_gap < 1e-3
    implicit = [r for r in rows if r.integrator == "implicit-euler"]
    xpbd = [r for r in rows if r.integrator == "xpbd"]
    explicit = [r for r in rows if r.integrator in ("verlet", "semi-implicit")]
    assert [r.preconditioner for r in implicit] == ["jacobi"] * len(QUICK_ITERATIONS) + ["multigrid"] * len(QUICK_MULTIGRID)
    assert len(xpbd) == len(QUICK_XPBD) and len(explicit) == 2
    assert all(r.preconditioner == "" for r in xpbd + explicit)
    assert all(r.converged_at is not None for r in rows)
    assert all(r.final_error <= 0.05 for r in rows)
    # the body at rest is within 0.05 h (the sag is 0.002 h): the relative criterion asks for the sag
    assert cases[0].sag < 0.05 and all(r.converged_rel_at is not None and r.relative_error <= 0.05 for r in implicit)
    assert all(0.0 <= r.mode_decay < 1e-6 for r in implicit) and all(r.mode_decay == 1.0 for r in explicit)
    assert all(np.isnan(r.mode_decay) for r in xpbd) and all(r.substeps == QUICK_XPBD[0][1] for r in xpbd)
    assert all(r.dt > 10 * max(e.dt for e in explicit) for r in implicit)
    text = format_stiff(rows, cases=cases)
    assert "in favour of" in text and "(0.05 of sag)" in text
    assert "cheapest converged implicit-euler (multigrid)" in text and "cheapest converged implicit-euler (jacobi)" in text


@pytest.mark.fem
def test_stiff_fem_error(stiff_rows):
    cases, rows = stiff_rows
    # linear FEM of the cube: about 5e-5 m at 1 MPa; the 5-across lattice is within a few % of it
    assert 4e-5 < cases[0].fem < 6e-5
    assert all(r.fem_error < 0.1 for r in rows if r.integrator == "implicit-euler")


@pytest.mark.plot
def test_stiff_csv_json_and_chart(stiff_rows, tmp_path):
    import csv
    import json

    from deformgl.bench import stiff_files

    cases, rows = stiff_rows
    stiff_files.write_csv(tmp_path / "stiff.csv", rows)
    with open(tmp_path / "stiff.csv", newline="") as f:
        table = list(csv.DictReader(f))
    assert tuple(table[0]) == stiff_files.FIELDS and len(table) == len(rows)
    assert {"wall_per_sim_s", "fem_error", "final_error", "converged_rel_at", "substeps"} <= set(table[0])
    assert [t["integrator"] for t in table] == [r.integrator for r in rows]
    assert [t["preconditioner"] for t in table] == [r.preconditioner for r in rows]
    assert float(table[-1]["wall_per_sim_s"]) == rows[-1].wall_per_sim_s
    stiff_files.write_json(tmp_path / "stiff.json", rows, cases, "machine")
    data = json.loads((tmp_path / "stiff.json").read_text())
    assert len(data["rows"]) == len(rows) and data["cases"][0]["nodes"] == 125
    stiff_files.write_chart(tmp_path / "stiff.png", rows, "machine")
    from PIL import Image

    with Image.open(tmp_path / "stiff.png") as im:
        assert im.size[0] > 500 and im.size[1] > 800   # one material: one column of two charts
    assert sorted(p.name for p in tmp_path.iterdir()) == ["stiff.csv", "stiff.json", "stiff.png"]


def test_realtime_frames(ctx):
    from studies.realtime import format_realtime, realtime

    rows, gap, nodes = realtime(ctx, "jelly.toml", frames=2, iterations=(20,))
    assert [r.integrator for r in rows] == ["implicit-euler", "verlet"] and nodes > 100
    assert rows[0].steps_per_frame == 1 and rows[1].steps_per_frame > 1
    assert all(r.fps > 0 for r in rows) and 0.0 <= rows[0].residual < 0.1
    assert np.isfinite(gap) and "fps" in format_realtime(rows, gap, nodes, "jelly.toml")


def test_guarded_run_notes_the_solver_and_the_census_catches_nan(ctx):
    from deformgl.errors import SimulationError
    from deformgl.sim.restartable import GuardedSimulation as guarded
    from deformgl.sim.run import run
    from deformgl.sim.integrators import State

    s = _case(MATERIAL).system
    sim = guarded(s, "implicit-euler", "fragment", dt=1 / 60, ctx=ctx, cg_iterations=3, cg_tolerance=1e-6,
                  cg_check_every=1)
    result = run(sim, 4)   # 200x the explicit limit: accepted, and the unconverged solves noted
    assert any("did not reach the tolerance 1e-06 in 4 of 4 steps" in n for n in result.notes)
    start = initial_state(s, 1 / 60)
    x = start.x.copy()
    x[50] = np.nan
    bad = guarded(s, "implicit-euler", "fragment", dt=1 / 60, ctx=ctx, state=State(x, start.v, start.x_prev))
    with pytest.raises(SimulationError, match="non-finite"):
        run(bad, 3)


def test_moving_sphere_gpu_matches_numpy(ctx):
    from deformgl.sim.integrators import Sphere

    case = _case()
    s = case.system
    sphere = Sphere(lambda t: (0.62, -0.02 + 0.5 * t, 0.035), 0.06)  # no node at its apex (a tie)
    opts = dict(dt=1 / 60, constraints=Constraints(spheres=(sphere,)), cg_iterations=5)
    ref = make_simulation(s, "implicit-euler", "numpy", **opts)
    with make_simulation(s, "implicit-euler", "fragment", ctx=ctx, **opts) as gpu:
        ref.step(3)
        gpu.step(3)
        x = gpu.positions().astype(np.float64)
        centre = np.array([0.62, -0.02 + 0.5 * 3 / 60, 0.035])
        assert np.linalg.norm(x - centre, axis=1).min() >= 0.06 - 1e-5
        hit = np.linalg.norm(ref.positions() - centre, axis=1) <= 0.06 + 1e-9
        assert hit.any()
        assert np.abs(x - ref.positions()).max() <= 1e-4 * case.spacing


def test_cli_integrator_and_unconverged_note(ctx, tmp_path, capsys):  # ctx: marks it gl (the CLI makes its own)
    from deformgl.cli import main
    from deformgl.data import scene_file

    out = tmp_path / "j.png"
    code = main(["render", str(scene_file("jelly.toml")), "-o", str(out), "--integrator", "implicit-euler",
                 "--set", "physics.dt=0.0166667", "--set", "physics.steps=4",
                 "--set", "physics.implicit.iterations=2", "--set", "physics.implicit.tolerance=1e-6"])
    err = capsys.readouterr().err
    assert code == 0 and out.exists()
    assert "implicit-euler on fragment, 4 steps of dt 0.0166667 s" in err
    assert "CG did not reach the tolerance 1e-06 in 4 of 4 steps" in err


def test_lowest_mode_decays_as_backward_euler_predicts():
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    from deformgl.bench.fem import stiffness_matrix
    from deformgl.grid.nodes import NodeGrid
    from deformgl.sim.integrators import State
    from deformgl.sim.materials import lattice_system

    grid = NodeGrid(np.zeros(3), 0.025, np.ones((5, 5, 5), bool))
    system, _ = lattice_system(grid, ElasticMaterial(3.0e3, 1060.0), fixed=grid.ijk[:, 1] == 0, gravity=(0, 0, 0))
    dof = np.repeat(~system.fixed, 3)
    m = np.repeat(system.mass, 3)[dof]
    w2, vec = spla.eigsh(stiffness_matrix(system)[dof][:, dof].tocsc(), k=1, M=sp.diags(m).tocsc(), sigma=0.0)
    w, phi = float(np.sqrt(w2[0])), np.zeros(3 * system.count)
    phi[dof] = vec[:, 0] / np.abs(vec[:, 0]).max() * 1e-6          # 1 um: linear
    dt = 1 / 60
    x0 = system.rest_positions + phi.reshape(-1, 3)
    sim = make_simulation(system, "implicit-euler", "numpy", dt=dt, solver="direct",
                          state=State(x0, np.zeros_like(x0), x0))
    mass = np.repeat(system.mass, 3)

    def coordinate(x):
        return float(((x - system.rest_positions).ravel() * mass) @ phi / (phi * mass @ phi))

    a, b = 1.0, 0.0
    for _ in range(60):
        sim.step()
        b = (b - dt * w * w * a) / (1 + (w * dt) ** 2)   # the mode's backward-Euler step
        a = a + dt * b
        assert coordinate(sim.positions()) == pytest.approx(a, abs=2e-3)
    # its amplitude after 1 s: the bench's mode_decay formula, (1 + (w dt)^2)^(-1/(2 dt))
    radius = max(abs(np.linalg.eigvals(np.array([[1 - (w * dt) ** 2 / (1 + (w * dt) ** 2), dt / (1 + (w * dt) ** 2)],
                                                 [-dt * w * w / (1 + (w * dt) ** 2), 1 / (1 + (w * dt) ** 2)]]))))
    assert radius ** 60 == pytest.approx((1 + (w * dt) ** 2) ** (-0.5 / dt), rel=1e-9)


@pytest.mark.parametrize("constraint", ["none", "sphere"])
def test_flexion_wind_damping_gpu_matches_numpy(ctx, constraint):
    from deformgl.pack.es_check import integrator_case

    system, grid, state, c = integrator_case(constraint)   # flexion springs, spring damping, wind
    opts = dict(dt=1e-2, state=state, constraints=c, cg_iterations=10)
    ref = make_simulation(system, "implicit-euler", "numpy", **opts)
    with make_simulation(system, "implicit-euler", "fragment", ctx=ctx, cg_tolerance=1e-9, cg_check_every=2,
                         **opts) as gpu:
        ref.step(5)
        gpu.step(5)
        assert gpu.last_report.within_tolerance and gpu.last_report.iterations < 10
        assert np.abs(gpu.positions() - ref.positions()).max() <= 1e-6


def test_bench_stiff_flag_errors(capsys):
    from deformgl.cli import main

    assert main(["bench", "trade", "--stiff", "--resolution"]) == 2
    assert "--stiff: only for bench trade, without --resolution" in capsys.readouterr().err
    assert main(["bench", "scaling", "--stiff"]) == 2
