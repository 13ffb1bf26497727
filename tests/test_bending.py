"""A sheet's bending stiffness in N·m (deformgl.sim.terms.bending): the discrete plate energy, its
calibration against the analytic plate, every backend against the NumPy reference, the dt check."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from studies.cloth_bending import elastica_errors, plate_ratio, strip_ratio, twisted_plate_ratio
from deformgl.errors import InputError
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.terms.bending import SHEET_BENDING_POISSON, sheet_bending
from deformgl.sim.limits import check_dt, dt_limit
from deformgl.sim.materials import SheetMaterial, sheet_system
from deformgl.sim.simulation import SimulationSetupError, make_simulation
from deformgl.sim.springs import max_angular_frequency

NU = SHEET_BENDING_POISSON


def _sheet(n: int = 9, m: int | None = None, h: float = 0.1) -> NodeGrid:
    return NodeGrid(np.zeros(3), h, np.ones((n, 1, m or n), bool))


@pytest.mark.parametrize("field", ["cylinder", "saddle", "twist"])
def test_energy_of_quadratic_fields_is_the_plate_energy(field: str) -> None:
    """Under w = quadratic the stencils sum to Timoshenko's W = D/2 [(k_xx + k_yy)^2 - 2 (1 - nu)
    (k_xx k_yy - k_xy^2)] times the area they cover: the closed forms of a 9 x 9 sheet, borders included."""
    n, h, d, k = 9, 0.1, 2.0, 3.0
    grid = _sheet(n, h=h)
    bending = sheet_bending(grid, d)
    x = grid.rest_positions.copy()
    px, pz = x[:, 0], x[:, 2]
    w = {"cylinder": 0.5 * k * px ** 2, "saddle": 0.5 * k * (px ** 2 - pz ** 2), "twist": k * px * pz}[field]
    x[:, 1] = w
    expected = {
        # x-triplets at the n - 2 inner columns: D/2 k^2 h^2 at the n - 2 inner nodes of each, and at
        # its 2 border nodes (weight 1/2, one triplet: a free edge) (1 - nu^2) D/2 k^2 h^2 / 2
        "cylinder": d / 2 * k ** 2 * h ** 2 * (n - 2) * ((n - 2) + (1 - NU ** 2)),
        # inner nodes: (1 - nu) D k^2 h^2 (the Laplacian is 0); border nodes (weight 1/2, one
        # triplet): (1 - nu^2) D k^2 h^2 / 4, 4 (n - 2) of them
        "saddle": (1 - NU) * d * k ** 2 * h ** 2 * (n - 2) ** 2 + (1 - NU ** 2) * d * k ** 2 * h ** 2 * (n - 2),
        # every full cell: (1 - nu) D k^2 h^2
        "twist": (1 - NU) * d * k ** 2 * ((n - 1) * h) ** 2,
    }[field]
    assert bending.energy(x) == pytest.approx(expected, rel=1e-10)


def test_matrix_is_symmetric_semidefinite_with_rigid_motions_free() -> None:
    grid = NodeGrid(np.zeros(3), 0.05, np.pad(np.ones((6, 1, 5), bool), ((0, 2), (0, 0), (0, 1)))
                    | np.eye(8, 6, dtype=bool)[:, None, :])  # a sheet with a ragged edge and a thin tail
    bending = sheet_bending(grid, 0.7)
    b = bending.matrix.toarray()
    assert np.array_equal(b, b.T)
    eig = np.linalg.eigvalsh(b)
    assert eig.min() > -1e-12 * eig.max()
    assert np.allclose(b.sum(axis=1), 0.0, atol=1e-12 * eig.max())
    rest = grid.rest_positions
    moved = Rotation.from_rotvec([0.3, -1.1, 0.4]).apply(rest) + [0.2, -0.5, 1.0]
    # (zero up to rounding: |B| |x|^2 times the float64 epsilon)
    assert bending.energy(moved) < 1e-14 * eig.max() * float((moved ** 2).sum())
    stretched = rest * [1.3, 1.0, 0.8]  # any in-plane affine map of the flat sheet: no bending
    assert bending.energy(stretched) < 1e-14 * eig.max() * float((stretched ** 2).sum())
    bent = rest.copy()
    bent[:, 1] = 0.1 * rest[:, 0] ** 2  # and a bent one stores energy
    assert bending.energy(bent) > 1e-6


def test_calibrated_against_the_analytic_plate() -> None:
    """Navier's simply supported plate (second order: 0.19 % at 9 across, 0.045 % at 17), the
    twisted plate (exact), the free cantilever strip against the narrow plate's D (1 - nu^2)
    (two nodes wide: 0.18 % at 17 along; 0.1 m wide: 1.8 % stiff at 3 and 9 across alike, the
    clamp holding the curl near the root): docs/ACCURACY.md."""
    e9, e17 = abs(plate_ratio(9) - 1), abs(plate_ratio(17) - 1)
    assert e9 < 3e-3 and e17 < 6e-4 and e9 / e17 > 3.5
    assert twisted_plate_ratio(5) == pytest.approx(1.0, abs=1e-10)
    assert twisted_plate_ratio(9) == pytest.approx(1.0, abs=1e-10)
    s9, s17 = abs(strip_ratio(9) - 1), abs(strip_ratio(17) - 1)
    assert s9 < 1e-2 and s17 < 3e-3 and s9 / s17 > 3.0
    wide3, wide9 = strip_ratio(21, 3), strip_ratio(81, 9)  # free edges: no first-order error in h
    assert 0.97 < wide3 < 0.99 and 0.97 < wide9 < 0.99 and abs(wide3 - wide9) < 2e-3


def test_large_deflection_matches_the_heavy_elastica() -> None:
    """An inextensible strip hanging to 0.9 of its length (rho_A g L^3 / D = 30) by Newton on the
    nonlinear sheet: within 0.7 % of the elastica at 11 nodes along, 0.2 % at 21 (measured 0.59 %
    and 0.16 %)."""
    for n, tol in ((11, 7e-3), (21, 2e-3)):
        ex, ey = elastica_errors(n, 30.0)
        assert abs(ex) < tol and abs(ey) < tol


def test_material_and_scene_errors(tmp_path) -> None:
    with pytest.raises(ValueError, match="give one"):
        SheetMaterial(50.0, 0.2, flexion_ratio=0.2, bending_stiffness=1e-4)
    with pytest.raises(ValueError, match="bending_stiffness must be a finite number >= 0"):
        SheetMaterial(50.0, 0.2, bending_stiffness=-1.0)
    from deformgl.scene.schema import load_scene

    base = ('[cloth]\nnodes = [9, 9]\nsize = 0.3\n[material]\nstretch_modulus = 50.0\nareal_density = 0.2\n')
    cases = {"bending_stiffness = 1e-4\nflexion_ratio = 0.1\n": "material.bending_stiffness: not used with flexion_ratio",
             "bending_stiffness = -2.0\n": "material.bending_stiffness: must be > 0",
             "bending_stiffness = 1e-4\n[physics]\nintegrator = \"xpbd\"\n": "material.bending_stiffness: has no XPBD"}
    for extra, message in cases.items():
        path = tmp_path / "s.toml"
        path.write_text(base + extra)
        with pytest.raises(InputError, match=message):
            load_scene(path)
    path.write_text(base + "bending_stiffness = 1e-4\n")
    assert load_scene(path).physics.material.bending_stiffness == 1e-4


def _hanging(d: float = 2e-4, n: int = 9, m: int = 5, ragged: bool = False):
    occupied = np.ones((n, 1, m), bool)
    if ragged:  # a sheet that is not a full box: the backends' neighbour tables, not the dense path
        occupied[n - 2:, :, m - 2:] = False
    grid = NodeGrid(np.zeros(3), 0.02, occupied)
    system, _ = sheet_system(grid, SheetMaterial(50.0, 0.2, bending_stiffness=d), fixed=grid.ijk[:, 0] <= 1)
    return system


def test_xpbd_refuses_bending() -> None:
    with pytest.raises(SimulationSetupError, match="no XPBD constraint"):
        make_simulation(_hanging(), "xpbd", "numpy", dt=1e-3)


@pytest.mark.gl
def test_xpbd_on_the_gpu_refuses_bending(ctx) -> None:
    with pytest.raises(SimulationSetupError, match="no XPBD constraint"):
        make_simulation(_hanging(), "xpbd", "fragment", dt=1e-3, ctx=ctx)


def test_bending_parameters_are_checked() -> None:
    grid = _sheet(5)
    for nu in (-0.1, 1.0, 1.5):
        with pytest.raises(ValueError, match="poissons_ratio must be in"):
            sheet_bending(grid, 1.0, poissons_ratio=nu)
    with pytest.raises(ValueError, match="not one node thick"):
        sheet_bending(NodeGrid(np.zeros(3), 0.1, np.ones((3, 2, 3), bool)), 1.0)
    bending = sheet_bending(grid, 1.0)
    with pytest.raises(ValueError, match="not in its neighbour table"):
        bending.neighbour_coefficients(grid.neighbours)  # the 18 without the flexion neighbours at 2h


@pytest.mark.parametrize("integrator,dt,backends", [
    ("semi-implicit", 2e-4, ("fragment", "feedback")), ("rk4", 2e-4, ("fragment", "feedback")),
    ("verlet", 2e-4, ("fragment", "feedback")), ("implicit-euler", 2e-3, ("fragment",))])
@pytest.mark.parametrize("ragged", [False, True])
def test_gpu_backends_match_numpy(ctx, integrator: str, dt: float, backends: tuple[str, ...], ragged: bool) -> None:
    """A cantilever sheet with bending (a full rectangle: the fragment backend's dense path; and
    ragged: its neighbour tables), 200 steps: the GPU's float32 positions within 1e-5 of the
    sheet's length of the float64 reference (float32 rounding of positions: measured 5e-8 to
    1.1e-6 m on 0.16 m), and 30 times closer to it than the same sheet without its bending is."""
    from dataclasses import replace

    system = _hanging(ragged=ragged)
    options = {"cg_iterations": 40} if integrator == "implicit-euler" else {}
    ref = make_simulation(system, integrator, "numpy", dt=dt, **options)
    ref.step(200)
    expected = ref.positions()
    plain = make_simulation(replace(system, bending=None), integrator, "numpy", dt=dt, **options)
    plain.step(200)
    bending_effect = float(np.abs(plain.positions() - expected).max())
    length = float(np.ptp(system.rest_positions[:, 0]))
    for backend in backends:
        with make_simulation(system, integrator, backend, dt=dt, ctx=ctx, **options) as sim:
            sim.step(200)
            error = float(np.abs(sim.positions() - expected).max())
            assert error < 1e-5 * length and error * 30 < bending_effect, (backend, error, bending_effect)


def test_forces_and_stiffness_carry_the_bending() -> None:
    """springs.forces adds -B x, and the rest stiffness (the spectrum's, the dt check's) adds B on
    each coordinate: the same system without it differs by exactly that."""
    from dataclasses import replace

    from deformgl.sim.spectrum import stiffness_matrix, stiffness_product
    from deformgl.sim.springs import forces

    system = _hanging()
    plain = replace(system, bending=None)
    rng = np.random.default_rng(3)
    x = system.rest_positions + 0.003 * rng.standard_normal((system.count, 3))
    v = np.zeros_like(x)
    b = system.bending.matrix
    assert np.allclose(forces(system, x, v, 0.0) - forces(plain, x, v, 0.0), -(b @ x), rtol=0, atol=1e-12)
    dx = rng.standard_normal((system.count, 3))
    assert np.allclose(stiffness_product(system, dx) - stiffness_product(plain, dx), b @ dx, atol=1e-9)
    k = stiffness_matrix(system) - stiffness_matrix(plain)
    assert np.allclose(k @ dx.ravel(), (b @ dx).ravel(), atol=1e-9)


def test_dt_check_sees_the_bending() -> None:
    """A bending-dominated sheet (D = 0.5 N m, a soft membrane): the Gershgorin bound is above the
    exact top frequency, the exact limit predicts where semi-implicit Euler turns unstable (stable
    at 0.95 of it, growing at 1.1), and the bound is 10x the membrane's alone."""
    system = _hanging(d=0.5, n=7, m=3)
    membrane = _hanging(d=1e-12, n=7, m=3)
    bound = max_angular_frequency(system).omega
    limit = dt_limit(system, "semi-implicit", exact=True)
    assert bound >= limit.omega * (1 - 1e-9)
    assert max_angular_frequency(membrane).omega * 10 < bound
    assert check_dt(system, "semi-implicit", 0.95 * limit.dt) is None
    assert check_dt(system, "semi-implicit", 1.1 * limit.dt) is not None
    for factor, stable in ((0.95, True), (1.1, False)):
        sim = make_simulation(system, "semi-implicit", "numpy", dt=factor * limit.dt)
        with np.errstate(all="ignore"):  # (the unstable run overflows)
            sim.step(3000)
        moved = np.abs(sim.positions() - system.rest_positions).max()
        assert (np.isfinite(moved) and moved < 1.0) == stable, factor


FLAP = Path(__file__).resolve().parents[1] / "scenes" / "cloth_flap.toml"


def test_flap_scene_settles_at_the_static_equilibrium() -> None:
    """scenes/cloth_flap.toml (3 mm rubber, D = 5e-3 N m, rho_A g L^3 / D = 22) run to its end
    with implicit Euler (NumPy) is at rest where Newton's static equilibrium of the same sheet
    is: within 1 % of its 12 cm sag (measured 0.74 mm)."""
    from studies.tissue_accuracy import static_equilibrium
    from deformgl.scene.pipeline import build_scene_model
    from deformgl.scene.schema import load_scene

    scene = load_scene(FLAP)
    system = build_scene_model(scene).system
    assert system.bending is not None and system.bending.bending_stiffness == 5e-3
    settled = static_equilibrium(system)
    sag = float(system.rest_positions[:, 1].max() - settled[:, 1].min())
    assert 0.10 < sag < 0.14
    physics = scene.physics
    sim = make_simulation(system, "implicit-euler", "numpy", dt=physics.dt, cg_iterations=60)
    sim.step(physics.steps)
    assert np.abs(sim.positions() - settled).max() < 0.01 * sag


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "deformgl", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=300)


@pytest.mark.gl
@pytest.mark.parametrize("backend, integrator, dt, steps", [
    ("fragment", "implicit-euler", 0.015, 100), ("numpy", "implicit-euler", 0.015, 100),
    ("feedback", "semi-implicit", 2e-4, 300), ("fragment", "rk4", 2e-4, 300)])
def test_flap_scene_from_the_cli(tmp_path, backend: str, integrator: str, dt: float, steps: int) -> None:
    out = tmp_path / "flap.png"
    done = _cli("render", str(FLAP), "-o", str(out), "--backend", backend, "--integrator", integrator,
                "--set", f"physics.dt={dt}", "--set", f"physics.steps={steps}", cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    assert out.stat().st_size > 0


@pytest.mark.gl
def test_flap_scene_refuses_xpbd_and_a_large_explicit_dt(tmp_path) -> None:
    done = _cli("render", str(FLAP), "-o", str(tmp_path / "x.png"), "--integrator", "xpbd", cwd=tmp_path)
    assert done.returncode != 0 and "--integrator: xpbd: the scene's material.bending_stiffness has no XPBD constraint" in done.stderr
    assert "Traceback" not in done.stderr
    done = _cli("render", str(FLAP), "-o", str(tmp_path / "x.png"), "--integrator", "semi-implicit",
                "--set", "physics.dt=0.0005", cwd=tmp_path)
    assert done.returncode != 0 and "Traceback" not in done.stderr and "dt" in done.stderr
    assert not (tmp_path / "x.png").exists()


@pytest.mark.gl
def test_bench_sim_bending_prints_the_cost_ratios(ctx) -> None:
    """``python -m studies.bending_cost``'s table: the flexion springs' ratio is 1 in every round,
    every variant of both integrators has a row (timings are for the benchmark, not asserted)."""
    from studies.bending_cost import INTEGRATORS, VARIANTS, bench_bending, format_bending

    rows = bench_bending(ctx, steps=2, rounds=2, sheets=(8,))
    assert {(r.integrator, r.variant) for r in rows} == {(i, v) for i in INTEGRATORS for v in VARIANTS}
    assert all(r.ratio == (1.0, 1.0, 1.0) for r in rows if r.variant == "flexion springs")
    assert all(r.ms > 0 and r.ratio[1] <= r.ratio[0] <= r.ratio[2] for r in rows)
    assert "8x8" in format_bending(rows, "machine", 2)


def test_bench_bending_flag_is_for_bench_sim_only(tmp_path) -> None:
    """The bending cost moved to ``python -m studies.bending_cost`` (issue 43): the flag, with
    ``bench sim`` or elsewhere, ends in one line naming the study's command, no traceback."""
    for args in (["bench", "render", "--bending"], ["bench", "sim", "--bending", "--poisson", "0.45"]):
        done = _cli(*args, cwd=tmp_path)
        assert done.returncode != 0 and "python -m studies." in done.stderr and "Traceback" not in done.stderr
        assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "python -m studies.bending_cost" in _cli("bench", "sim", "--bending", cwd=tmp_path).stderr


def test_dt_message_names_the_bending_where_it_sets_the_limit() -> None:
    limit = dt_limit(_hanging(d=0.5, n=7, m=3), "semi-implicit", exact=True)
    assert "a sheet's bending, D = 0.5 N*m" in limit.message(2 * limit.dt)
    membrane = dt_limit(_hanging(d=1e-9, n=7, m=3), "semi-implicit", exact=True)
    assert "spring" in membrane.message(2 * membrane.dt) and "bending" not in membrane.message(2 * membrane.dt)
