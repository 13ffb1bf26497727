"""Physical materials (deformgl.sim.materials): the calibration constants of the cell-assembled
lattice, its mass assembly, Rayleigh damping, the fragment backend's per-spring stiffness, and
the scene table ``[material]``. The FEM comparison is tests/test_fem.py."""

from __future__ import annotations

import dataclasses
import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from deformgl.cli import main
from deformgl.errors import SceneError
from deformgl.grid.nodes import NodeGrid
from deformgl.scene.pipeline import build_scene_model
from deformgl.scene.schema import load_scene
from deformgl.sim.materials import (PRESETS, ElasticMaterial, SheetMaterial, cell_counts, critical_dt,
                                    lattice_stiffness, lattice_system, sheet_system)
from deformgl.sim.simulation import make_simulation
from deformgl.sim.springs import SHEAR, STRUCTURAL, forces

SCENES = Path(__file__).resolve().parent.parent / "scenes"
GEL = ElasticMaterial(youngs_modulus=5e3, density=1030.0)


def block(shape, h=0.01, origin=(0.0, 0.0, 0.0)) -> NodeGrid:
    return NodeGrid(np.asarray(origin, float), h, np.ones(shape, bool))


def linear_energy(system, strain: np.ndarray) -> float:
    """Sum over springs of k L^2 (n . eps . n)^2 / 2: the lattice's energy under the uniform small
    strain eps, to first order in eps."""
    d = system.rest_positions[system.j] - system.rest_positions[system.i]
    length = np.linalg.norm(d, axis=1)
    n = d / length[:, None]
    stretch = np.einsum("si,ij,sj->s", n, strain, n) * length
    return float(0.5 * np.sum(system.stiffness * stretch ** 2))


def continuum_energy(material: ElasticMaterial, strain: np.ndarray, volume: float) -> float:
    """V (lambda (tr eps)^2 / 2 + mu eps:eps) with the lattice's lambda = mu = 2 E / 5 (nu = 1/4)."""
    lam = mu = 0.4 * material.youngs_modulus
    return volume * (0.5 * lam * np.trace(strain) ** 2 + mu * np.sum(strain * strain))


def random_strain(rng) -> np.ndarray:
    a = rng.normal(size=(3, 3)) * 1e-3
    return 0.5 * (a + a.T)


@pytest.mark.parametrize("shape", [(2, 2, 2), (4, 3, 5), (7, 2, 3)])
def test_a_uniform_strain_of_a_block_stores_the_energy_of_the_isotropic_tensor(shape):
    """C11 = 3k/h, C12 = C44 = k/h (lambda = mu = k/h, nu = 1/4, E = 5k/(2h)): the block of
    full cells stores exactly the continuum's energy under every uniform strain, boundary
    springs included (the patch test of the cell assembly)."""
    rng = np.random.default_rng(1)
    grid = block(shape, h=0.02)
    system, report = lattice_system(grid, GEL)
    volume = report.cells * grid.spacing ** 3
    assert report.cells == math.prod(s - 1 for s in shape) and report.thin_springs == 0
    for _ in range(5):
        eps = random_strain(rng)
        assert linear_energy(system, eps) == pytest.approx(continuum_energy(GEL, eps, volume), rel=1e-10)


def test_the_constants_are_the_ones_derived():
    h = 0.004
    k = lattice_stiffness(GEL, h)
    assert k == pytest.approx(2.0 * GEL.youngs_modulus * h / 5.0)
    # one cell: each edge k/4 and each face diagonal k/2
    system, _ = lattice_system(block((2, 2, 2), h=h), GEL)
    edges = system.spring_class == STRUCTURAL
    assert edges.sum() == 12 and (~edges).sum() == 12
    assert np.allclose(system.stiffness[edges], k / 4) and np.allclose(system.stiffness[~edges], k / 2)
    # uniaxial strain eps_xx only: sigma_xx = C11 eps = 3k/h eps, energy C11 eps^2 / 2 per volume
    eps = np.diag([1e-3, 0.0, 0.0])
    big, report = lattice_system(block((5, 5, 5), h=h), GEL)
    assert linear_energy(big, eps) == pytest.approx(0.5 * 3 * k / h * 1e-6 * report.cells * h ** 3, rel=1e-10)


def test_uniaxial_stress_gives_youngs_modulus_and_a_quarter_poisson_ratio():
    """Minimise the energy over the lateral strains at a fixed axial strain: the stress over the
    axial strain is E and the lateral contraction 1/4 (from the lattice's energy, no formula)."""
    system, report = lattice_system(block((3, 3, 3), h=0.01), GEL)
    volume = report.cells * 0.01 ** 3
    axial = 1e-3

    def energy(lateral: float) -> float:
        return linear_energy(system, np.diag([axial, -lateral * axial, -lateral * axial]))

    # the energy is quadratic in the lateral ratio: three samples give its minimum
    e0, e1, e2 = energy(0.0), energy(0.5), energy(1.0)
    nu = 0.25 * (3 * e0 - 4 * e1 + e2) / (e0 - 2 * e1 + e2)
    assert nu == pytest.approx(0.25, rel=1e-9)
    youngs = 2.0 * energy(nu) / (volume * axial ** 2)
    assert youngs == pytest.approx(GEL.youngs_modulus, rel=1e-9)


def test_masses_are_an_eighth_of_a_cell_per_corner():
    h = 0.01
    grid = block((3, 3, 3), h=h)
    system, report = lattice_system(grid, GEL)
    cell = GEL.density * h ** 3
    assert system.mass.sum() == pytest.approx(8 * cell)  # 8 cells
    ijk = grid.ijk
    on_boundary = ((ijk == 0) | (ijk == 2)).sum(axis=1)  # 3: corner, 2: edge, 1: face, 0: centre
    expected = {3: cell / 8, 2: cell / 4, 1: cell / 2, 0: cell}
    for count, mass in expected.items():
        assert np.allclose(system.mass[on_boundary == count], mass)


def test_the_same_body_at_any_resolution_has_the_same_mass_and_stiffness_scale():
    """The issue's complaint: mass and stiffness no longer follow the node count."""
    masses = []
    for n in (3, 5, 9, 17):
        h = 0.08 / (n - 1)
        system, _ = lattice_system(block((n, n, n), h=h), GEL)
        masses.append(system.mass.sum())
    assert np.allclose(masses, GEL.density * 0.08 ** 3, rtol=1e-12)


def test_thin_features_get_one_cells_share_and_are_reported():
    occ = np.zeros((4, 4, 3), bool)
    occ[:2, :2, :2] = True     # one full cell
    occ[2:, 0, 0] = True       # a one-node-thin line sticking out of it
    grid = NodeGrid(np.zeros(3), 0.01, occ)
    system, report = lattice_system(grid, GEL)
    counts, node_cells, _ = cell_counts(grid, system)
    assert report.cells == 1 and report.thin_nodes == 2 and report.thin_springs == int((counts == 0).sum()) > 0
    k = lattice_stiffness(GEL, 0.01)
    thin = counts == 0
    share = np.where(system.spring_class[thin] == STRUCTURAL, k / 4, k / 2)
    assert np.allclose(system.stiffness[thin], share)
    assert np.allclose(system.mass[node_cells == 0], GEL.density * 0.01 ** 3 / 8)
    assert "2 nodes" in report.summary() and "no full cell" in report.summary()


def test_the_sheet_is_isotropic_with_its_membrane_modulus():
    """2D lattice: k_e = 2 k_d, k_d = 3Y/8: energy Y/(1 - nu^2) (...) with nu = 1/3, per area."""
    sheet = SheetMaterial(stretch_modulus=200.0, areal_density=0.2)
    grid = NodeGrid(np.zeros(3), 0.01, np.ones((5, 1, 4), bool))
    system, report = sheet_system(grid, sheet)
    area = report.cells * 0.01 ** 2
    lam = mu = 3.0 * sheet.stretch_modulus / 8.0  # 2D Lame constants k_d
    rng = np.random.default_rng(3)
    for _ in range(4):
        a = rng.normal(size=(2, 2)) * 1e-3
        e2 = 0.5 * (a + a.T)
        eps = np.zeros((3, 3))
        eps[np.ix_([0, 2], [0, 2])] = e2
        expected = area * (0.5 * lam * np.trace(e2) ** 2 + mu * np.sum(e2 * e2))
        assert linear_energy(system, eps) == pytest.approx(expected, rel=1e-10)
    assert 4 * lam * (lam + mu) / (lam + 2 * mu) == pytest.approx(sheet.stretch_modulus)  # Y = 8 k_d / 3
    assert system.mass.sum() == pytest.approx(sheet.areal_density * area)


def test_mass_damping_decays_a_rigid_motion_as_exp_minus_alpha_t():
    material = dataclasses.replace(GEL, mass_damping=5.0)
    system, _ = lattice_system(block((3, 3, 3), h=0.01), material, gravity=(0.0, 0.0, 0.0))
    v = np.tile([0.1, 0.0, 0.0], (system.count, 1))
    f = forces(system, system.rest_positions, v, 0.0)
    assert np.allclose(f, -5.0 * system.mass[:, None] * v)
    from deformgl.sim.integrators import State
    sim = make_simulation(system, "rk4", "numpy", dt=1e-3,
                          state=State(system.rest_positions.copy(), v.copy(), system.rest_positions.copy()))
    sim.step(200)
    assert np.allclose(sim.velocities()[:, 0], 0.1 * math.exp(-5.0 * 0.2), rtol=1e-6)


@pytest.mark.parametrize("integrator", ["euler", "semi-implicit", "midpoint", "rk4", "verlet"])
def test_the_gpu_backends_run_the_calibrated_lattice_like_the_reference(ctx, integrator):
    occ = np.ones((6, 4, 3), bool)
    occ[5, 3, 2] = occ[0, 3, 2] = False  # partial cells: weights other than 1 inside the body
    grid = NodeGrid(np.zeros(3), 0.01, occ)
    material = ElasticMaterial(1e4, 1000.0, mass_damping=4.0, stiffness_damping=2e-4)
    system, _ = lattice_system(grid, material, fixed=grid.ijk[:, 0] == 0)
    dt = 1e-4 if integrator != "euler" else 2e-5
    ref = make_simulation(system, integrator, "numpy", dt=dt)
    ref.step(100)
    moved = np.abs(ref.positions() - system.rest_positions).max()
    assert moved > 1e-5
    for backend in ("fragment", "feedback"):
        sim = make_simulation(system, integrator, backend, dt=dt, ctx=ctx)
        try:
            if backend == "fragment":
                assert sim.tex_weights is not None and sim.fast is None
            sim.step(100)
            assert np.abs(sim.positions() - ref.positions()).max() <= 2e-3 * moved + 1e-7
        finally:
            sim.release()


def test_the_fragment_backend_refuses_damping_out_of_proportion_to_the_weights(ctx):
    system, _ = lattice_system(block((3, 3, 3)), GEL)
    uneven = dataclasses.replace(system, damping=np.full(system.spring_count, 1e-3))
    with pytest.raises(ValueError, match="spring damping in proportion to their stiffness"):
        make_simulation(uneven, "verlet", "fragment", dt=1e-4, ctx=ctx)


def test_critical_dt_falls_as_h_sqrt_rho_over_e():
    base = critical_dt(GEL, 0.01)
    assert critical_dt(GEL, 0.005) == pytest.approx(base / 2)
    assert critical_dt(dataclasses.replace(GEL, youngs_modulus=4 * GEL.youngs_modulus), 0.01) == pytest.approx(base / 2)
    # and it is a true bound of the built system's limit
    from deformgl.sim.limits import dt_limit
    system, _ = lattice_system(block((5, 5, 5), h=0.01), GEL, fixed=block((5, 5, 5)).ijk[:, 1] == 0)
    assert base <= dt_limit(system, "verlet").dt


def test_presets_have_sources():
    assert {"liver", "gelatin", "rubber"} <= set(PRESETS)
    for name, material in PRESETS.items():
        assert material.name == name and material.source and material.youngs_modulus > 0
    assert 1e3 <= PRESETS["liver"].youngs_modulus <= 1e4 and PRESETS["liver"].density == 1060.0


def test_bad_material_values_are_refused():
    with pytest.raises(ValueError, match="youngs_modulus"):
        ElasticMaterial(0.0, 1000.0)
    with pytest.raises(ValueError, match="mass_damping"):
        ElasticMaterial(1e3, 1000.0, mass_damping=-1.0)


# --- scenes --------------------------------------------------------------------------------------


def scene_copy(tmp_path, name="jelly.toml", edit=lambda text: text) -> Path:
    (tmp_path / "assets").mkdir(exist_ok=True)
    shutil.copy(SCENES / "assets" / "jelly_block.obj", tmp_path / "assets")
    path = tmp_path / name
    path.write_text(edit((SCENES / "jelly.toml").read_text()))
    return path


def test_the_jelly_scene_is_a_material_scene_at_any_resolution():
    scene = load_scene(SCENES / "jelly.toml")
    assert isinstance(scene.physics.material, ElasticMaterial) and scene.physics.damping == 0.0
    masses = []
    for n in (9, 13, 17):
        built = build_scene_model(dataclasses.replace(scene, grid=dataclasses.replace(scene.grid, nodes_along_longest=n)))
        assert built.lattice is not None and built.lattice.cells > 0
        masses.append(built.system.mass.sum())
        total_pull = sum(load.node_forces(1.0, built.system.mass).sum(axis=0) for load in built.loads)
        assert np.allclose(total_pull, [1.0, 0.0, 0.0])  # total N, whatever the node count
    # the body weighs rho x its volume (0.0976 x 0.0586 x 0.0781 m box: 0.46 kg) within the
    # voxelization's rounding of the box to whole cells
    assert np.allclose(masses, 1030.0 * 0.0976 * 0.05856 * 0.07808, rtol=0.1)


def test_a_material_scene_refuses_per_spring_keys(tmp_path):
    path = scene_copy(tmp_path, edit=lambda t: t.replace("[physics]\n", "[physics]\nstiffness = 6.0\n"))
    with pytest.raises(SceneError, match=r"jelly.toml: physics.stiffness: not used with \[material\]"):
        load_scene(path)


@pytest.mark.parametrize("edit, message", [
    (lambda t: t.replace("density = 1030.0", ""), r"material.density: required"),
    (lambda t: t.replace("density = 1030.0", "density = -3"), r"material.density: must be > 0"),
    (lambda t: t.replace("density = 1030.0", "density = 1030.0\npreset = \"jelly\""), r"material.preset: must be one of"),
    (lambda t: t.replace("density = 1030.0", "stretch_modulus = 3.0"), r"material.stretch_modulus: a sheet"),
    (lambda t: t.replace("density = 1030.0", "densty = 1030.0"), r"material.densty: unknown key"),
    (lambda t: t.replace("density = 1030.0", "density = 1030.0\npoissons_ratio = 0.3\npreset = \"liver\""),
     r"material.preset: not used when youngs_modulus, density and poissons_ratio are all given"),
    (lambda t: t.replace("density = 1030.0", "density = 1030.0\npoissons_ratio = 0.2"),
     r"material.poissons_ratio: must be in \[0.25, 0.499\], got 0.2: below 1/4 the spring lattice would need lambda < mu"),
    (lambda t: t.replace("density = 1030.0", "density = 1030.0\npoissons_ratio = 0.5"),
     r"material.poissons_ratio: must be in \[0.25, 0.499\], got 0.5"),
])
def test_bad_material_tables_name_the_key(tmp_path, edit, message):
    with pytest.raises(SceneError, match=message):
        load_scene(scene_copy(tmp_path, edit=edit))


def test_a_preset_gives_its_values(tmp_path):
    path = scene_copy(tmp_path, edit=lambda t: re.sub(r"youngs_modulus = .*\ndensity = .*\n", 'preset = "liver"\n', t))
    material = load_scene(path).physics.material
    assert material.youngs_modulus == PRESETS["liver"].youngs_modulus and material.name == "liver"


def test_a_region_that_holds_no_material_is_an_error_naming_the_key(ctx, tmp_path, capsys):
    """At 5 along the jelly's `below y 0.05` caught no node (it holds space); selected by material
    it holds the bottom plane (issue 28). A region with none of the mesh's material (above the
    finned bar's bar, beside its fin) is one line naming the key, and the render writes nothing."""
    path = scene_copy(tmp_path, edit=lambda t: t.replace("nodes_along_longest = 9", "nodes_along_longest = 5"))
    built = build_scene_model(load_scene(path))
    assert set(built.grid.ijk[built.system.fixed, 1].tolist()) == {0} and built.system.fixed.sum() >= 16
    fin = (SCENES / "assets" / "finned_bar.obj").as_posix()
    scene = tmp_path / "fin.toml"
    scene.write_text(f'[mesh]\npath = "{fin}"\n[grid]\nnodes_along_longest = 12\n[material]\nyoungs_modulus = 1e6\n'
                     f'density = 1000.0\n[[physics.fixed]]\nregion = "box"\nmin = [0.0, 0.9, 0.6]\nmax = [1.0, 1.0, 1.0]\n')
    with pytest.raises(SceneError, match=r"fin.toml: physics.fixed\[0\]: the region holds none of the mesh's material"):
        build_scene_model(load_scene(scene))
    code = main(["render", str(scene), "-o", str(tmp_path / "out.png"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "physics.fixed[0]: the region holds none of the mesh's material" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out.png").exists()


def test_mesh_scale_makes_the_same_body_in_other_units(tmp_path):
    """A mesh in millimetres with scale = 0.001 is the metre body: same grid, same springs."""
    import trimesh
    mesh = trimesh.load(SCENES / "assets" / "jelly_block.obj", force="mesh")
    mesh.apply_scale(1000.0)
    (tmp_path / "assets").mkdir()
    mesh.export(tmp_path / "assets" / "jelly_mm.obj")
    text = (SCENES / "jelly.toml").read_text().replace('path = "assets/jelly_block.obj"',
                                                       'path = "assets/jelly_mm.obj"\nscale = 0.001')
    (tmp_path / "mm.toml").write_text(text)
    metres = build_scene_model(load_scene(SCENES / "jelly.toml"))
    mm = build_scene_model(load_scene(tmp_path / "mm.toml"))
    assert mm.grid.count == metres.grid.count
    assert mm.grid.spacing == pytest.approx(metres.grid.spacing, rel=1e-9)
    assert np.allclose(mm.system.stiffness, metres.system.stiffness, rtol=1e-9)
    assert np.allclose(mm.system.mass, metres.system.mass, rtol=1e-9)


def test_a_scaled_body_scales_its_springs_and_masses_physically():
    """Length x s with E, rho fixed: k x s, m x s^3, so gravity's sag (m g / k) grows as s^2."""
    for s in (0.01, 100.0):
        small, _ = lattice_system(block((4, 3, 3), h=0.01), GEL)
        scaled, _ = lattice_system(block((4, 3, 3), h=0.01 * s), GEL)
        assert np.allclose(scaled.stiffness, small.stiffness * s, rtol=1e-12)
        assert np.allclose(scaled.mass, small.mass * s ** 3, rtol=1e-12)


def test_an_unstable_material_dt_is_refused_in_material_terms(ctx, tmp_path, capsys):
    path = scene_copy(tmp_path, edit=lambda t: t.replace("dt = 0.0016 ", "dt = 0.05 "))
    code = main(["render", str(path), "-o", str(tmp_path / "out.png"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert re.search(r"it is [0-9.]+ h sqrt\(rho/E\) \(h = [0-9.e-]+ m, E = 5000 Pa, rho = 1030 kg/m\^3\)", err), err
    assert re.search(r"above the verlet limit [0-9.e-]+ s, w = [0-9.e+]+ rad/s at node \d+ \(the cells' inversion barrier, "
                     r"kappa_b = 2.4e\+04 Pa, m = [0-9.e-]+ kg; lanczos bound\)", err), err


def test_a_cloth_takes_a_sheet_material(ctx, tmp_path):
    text = (SCENES / "cloth_64.toml").read_text()
    text = re.sub(r"\nmass = .*\n", "\n", text)
    text = re.sub(r"\ndamping = .*\n", "\n", text)
    text = re.sub(r"\nstiffness = .*\n", "\n", text)
    text = re.sub(r"\[physics.springs\]\n(.*\n)*?\n", "\n", text)
    text = text.replace("[physics]\n", "[material]\nstretch_modulus = 50.0\nareal_density = 0.25\n"
                        "mass_damping = 1.0\n\n[physics]\n")
    path = tmp_path / "cloth.toml"
    path.write_text(text)
    scene = dataclasses.replace(load_scene(path), physics=dataclasses.replace(load_scene(path).physics, steps=20))
    built = build_scene_model(scene)
    assert isinstance(scene.physics.material, SheetMaterial)
    size = scene.cloth.size
    assert built.system.mass.sum() == pytest.approx(0.25 * size * size, rel=1e-9)
    assert set(np.unique(built.system.spring_class)) == {STRUCTURAL, SHEAR}


def test_the_python_api_takes_a_material(ctx):
    from deformgl import Body
    from deformgl.scene.body import below
    import trimesh
    box = trimesh.creation.box(extents=(0.1, 0.05, 0.05))
    masses = []
    for resolution in (5, 9):
        with Body(box, resolution=resolution, material="gelatin", fixed=below("y", 0.1), ctx=ctx) as body:
            assert body.lattice is not None and body.lattice.cells > 0
            masses.append(body.system.mass.sum())
    assert np.allclose(masses, PRESETS["gelatin"].density * 0.1 * 0.05 * 0.05, rtol=0.15)
    with Body(box, resolution=5, material="gelatin", scale=0.001, fixed=below("y", 0.1), ctx=ctx) as mm:
        assert mm.grid.spacing == pytest.approx(0.1e-3 / 4, rel=1e-6)
    with pytest.raises(Exception, match="material must be an ElasticMaterial or one of"):
        Body(box, material="jelly", ctx=ctx)
    with pytest.raises(Exception, match="stiffness: not used with material="):
        Body(box, material="gelatin", stiffness=300.0, ctx=ctx)
    # the Python API's dt refusal speaks in the material's terms too
    import deformgl as dg
    from deformgl.errors import RefusedStepError
    with Body(box, resolution=9, material="gelatin", fixed=below("y", 0.1), ctx=ctx) as body:
        sim = body.simulate(dt=0.05)
        with pytest.raises(RefusedStepError, match=r"it is [0-9.]+ h sqrt\(rho/E\) \(h = [0-9.e-]+ m, E = 1e\+04 Pa"):
            dg.run(sim, 10)


@pytest.mark.parametrize("weight_texture", [False, True], ids=["levels", "texture"])
def test_the_verlet_fast_path_runs_the_lattice_with_weights_and_unweighted_normals(ctx, weight_texture):
    """The foundation pass (one pass per step, the packed Mosegaard & Sørensen 2005, eq. 3 normal with each position) takes
    per-spring weights, as the levels code in the node texture (the default for the lattice) or as
    the weight texture: the same positions as the reference, and normals that are still the
    unweighted unit-vector sums of Mosegaard & Sørensen 2005, eq. 3."""
    from deformgl.sim.backends.verlet_pass import FoundationVerlet
    from deformgl.sim.normals import unit_sums, unpack_normals
    occ = np.ones((6, 4, 3), bool)
    occ[5, 3, 2] = False
    grid = NodeGrid(np.zeros(3), 0.01, occ)
    system, _ = lattice_system(grid, ElasticMaterial(1e4, 1000.0, mass_damping=4.0), fixed=grid.ijk[:, 0] == 0)
    ref = make_simulation(system, "verlet", "numpy", dt=1e-4)
    if not weight_texture:  # the backend picks the pass by itself, with the levels code (the texture: a switch of the pass)
        picked = make_simulation(system, "verlet", "fragment", ctx=ctx, dt=1e-4)
        try:
            assert picked.fast is not None and picked.textures.weight_levels
        finally:
            picked.release()
    sim = FoundationVerlet.for_system(ctx, system, 1e-4, weight_texture=weight_texture)
    try:
        assert sim.textures.weight_levels is not weight_texture
        assert (sim.textures.weights is not None) is weight_texture
        ref.step(150)
        sim.step(150)
        moved = np.abs(ref.positions() - system.rest_positions).max()
        assert moved > 1e-5
        assert np.abs(sim.positions() - ref.positions()).max() <= 2e-3 * moved + 1e-7
        texture, row, slots, slot = sim.position_slot()
        layout = sim.textures.layout
        image = np.frombuffer(texture.read(), dtype="f4").reshape(layout.size[1], layout.size[0], 4)
        got = unpack_normals(layout.gather(grid.ijk, image)[:, 3].astype(np.float32))
        x = layout.gather(grid.ijk, image)[:, :3].astype(np.float64)  # (one step after the normals' x)
        sums = unit_sums(grid, x)
        surface = np.linalg.norm(sums, axis=1) > 0.5
        expected = sums[surface] / np.linalg.norm(sums[surface], axis=1)[:, None]
        assert np.min(np.sum(got[surface] * expected, axis=1)) > 0.999
    finally:
        sim.release()


def test_the_weight_levels_code_holds_the_lattices_cell_shares_and_nothing_else():
    """weight_levels: 24 bits (exact in a float32) that decode, as SPRING_WEIGHT_LEVELS does, to
    the very weights of the lattice; weights that are not cell shares (a third, a zero on an
    existing neighbour, a weight where there is none) get no code, so the texture keeps them."""
    from deformgl.sim.backends.grid_springs import weight_levels
    from deformgl.sim.backends.grid_springs import spring_weights
    occ = np.ones((5, 4, 3), bool)
    occ[4, 3, 2] = occ[0, 0, 0] = False
    grid = NodeGrid(np.zeros(3), 0.01, occ)
    system, _ = lattice_system(grid, GEL)
    k = [float(system.stiffness[system.spring_class == c].max()) for c in (0, 1)]
    weights = spring_weights(system, grid.neighbours, [k[0], k[1], 0.0])
    code = weight_levels(weights, grid.neighbour_mask)
    assert code is not None and code.max() < 2 ** 24
    assert np.array_equal(code.astype(np.float32).astype(np.int64), code)
    mask = (grid.neighbour_mask[:, None] >> np.arange(18)) & 1
    decoded = np.concatenate([0.25 * (((code[:, None] >> (2 * np.arange(6))) & 3) + 1),
                              0.5 * (((code[:, None] >> (6 + np.arange(6, 18))) & 1) + 1)], axis=1) * mask
    assert np.array_equal(decoded, weights)
    assert len(np.unique(weights[mask == 1])) > 2  # (the block has edges in 1, 2 and 4 cells)
    for bad in (1.0 / 3.0, 0.0):
        other = weights.copy()
        other[7, np.flatnonzero(mask[7])[0]] = bad
        assert weight_levels(other, grid.neighbour_mask) is None
    absent = np.flatnonzero(mask[0] == 0)[0]
    other = weights.copy()
    other[0, absent] = 0.5
    assert weight_levels(other, grid.neighbour_mask) is None


def test_the_levels_code_takes_shares_that_float64_rounds_off_a_quarter():
    """An L-shaped body has edges in 3 cells; 3 k / 4 over k is 0.7500000000000001 in float64 for
    some k (here E = 10 kPa, h = 1/11 m), exactly 0.75 in the float32 a texture holds: the code
    still holds the lattice (and so decodes to what the texture path computes with)."""
    from deformgl.sim.backends.grid_springs import weight_levels
    from deformgl.sim.backends.grid_springs import spring_weights
    occ = np.ones((4, 4, 3), bool)
    occ[2:, 2:, :] = False
    grid = NodeGrid(np.zeros(3), 1.0 / 11.0, occ)
    system, _ = lattice_system(grid, ElasticMaterial(1e4, 1000.0))
    k = [float(system.stiffness[system.spring_class == c].max()) for c in (0, 1)]
    weights = spring_weights(system, grid.neighbours, [k[0], k[1], 0.0])
    assert np.any((weights != 0.75) & (weights.astype(np.float32) == np.float32(0.75)))
    assert weight_levels(weights, grid.neighbour_mask) is not None


def test_the_verlet_pass_steps_the_same_with_levels_as_with_the_weight_texture(ctx):
    """The two stores of the lattice's weights are the same function: bit-identical positions
    and normals after 60 steps."""
    from deformgl.sim.backends.verlet_pass import FoundationVerlet
    occ = np.ones((7, 5, 4), bool)
    occ[6, 4, 3] = False
    grid = NodeGrid(np.zeros(3), 0.01, occ)
    system, _ = lattice_system(grid, ElasticMaterial(1e4, 1000.0), fixed=grid.ijk[:, 0] == 0)
    sims = [FoundationVerlet.for_system(ctx, system, 1e-4, weight_texture=t) for t in (False, True)]
    try:
        assert sims[0].textures.weight_levels and sims[0].textures.weights is None
        assert not sims[1].textures.weight_levels and sims[1].textures.weights is not None
        for sim in sims:
            sim.step(60)
        a, b = (sim.read_state() for sim in sims)
        assert np.abs(a[:, :3] - system.rest_positions).max() > 1e-6
        assert np.array_equal(a, b)
    finally:
        for sim in sims:
            sim.release()


def test_the_cpu_peers_refuse_the_calibrated_lattice_rather_than_step_it_wrong():
    from deformgl.bench.peers import PeerStepper
    system, _ = lattice_system(block((3, 3, 3)), GEL)
    with pytest.raises(ValueError, match="per-spring stiffness"):
        PeerStepper(system, dt=1e-4)  # (the check every peer's constructor runs first)


def test_flexion_springs_keep_the_sheets_membrane_modulus():
    """Flexion springs (2h) of r k_d add 4 r k_d to C11; the edges give it up, so the sheet keeps
    Y and nu = 1/3: exactly under shear, and under stretch up to the row ends' missing flexion
    springs (a deficit that falls as 1/n; 41 x 41 nodes: under 2 %)."""
    grid = NodeGrid(np.zeros(3), 0.01, np.ones((41, 1, 41), bool))
    lam = mu = 3.0 * 200.0 / 8.0
    for r in (0.3, 0.5):
        system, report = sheet_system(grid, SheetMaterial(200.0, 0.2, flexion_ratio=r))
        assert (system.spring_class == 2).any()
        area = report.cells * 0.01 ** 2
        for e2, tol in ((np.array([[1e-3, 0.0], [0.0, 0.0]]), 0.02), (np.array([[0.0, 1e-3], [1e-3, 0.0]]), 1e-9)):
            eps = np.zeros((3, 3))
            eps[np.ix_([0, 2], [0, 2])] = e2
            expected = area * (0.5 * lam * np.trace(e2) ** 2 + mu * np.sum(e2 * e2))
            assert linear_energy(system, eps) == pytest.approx(expected, rel=tol)
    with pytest.raises(ValueError, match="flexion_ratio must be at most 0.5"):
        SheetMaterial(200.0, 0.2, flexion_ratio=0.6)


def test_replacing_the_mesh_keeps_its_scale_and_the_record_names_the_material(tmp_path):
    from deformgl.scene.record import material_fields
    path = scene_copy(tmp_path, edit=lambda t: t.replace('path = "assets/jelly_block.obj"',
                                                         'path = "assets/jelly_block.obj"\nscale = 0.5'))
    scene = load_scene(path).with_overrides(mesh=SCENES / "assets" / "jelly_block.obj")
    assert scene.mesh.scale == 0.5
    fields = material_fields(scene)
    assert fields["mesh_scale_m"] == 0.5 and fields["material"]["youngs_modulus"] == 5000.0
    assert material_fields(load_scene(SCENES / "jelly_springs.toml"))["material"] is None
