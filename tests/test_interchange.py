"""Results in the tools users open them in (deformgl.scene.interchange, deformgl.scene.fields):
ParaView time series (.pvd of .vtu frames, .xdmf + .h5, read back with meshio), the node grid as
hexahedra with its strain, a USD point cache (read back with usd-core), and the morph-target glb
read back with pygltflib. The fields are checked against the simulation's arrays and against
independent facts (the backward difference of the exported frames, det F of the exported
hexahedra in VTK's own corner order)."""

from __future__ import annotations

import os
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from deformgl.cli import main
from deformgl.scene.animation import frame_plan, render_frames
from deformgl.scene.fields import grid_series, mesh_series
from deformgl.scene.interchange import write_series
from deformgl.scene.schema import load_scene

SCENES = Path(__file__).resolve().parents[1] / "scenes"
#: frames one step apart: the exported velocity is checked against the frames' own difference
FRAMES, STEPS_PER_FRAME = 12, 1


@pytest.fixture(scope="module")
def jelly(tmp_path_factory):
    """A copy of the jelly scene (160x120) and its mesh."""
    folder = tmp_path_factory.mktemp("jelly")
    (folder / "assets").mkdir()
    shutil.copy(SCENES / "assets" / "jelly_block.obj", folder / "assets")
    scene = folder / "jelly.toml"
    scene.write_text((SCENES / "jelly_springs.toml").read_text().replace("size = [320, 240]", "size = [160, 120]"))
    return scene


@pytest.fixture(scope="module")
def frames(ctx, jelly):
    """One run of the jelly falling from rest, drawn through the constant mapping: 12 frames one
    step apart, with its meshes and node states."""
    scene = load_scene(jelly, {"mapping.mode": "constant"})
    plan = frame_plan(scene, frames=FRAMES, steps_per_frame=STEPS_PER_FRAME)
    return scene, plan, render_frames(ctx, scene, plan, mesh=True, nodes=True)


def jelly_mesh(scene) -> Path:
    return Path(scene.mesh.path)


def test_the_node_states_are_the_simulations(frames):
    scene, plan, done = frames
    assert [round(t / scene.physics.dt) for t, *_ in done.nodes] == list(range(FRAMES))
    x = [state[1] for state in done.nodes]
    v = [state[2] for state in done.nodes]
    for k in range(1, FRAMES):  # position Verlet: the simulation's velocity is the backward difference
        assert np.allclose(v[k], (x[k] - x[k - 1]) / scene.physics.dt, atol=1e-3 * np.abs(v[k]).max() + 1e-9)
    assert np.abs(v[-1]).max() > 0  # it moves


@pytest.mark.io
@pytest.mark.parametrize("suffix", [".pvd", ".xdmf"])
def test_the_mesh_series_reads_back_with_its_fields(frames, tmp_path, suffix):
    scene, plan, done = frames
    series = mesh_series(done, plan.fps)
    path = tmp_path / f"mesh{suffix}"
    write_series(path, series)
    rest = done.model.mesh.vertices + done.model.centre
    read = _read_series(path)
    assert [t for t, *_ in read] == pytest.approx([t for t, *_ in done.nodes])
    for k, (t, points, point_data, _) in enumerate(read):
        vertices = done.meshes[k][0]
        if suffix == ".pvd":  # the deformed geometry per frame
            assert np.array_equal(points, vertices)
        else:  # the rest geometry, deformed by its displacement (ParaView's Warp By Vector)
            assert np.array_equal(points, rest)
        assert np.allclose(point_data["displacement"], vertices - rest, rtol=0, atol=1e-12)
        assert np.array_equal(point_data["velocity"], series.point_data[k]["velocity"])
    # frame 0 is the rest state: the rendered mesh is the mesh file's own (scaled), undisplaced
    import trimesh

    own = trimesh.load(jelly_mesh(scene), process=False).vertices * scene.mesh.scale
    assert np.allclose(rest, own, rtol=0, atol=1e-12)
    assert np.abs(read[0][2]["displacement"]).max() < 1e-6 * np.abs(own).max()
    # the velocity is the backward difference of the mesh's own positions over the last step
    # (frames one step apart; float32 positions: measured within 0.1 % of the largest speed)
    dt = scene.physics.dt
    for k in range(2, FRAMES):
        difference = (done.meshes[k][0] - done.meshes[k - 1][0]) / dt
        velocity = read[k][2]["velocity"]
        assert np.abs(velocity - difference).max() < 0.005 * np.abs(difference).max(), k
    assert np.abs(read[-1][2]["velocity"]).max() > 0.02  # m/s: it falls
    # the grid's strain at each vertex: that of the full cell it lies in at rest (found by index here)
    grid = done.model.grid
    from deformgl.sim.terms.volume.energy import grid_cells

    cells = grid_cells(grid.occupied, grid.index)
    lower = {tuple(ijk): c for c, ijk in enumerate(grid.ijk[cells[:, 0]])}
    at = (done.model.mesh.vertices - grid.origin) / grid.spacing
    inside = np.floor(at).astype(int)
    clear = (np.abs(at - np.round(at)) > 1e-6).all(axis=1)  # not on a face between two cells
    hits = [(v, lower[tuple(ijk)]) for v, ijk in enumerate(inside) if clear[v] and tuple(ijk) in lower]
    assert len(hits) >= 10, len(hits)
    vertex, cell = np.array(hits).T
    x = done.nodes[-1][1]
    f = np.einsum("cai,aj->cij", x[cells[cell]], np.array([[2 * (c & 1) - 1, 2 * (c >> 1 & 1) - 1, 2 * (c >> 2 & 1) - 1]
                                                         for c in range(8)]) / (4 * grid.spacing))
    assert np.allclose(read[-1][2]["volume_ratio"][vertex], np.linalg.det(f), rtol=1e-9)
    assert read[-1][2]["green_strain"].shape == (len(rest), 9)


@pytest.mark.io
def test_the_grid_series_holds_hexahedra_with_their_strain(frames, tmp_path):
    import meshio

    scene, plan, done = frames
    grid = done.model.grid
    write_series(tmp_path / "grid.pvd", grid_series(done, plan.fps))
    read = _read_series(tmp_path / "grid.pvd")
    mesh = meshio.read(tmp_path / "grid_0000.vtu")
    (block,) = mesh.cells
    assert block.type == "hexahedron" and len(block.data) > 0
    h = grid.spacing
    # VTK's own hexahedron: natural corners (-1,-1,-1) (1,-1,-1) (1,1,-1) (-1,1,-1), then z = +1
    natural = np.array([[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1],
                        [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]], float)
    for k, (t, points, point_data, cell_data) in enumerate(read):
        x = done.nodes[k][1] + done.model.centre
        assert np.array_equal(points, x)
        assert np.allclose(point_data["displacement"], done.nodes[k][1] - grid.rest_positions, rtol=0, atol=1e-12)
        assert np.array_equal(point_data["velocity"], done.nodes[k][2])
        f = np.einsum("cai,aj->cij", points[block.data], natural / (4 * h))  # F at the centre, from VTK's order
        assert np.allclose(cell_data["volume_ratio"], np.linalg.det(f), rtol=1e-9)
        e = 0.5 * (np.einsum("cki,ckj->cij", f, f) - np.eye(3))
        assert np.allclose(cell_data["green_strain"].reshape(-1, 3, 3), e, atol=1e-12)
        assert ((cell_data["fill"] > 0) & (cell_data["fill"] <= 1)).all()
    assert np.allclose(read[0][3]["volume_ratio"], 1.0, atol=1e-5)  # at rest (float32 positions)
    assert np.abs(read[-1][3]["green_strain"]).max() > 1e-5  # it strains under its weight


@pytest.mark.usd
@pytest.mark.parametrize("suffix", [".usd", ".usda"])
def test_a_usd_point_cache_holds_every_frame(frames, tmp_path, suffix):
    from pxr import Usd, UsdGeom

    scene, plan, done = frames
    series = mesh_series(done, plan.fps)
    path = tmp_path / f"jelly{suffix}"
    write_series(path, series)
    stage = Usd.Stage.Open(str(path))
    assert stage.GetTimeCodesPerSecond() == stage.GetFramesPerSecond() == plan.fps
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0 and UsdGeom.GetStageUpAxis(stage) == "Y"
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, FRAMES - 1)
    mesh = UsdGeom.Mesh(stage.GetDefaultPrim().GetChild("mesh"))
    faces = np.asarray(done.model.mesh.faces)
    assert np.array_equal(np.asarray(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3), faces)
    assert set(mesh.GetFaceVertexCountsAttr().Get()) == {3}
    assert mesh.GetPointsAttr().GetTimeSamples() == list(range(FRAMES))
    displacement = UsdGeom.PrimvarsAPI(mesh.GetPrim()).GetPrimvar("displacement")
    for k in range(FRAMES):
        points = np.asarray(mesh.GetPointsAttr().Get(k))
        assert np.array_equal(points, done.meshes[k][0].astype(np.float32))
        normals = np.asarray(mesh.GetNormalsAttr().Get(k))
        assert np.allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)
        speed = UsdGeom.PrimvarsAPI(mesh.GetPrim()).GetPrimvar("velocity")
        assert np.array_equal(np.asarray(speed.Get(k)), series.point_data[k]["velocity"].astype(np.float32))
        if k:  # per second of time codes: points + velocities / fps meet the next sample (one step apart)
            before = np.asarray(mesh.GetPointsAttr().Get(k - 1), np.float64)
            step = np.asarray(mesh.GetVelocitiesAttr().Get(k), np.float64) / plan.fps
            assert np.abs(before + step - points).max() < 0.01 * np.abs(points - before).max() + 1e-7
        assert np.array_equal(np.asarray(displacement.Get(k)), series.point_data[k]["displacement"].astype(np.float32))
        lo, hi = (np.asarray(v) for v in mesh.GetExtentAttr().Get(k))
        assert np.allclose(lo, points.min(axis=0)) and np.allclose(hi, points.max(axis=0))


@pytest.mark.io
def test_the_morph_target_glb_reads_back_with_pygltflib(frames, tmp_path):
    from pygltflib import GLTF2

    from deformgl.render.gltf_morph import write_morph_glb

    scene, plan, done = frames
    write_morph_glb(tmp_path / "a.glb", [(v, n) for v, n, _ in done.meshes], done.meshes[0][2], plan.fps)
    gltf = GLTF2.load(str(tmp_path / "a.glb"))
    blob = gltf.binary_blob()

    def accessor(i):
        a = gltf.accessors[i]
        view = gltf.bufferViews[a.bufferView]
        width = {"SCALAR": 1, "VEC3": 3}[a.type]
        dtype = np.float32 if a.componentType == 5126 else np.uint32
        return np.frombuffer(blob, dtype, a.count * width, view.byteOffset + (a.byteOffset or 0)).reshape(a.count, -1)

    primitive = gltf.meshes[0].primitives[0]
    base = accessor(primitive.attributes.POSITION)
    for k in range(FRAMES):
        frame = base + (accessor(primitive.targets[k - 1]["POSITION"]) if k else 0)
        assert np.abs(frame - done.meshes[k][0]).max() < 1e-5
    assert np.array_equal(accessor(primitive.indices).reshape(-1, 3), done.meshes[0][2])
    assert len(gltf.animations[0].channels) == 1 and gltf.animations[0].channels[0].target.path == "weights"


@pytest.mark.io
def test_the_cli_writes_both_series_together(ctx, jelly, tmp_path, capsys):
    args = ["render", str(jelly), "--frames", "3", "--steps-per-frame", "5", "--mapping", "constant", "--quiet", "-o", str(tmp_path / "a.gif"),
            "--export-mesh", str(tmp_path / "m.xdmf"), "--export-grid", str(tmp_path / "g.pvd")]
    assert main(args) == 0, capsys.readouterr().err
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["a.gif", "g.pvd", "g_0000.vtu", "g_0001.vtu", "g_0002.vtu", "m.h5", "m.xdmf"]
    # a killed run's scratch folder in an output folder is removed by the next run there
    stale = tmp_path / ".m.xdmf.deformgl-999999999-0123456789ab.tmp"
    stale.mkdir()
    (stale / "m.h5").write_bytes(b"x")
    os.utime(stale, (1, 1))
    assert len(_read_series(tmp_path / "m.xdmf")) == len(_read_series(tmp_path / "g.pvd")) == 3
    # a still: one .vtu with the velocity of the run's last step (the still's 20 steps, whatever
    # steps per frame say), drawn as the .ply export of the same still draws it
    still = ["render", str(jelly), "--steps", "20", "--steps-per-frame", "7", "--mapping", "constant", "--quiet",
             "-o", str(tmp_path / "s.png")]
    assert main([*still, "--export-mesh", str(tmp_path / "s.vtu")]) == 0, capsys.readouterr().err
    assert main([*still[:-1], str(tmp_path / "p.png"), "--export-mesh", str(tmp_path / "p.ply")]) == 0
    assert not stale.exists()
    (frame,) = _read_vtu_frames(tmp_path / "s.vtu")
    import trimesh

    assert np.abs(frame.points - trimesh.load(tmp_path / "p.ply", process=False).vertices).max() < 1e-6
    assert set(frame.point_data) == {"displacement", "velocity", "volume_ratio", "green_strain"}
    assert np.abs(frame.point_data["velocity"]).max() > 0


def _read_vtu_frames(path: Path):
    import meshio

    return [meshio.read(path)]


def test_a_missing_extra_is_one_line_before_any_work(jelly, tmp_path, capsys, monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name in ("meshio", "pxr") else real(name, *a))
    for flag, name, extra in (("--export-mesh", "m.usd", "usd"), ("--export-mesh", "m.pvd", "io"),
                              ("--export-grid", "g.xdmf", "io")):
        code = main(["render", str(jelly), "--frames", "2", "-o", str(tmp_path / "a.gif"), flag, str(tmp_path / name)])
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1 and f"pip install 'deformgl[{extra}]'" in err and flag in err, err
    assert not list(tmp_path.iterdir())


def test_formats_that_cannot_hold_the_request_are_refused(jelly, tmp_path, capsys):
    for flag, name, words in (("--export-mesh", "m.vtu", "a .vtu holds one frame"),
                              ("--export-grid", "g.usd", "--export-grid must end in"),
                              ("--export-mesh", "m.stl", "--export-mesh must end in")):
        code = main(["render", str(jelly), "--frames", "2", "-o", str(tmp_path / "a.gif"), flag, str(tmp_path / name)])
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1 and words in err, err
    code = main(["render", str(jelly), "--frames", "2", "-o", str(tmp_path / "a.gif"), "--mapping", "constant",
                 "--export-mesh", str(tmp_path / "m.glb"), "--json", str(tmp_path / "m.glb")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "named twice among the outputs" in err, err
    assert not list(tmp_path.iterdir())


@pytest.mark.io
def test_what_a_time_series_cannot_hold_is_refused(jelly, tmp_path, capsys):
    code = main(["render", str(jelly), "--frames", "2", "-o", str(tmp_path / "a.gif"), "--mapping", "constant",
                 "--export-mesh", str(tmp_path / "m.pvd"), "--export-grid", str(tmp_path / "m.pvd")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "named twice among the outputs" in err, err
    # a still's shader-pack inputs are not written beside a time series
    code = main(["render", str(jelly), "-o", str(tmp_path / "a.png"), "--mapping", "constant", "--pack-inputs",
                 str(tmp_path / "p.npz"), "--export-grid", str(tmp_path / "g.vtu")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "not with a time series" in err, err
    # frames of one node state: a time series of them would repeat one state
    for scene, more in ((jelly, ["--steps-per-frame", "0", "--mapping", "constant"]),
                        (SCENES / "dragon_bend_auto.toml", [])):  # (nodes from a motion)
        code = main(["render", str(scene), "--frames", "3", "-o", str(tmp_path / "a.gif"), "--export-mesh",
                     str(tmp_path / "m.pvd"), *more])
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1 and "show one node state" in err, err
    assert not list(tmp_path.iterdir())


def _read_series(path: Path) -> list[tuple[float, np.ndarray, dict, dict]]:
    """(time, points, point data, cell data of the one block) per frame of a .pvd or .xdmf."""
    import meshio

    if path.suffix == ".pvd":
        out = []
        for entry in ET.parse(path).getroot().iter("DataSet"):
            mesh = meshio.read(path.parent / entry.get("file"))
            out.append((float(entry.get("timestep")), mesh.points, mesh.point_data,
                        {n: v[0] for n, v in mesh.cell_data.items()}))
        return out
    with meshio.xdmf.TimeSeriesReader(path) as reader:
        points, _ = reader.read_points_cells()
        out = []
        for k in range(reader.num_steps):
            t, point_data, cell_data = reader.read_data(k)
            out.append((float(t), points, point_data, {n: v[0] for n, v in cell_data.items()}))
        return out


@pytest.mark.io
def test_a_cloth_grid_is_a_sheet_of_quads_with_their_area_ratio(ctx, tmp_path, capsys):
    import meshio

    from deformgl.grid.nodes import NodeGrid
    from deformgl.scene.fields import sheet_quads

    args = ["render", str(SCENES / "cloth_64.toml"), "--frames", "2", "--steps-per-frame", "40", "--quiet",
            "-o", str(tmp_path / "a.gif"), "--export-grid", str(tmp_path / "g.pvd")]
    assert main(args) == 0, capsys.readouterr().err
    mesh = meshio.read(tmp_path / "g_0001.vtu")
    (block,) = mesh.cells
    assert block.type == "quad" and len(block.data) == 63 * 63
    p = mesh.points[block.data]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1]), axis=1)
    rest = (mesh.points - mesh.point_data["displacement"])[block.data]
    rest_area = 0.5 * np.linalg.norm(np.cross(rest[:, 2] - rest[:, 0], rest[:, 3] - rest[:, 1]), axis=1)
    assert np.allclose(mesh.cell_data["area_ratio"][0], area / rest_area, rtol=1e-6)
    # each quad turns counter-clockwise about the sheet's thin axis (+y here)
    for axis in range(3):
        shape = [3, 2, 4]
        shape[axis] = 1
        sheet = NodeGrid(np.zeros(3), 1.0, np.ones(shape, bool))
        quads = sheet_quads(sheet)
        x = sheet.rest_positions[quads]
        assert len(quads) == np.prod([n - 1 for n in shape if n > 1])
        assert (np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 1])[:, axis] > 0).all(), axis
    assert len(sheet_quads(NodeGrid(np.zeros(3), 1.0, np.ones((2, 2, 2), bool)))) == 0


@pytest.mark.io
def test_a_failed_series_leaves_nothing(frames, tmp_path, monkeypatch):
    """A write that fails half-way (the third frame's .vtu) leaves no file, no temporary and no
    scratch folder, inside the run's OutputSet or alone."""
    from deformgl.files import OutputSet
    from deformgl.scene import interchange
    from deformgl.scene.interchange import series_paths

    scene, plan, done = frames
    series = grid_series(done, plan.fps)
    real, calls = interchange._write_vtu, []

    def fail_on_the_third(path, s, k):
        calls.append(k)
        if len(calls) == 3:
            raise OSError(28, "No space left on device")
        real(path, s, k)

    monkeypatch.setattr(interchange, "_write_vtu", fail_on_the_third)
    for inside in (False, True):
        calls.clear()
        with pytest.raises(OSError, match="No space"):
            if inside:
                with OutputSet(series_paths(tmp_path / "g.pvd", FRAMES)):
                    write_series(tmp_path / "g.pvd", series)
            else:
                write_series(tmp_path / "g.pvd", series)
        assert list(tmp_path.iterdir()) == []


@pytest.mark.io
def test_a_non_finite_field_is_refused_and_nothing_written(frames, tmp_path):
    import dataclasses

    from deformgl.errors import SimulationError

    scene, plan, done = frames
    series = grid_series(done, plan.fps)
    data = [dict(d) for d in series.point_data]
    data[2]["velocity"] = data[2]["velocity"].copy()
    data[2]["velocity"][5, 1] = np.nan
    with pytest.raises(SimulationError, match=r"frame 2 .*velocity of point or cell 5 is not finite"):
        write_series(tmp_path / "g.xdmf", dataclasses.replace(series, point_data=data))
    assert list(tmp_path.iterdir()) == []


def test_a_grid_with_nothing_to_write_is_refused_before_the_run():
    from types import SimpleNamespace

    from deformgl.errors import InputError
    from deformgl.grid.nodes import NodeGrid
    from deformgl.scene.fields import check_grid_export

    scene = SimpleNamespace(source=Path("rod.toml"))
    with pytest.raises(InputError, match=r"rod.toml: --export-grid: .* neither a full cell nor the quads"):
        check_grid_export(scene, SimpleNamespace(grid=NodeGrid(np.zeros(3), 1.0, np.ones((1, 1, 5), bool))))
    for shape in ((2, 2, 2), (3, 1, 3)):  # a cell; a sheet
        check_grid_export(scene, SimpleNamespace(grid=NodeGrid(np.zeros(3), 1.0, np.ones(shape, bool))))
