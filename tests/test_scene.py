"""Tests for deformgl.scene.schema: parsing, defaults, every class of error message, regions and pulls."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from deformgl.errors import SceneError
from deformgl.scene.schema import load_scene
from deformgl.scene.spec import (
    ClothSpec, Converge, Mapping, MotionSpec, Nodes,
    Camera, GridSpec, Light, Material, MeshSpec, Output, Physics, Pull, Region, Render, Scene, parse_size,
)

MESH = '[mesh]\npath = "assets/m.ply.gz"\n'

FULL = """
[mesh]
path = "assets/m.ply.gz"

[mapping]
mode = "curvature"
normal_map = "procedural"
normal_map_strength = 0.5
normal_map_repeat = 2.0
cache = false

[nodes]
source = "motion"
[nodes.motion]
kind = "bend"
angle = 45.0
along = "z"
towards = "x"
amount = 0.5

[grid]
spacing = 0.025

[physics]
dt = 0.001
steps = 12
stiffness = 250
damping = 0.0
mass = 0.5
gravity = [0.0, 0.0, -1.5]

[[physics.fixed]]
region = "below"
axis = "y"
at = 0.1

[[physics.fixed]]
region = "box"
min = [0, 0.2, 0.25]
max = [1, 0.2, 0.75]

[[physics.pull]]
region = "above"
axis = "z"
at = 0.8
force = [0.5, 0.0, -2]
start = 0.25
ramp = 0.5
stop = 3.0

[render]
size = [640, 480]
msaa = 8
background = [0.0, 0.5, 1.0]
show_grid = true

[render.camera]
projection = "orthographic"
azimuth = -45
elevation = -89
fov = 60.5
distance = 2.5
target = [0.5, 0.25, 0.75]

[render.light]
direction = [0.0, 3.0, 4.0]
colour = [2.0, 1.0, 0.5]
ambient = 0.0

[render.material]
colour = [0.1, 0.2, 0.3]
specular = 1.0
shininess = 8

[output]
path = "out/full.png"
"""


@pytest.fixture
def scene_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A directory holding assets/m.ply.gz, made the working directory so messages say jelly.toml."""
    (tmp_path / "assets").mkdir()
    (tmp_path / "assets" / "m.ply.gz").write_bytes(b"not parsed by the loader")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _load(text: str, name: str = "jelly.toml") -> Scene:
    Path(name).write_text(text)
    return load_scene(name)


def _error(text: str) -> str:
    with pytest.raises(SceneError) as info:
        _load(text)
    message = str(info.value)
    assert "\n" not in message
    return message


def test_full_scene_round_trips_every_value(scene_dir: Path) -> None:
    scene = _load(FULL)
    below = Region("below", 1, 0.1, None, None)
    box = Region("box", None, None, (0.0, 0.2, 0.25), (1.0, 0.2, 0.75))
    above = Region("above", 2, 0.8, None, None)
    expected = Scene(
        source=scene_dir / "jelly.toml",
        mesh=MeshSpec(scene_dir / "assets" / "m.ply.gz"),
        grid=GridSpec(None, 0.025),
        physics=Physics(0.001, 12, 250.0, 0.0, 0.5, (0.0, 0.0, -1.5), (below, box),
                        (Pull(above, (0.5, 0.0, -2.0), 0.25, 0.5, 3.0),)),
        render=Render(
            size=(640, 480), msaa=8, background=(0.0, 0.5, 1.0), show_grid=True,
            camera=Camera("orthographic", -45.0, -89.0, 60.5, 2.5, (0.5, 0.25, 0.75)),
            light=Light((0.0, 0.6, 0.8), (2.0, 1.0, 0.5), 0.0),
            material=Material((0.1, 0.2, 0.3), 1.0, 8.0),
        ),
        output=Output(scene_dir / "out" / "full.png"),
        mapping=Mapping("curvature", "procedural", 0.5, 2.0, False),
        nodes=Nodes("motion", None, -1, MotionSpec("bend", 45.0, 1, 2, 0, (0.0, 0.0, 0.0), 0.5)),
    )
    assert scene == expected
    assert isinstance(scene.physics.stiffness, float) and isinstance(scene.render.size[0], int)
    assert scene.source.is_absolute() and scene.mesh.path.is_absolute()


def test_defaults_apply_to_absent_keys(scene_dir: Path) -> None:
    scene = _load(MESH)
    assert scene.grid == GridSpec(8, None)
    assert scene.physics == Physics(0.002, 400, 500.0, 0.5, 0.01, (0.0, -9.81, 0.0), (), ())
    assert scene.render.size == (800, 600) and scene.render.msaa == 4
    assert scene.render.background == (1.0, 1.0, 1.0) and scene.render.show_grid is False
    assert scene.render.camera == Camera("perspective", 30.0, 20.0, 35.0, 1.6, (0.5, 0.5, 0.5))
    assert scene.render.material == Material((0.85, 0.6, 0.35), 0.3, 32.0)
    light = scene.render.light
    assert light.colour == (1.0, 1.0, 1.0) and light.ambient == 0.2
    np.testing.assert_allclose(light.direction, np.array([0.4, 1.0, 0.6]) / math.sqrt(1.52))
    assert scene.output.path == scene_dir / "jelly.png"


def test_pull_defaults_and_absolute_output(scene_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> None:
    elsewhere = tmp_path_factory.mktemp("elsewhere") / "img.PNG"
    scene = _load(MESH + f'[[physics.pull]]\nregion = "box"\nmin = [0, 0, 0]\nmax = [1, 1, 1]\n'
                         f'force = [1, 2, 3]\n[output]\npath = "{elsewhere}"\n')
    (pull,) = scene.physics.pull
    assert (pull.start, pull.ramp, pull.stop) == (0.0, 0.0, math.inf)
    assert scene.output.path == elsewhere


def test_relative_paths_are_relative_to_the_scene_file(scene_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (scene_dir / "jelly.toml").write_text(MESH)
    monkeypatch.chdir(scene_dir / "assets")
    scene = load_scene(scene_dir / "jelly.toml")
    assert scene.mesh.path == scene_dir / "assets" / "m.ply.gz"
    assert scene.output.path == scene_dir / "jelly.png"


@pytest.mark.parametrize(("text", "message"), [
    # unknown keys, top level and nested, with suggestions
    ("[rendr]\nmsaa = 4\n", "rendr: unknown key (did you mean 'render'?)"),
    ("[render.camra]\nfov = 40\n", "render.camra: unknown key (did you mean 'camera'?)"),
    ('[[physics.fixed]]\nregion = "below"\naxis = "y"\natt = 0.1\n',
     "physics.fixed[0].att: unknown key (did you mean 'at'?)"),
    ("[output]\nzzz = 1\n", "output.zzz: unknown key (expected one of 'path')"),
    # wrong types; bools are not numbers; floats are not integers
    ('[physics]\ndt = "abc"\n', "physics.dt: must be a number, got string 'abc'"),
    ("[physics]\ndt = true\n", "physics.dt: must be a number, got boolean true"),
    ("[physics]\nsteps = 2.5\n", "physics.steps: must be an integer, got float 2.5"),
    ("[physics]\nsteps = false\n", "physics.steps: must be an integer, got boolean false"),
    ("[render]\nshow_grid = 1\n", "render.show_grid: must be a boolean (true or false), got integer 1"),
    ('[render]\ncull = "yes"\n', "render.cull: must be a boolean (true or false), got string 'yes'"),
    ("[render]\nsize = [800, true]\n", "render.size[1]: must be an integer, got boolean true"),
    ('[physics]\ngravity = [0, "a", 0]\n', "physics.gravity[1]: must be a number, got string 'a'"),
    ("[physics]\ngravity = 9.81\n", "physics.gravity: must be an array of 3 values, got float 9.81"),
    ("[render]\ncamera = 3\n", "render.camera: must be a table, got integer 3"),
    ("[physics]\nfixed = 3\n",
     "physics.fixed: must be an array of tables ([[physics.fixed]]), got integer 3"),
    ("[physics]\nfixed = [1]\n", "physics.fixed[0]: must be a table, got integer 1"),
    # out of range
    ("[physics]\ndt = -1\n", "physics.dt: must be > 0, got -1"),
    ("[physics]\ndt = 0.0\n", "physics.dt: must be > 0, got 0.0"),
    ("[physics]\ndamping = -0.1\n", "physics.damping: must be >= 0, got -0.1"),
    ("[physics]\nsteps = -1\n", "physics.steps: must be >= 0, got -1"),
    ("[physics]\nmass = nan\n", "physics.mass: must be finite, got nan"),
    ("[physics]\nstiffness = inf\n", "physics.stiffness: must be finite, got inf"),
    ("[render.camera]\nelevation = 90\n", "render.camera.elevation: must be in [-89, 89], got 90"),
    ("[render.camera]\nfov = 179\n", "render.camera.fov: must be in (0, 179), got 179"),
    ("[render]\nbackground = [1, 2, 0]\n", "render.background[1]: must be in [0, 1], got 2"),
    ("[render]\nsize = [0, 600]\n", "render.size[0]: must be in [16, 16384], got 0"),
    ("[render]\nsize = [800, 16385]\n", "render.size[1]: must be in [16, 16384], got 16385"),
    ("[render]\nmsaa = 3\n", "render.msaa: must be one of 0, 1, 2, 4, 8, 16, got 3"),
    ("[render.material]\nshininess = 0\n", "render.material.shininess: must be > 0, got 0"),
    ("[render.light]\nambient = 1.5\n", "render.light.ambient: must be in [0, 1], got 1.5"),
    ("[render.light]\ndirection = [0, 0.0, 0]\n", "render.light.direction: must be nonzero, got [0, 0, 0]"),
    ('[render.camera]\nprojection = "fisheye"\n',
     "render.camera.projection: must be one of 'perspective', 'orthographic', got 'fisheye'"),
    # wrong list lengths
    ("[physics]\ngravity = [0, -9.81]\n", "physics.gravity: must have 3 elements, got 2"),
    ("[render]\nsize = [800]\n", "render.size: must have 2 elements, got 1"),
    # grid: exactly one of the two keys
    ("[grid]\nnodes_along_longest = 8\nspacing = 0.1\n",
     "grid: set exactly one of 'nodes_along_longest' or 'spacing', not both"),
    ("[grid]\n", "grid: set exactly one of 'nodes_along_longest' or 'spacing'"),
    ("[grid]\nnodes_along_longest = 1\n", "grid.nodes_along_longest: must be >= 2, got 1"),
    # regions
    ('[[physics.fixed]]\nregion = "below"\naxis = "y"\nat = 0.1\n[[physics.fixed]]\nregion = "above"\n'
     'axis = "w"\nat = 0.9\n', "physics.fixed[1].axis: must be one of 'x', 'y', 'z', got 'w'"),
    ('[[physics.fixed]]\nregion = "sphere"\n',
     "physics.fixed[0].region: must be one of 'below', 'above', 'box', got 'sphere'"),
    ('[[physics.fixed]]\naxis = "y"\nat = 0.1\n', "physics.fixed[0].region: required key is missing"),
    ('[[physics.fixed]]\nregion = "below"\naxis = "y"\n', "physics.fixed[0].at: required for region 'below'"),
    ('[[physics.fixed]]\nregion = "box"\nmin = [0, 0, 0]\n', "physics.fixed[0].max: required for region 'box'"),
    ('[[physics.fixed]]\nregion = "below"\naxis = "y"\nat = 0.1\nmin = [0, 0, 0]\n',
     "physics.fixed[0].min: not used by region 'below'"),
    ('[[physics.fixed]]\nregion = "box"\nmin = [0, 0.5, 0]\nmax = [1, 0.1, 1]\n',
     "physics.fixed[0].max: must be >= min componentwise, got max[1] 0.1 < min[1] 0.5"),
    # pulls
    ('[[physics.pull]]\nregion = "above"\naxis = "y"\nat = 0.8\n', "physics.pull[0].force: required key is missing"),
    ('[[physics.pull]]\nregion = "above"\naxis = "y"\nat = 0.8\nforce = [1, 0, 0]\nstart = 1\nstop = 0.5\n',
     "physics.pull[0].stop: must be > start (1), got 0.5"),
    ('[[physics.pull]]\nregion = "above"\naxis = "y"\nat = 0.8\nforce = [1, 0, 0]\nramp = -1\n',
     "physics.pull[0].ramp: must be >= 0, got -1"),
    ('[[physics.pull]]\nregion = "above"\naxis = "y"\nat = 0.8\nforce = [1, 0, 0]\n' * 5,
     "physics.pull: at most 4 entries are allowed, got 5"),
    # the documented ranges (docs/SCENE_LIMITS.md)
    ("[physics]\ndt = 2\n", "physics.dt: must be in [1e-09, 1] s, got 2"),
    ("[physics]\ndamping = 1e308\n", "physics.damping: must be in [0, 1e+06] N*s/m, got 1e+308"),
    ("[physics]\nsteps = 100000001\n", "physics.steps: must be in [0, 1e+08], got 100000001"),
    ("[render.camera]\ndistance = 1e17\n", "render.camera.distance: must be in [0.001, 1000] box diagonals, got 1e+17"),
    ("[render.light]\ndirection = [1e-7, 0, 0]\n", "render.light.direction: length must be in (1e-06, 1e+06), got 1e-07"),
    ("[render.light]\ndirection = [1e200, 1, 0.7]\n", "render.light.direction[0]: must be in [-1e+06, 1e+06], got 1e+200"),
    ("[physics]\nmass = 1" + "0" * 400 + "\n", "physics.mass: is far out of range, got 100000...(401 digits)"),
    # output
    ('[output]\npath = "out.jpg"\n', "output.path: must end in .png (.gif, .webp or .mp4: an animation), got 'out.jpg'"),
    ('[output]\npath = ".png"\n', "output.path: must end in .png (.gif, .webp or .mp4: an animation), got '.png'"),
])
def test_errors_name_file_and_key(scene_dir: Path, text: str, message: str) -> None:
    assert _error(MESH + text) == f"jelly.toml: {message}"


def test_four_pulls_are_allowed(scene_dir: Path) -> None:
    pull = '[[physics.pull]]\nregion = "above"\naxis = "y"\nat = 0.8\nforce = [1, 0, 0]\n'
    assert len(_load(MESH + pull * 4).physics.pull) == 4


def test_ints_accepted_where_floats_expected(scene_dir: Path) -> None:
    scene = _load(MESH + "[physics]\ndt = 1\ngravity = [0, -10, 0]\n")
    assert scene.physics.dt == 1.0 and type(scene.physics.dt) is float
    assert all(type(g) is float for g in scene.physics.gravity)


def test_mesh_errors(scene_dir: Path) -> None:
    assert _error("[physics]\ndt = 0.1\n") == (
        "jelly.toml: mesh: set exactly one of [mesh] (a mesh to deform) or [cloth] (a cloth sheet)")
    assert _error('mesh = "m.ply"\n') == "jelly.toml: mesh: must be a table, got string 'm.ply'"
    missing = scene_dir / "assets" / "nope.ply"
    assert _error('[mesh]\npath = "assets/nope.ply"\n') == f"jelly.toml: mesh.path: file not found: {missing}"
    assert _error('[mesh]\npath = "assets"\n') == f"jelly.toml: mesh.path: not a file: {scene_dir / 'assets'}"


def test_toml_syntax_error_has_line_and_column(scene_dir: Path) -> None:
    message = _error(MESH + "[physics]\ndt = \n")
    assert message.startswith("jelly.toml: line 4, column 6: invalid TOML: ")
    assert _error(MESH + "[physics]\ngravity = [1,").startswith("jelly.toml: end of document: invalid TOML: ")


def test_missing_and_unreadable_scene_file(scene_dir: Path) -> None:
    with pytest.raises(SceneError, match=r"^nope\.toml: cannot read scene file: file not found$"):
        load_scene("nope.toml")
    with pytest.raises(SceneError, match=r"^assets: cannot read scene file: "):
        load_scene("assets")
    Path("bad.toml").write_bytes(b'x = "\xff"\n')
    with pytest.raises(SceneError, match=r"^bad\.toml: invalid TOML: not UTF-8"):
        load_scene("bad.toml")


def test_region_contains() -> None:
    points = np.array([[0.0, 0.1, 0.5], [0.5, 0.1000001, 0.5], [1.0, 0.9, 1.0], [0.2, -0.5, 2.0]])
    below = Region("below", 1, 0.1, None, None)
    above = Region("above", 2, 1.0, None, None)
    box = Region("box", None, None, (0.0, 0.1, 0.5), (0.5, 0.9, 1.0))
    np.testing.assert_array_equal(below.contains(points), [True, False, False, True])
    np.testing.assert_array_equal(above.contains(points), [False, False, True, True])
    np.testing.assert_array_equal(box.contains(points), [True, True, False, False])
    assert below.contains(points.astype(np.float32)).dtype == np.bool_
    assert below.contains(np.zeros((0, 3))).shape == (0,)
    with pytest.raises(ValueError, match=r"shape \(N, 3\)"):
        below.contains(np.zeros((4, 2)))


def test_region_axis_from_scene(scene_dir: Path) -> None:
    scene = _load(MESH + '[[physics.fixed]]\nregion = "above"\naxis = "x"\nat = 0.5\n')
    (region,) = scene.physics.fixed
    assert region.axis == 0
    np.testing.assert_array_equal(region.contains(np.array([[0.6, 0, 0], [0.4, 1, 1]])), [True, False])


def test_pull_force_at() -> None:
    region = Region("below", 1, 0.5, None, None)
    pull = Pull(region, (2.0, 0.0, -4.0), start=1.0, ramp=2.0, stop=5.0)
    for t, scale in [(0.0, 0.0), (1.0, 0.0), (2.0, 0.5), (2.5, 0.75), (3.0, 1.0), (4.99, 1.0), (5.0, 0.0),
                     (9.0, 0.0)]:
        np.testing.assert_allclose(pull.force_at(t), np.array([2.0, 0.0, -4.0]) * scale, err_msg=f"t={t}")
    assert pull.force_at(2.0).shape == (3,)
    instant = Pull(region, (1.0, 1.0, 1.0), start=0.5, ramp=0.0, stop=math.inf)
    np.testing.assert_array_equal(instant.force_at(0.49), [0.0, 0.0, 0.0])
    np.testing.assert_array_equal(instant.force_at(0.5), [1.0, 1.0, 1.0])
    np.testing.assert_array_equal(instant.force_at(1e12), [1.0, 1.0, 1.0])


def test_with_overrides(scene_dir: Path) -> None:
    scene = _load(MESH)
    (scene_dir / "other.obj").write_text("v 0 0 0\n")
    changed = scene.with_overrides(mesh=Path("other.obj"), steps=7, size=(320, 200))
    assert changed.mesh.path == scene_dir / "other.obj"
    assert changed.physics.steps == 7 and changed.render.size == (320, 200)
    assert changed.physics.dt == scene.physics.dt and changed.render.camera == scene.render.camera
    assert scene.physics.steps == 400 and scene.render.size == (800, 600)
    assert scene.with_overrides() == scene
    assert scene.with_overrides(steps=0).physics.steps == 0


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"steps": -1}, "--steps: must be >= 0, got -1"),
    ({"steps": True}, "--steps: must be an integer, got boolean true"),
    ({"steps": 2.0}, "--steps: must be an integer, got float 2.0"),
    ({"size": (0, 600)}, "--size[0]: must be in [16, 16384], got 0"),
    ({"size": (800,)}, "--size: must have 2 elements, got 1"),
])
def test_with_overrides_errors(scene_dir: Path, kwargs: dict[str, object], message: str) -> None:
    scene = _load(MESH)
    with pytest.raises(SceneError) as info:
        scene.with_overrides(**kwargs)  # type: ignore[arg-type]
    assert str(info.value) == f"{scene.source}: {message}"


def test_with_overrides_missing_mesh(scene_dir: Path) -> None:
    scene = _load(MESH)
    with pytest.raises(SceneError) as info:
        scene.with_overrides(mesh=Path("gone.ply"))
    assert str(info.value) == f"{scene.source}: --mesh: file not found: {scene_dir / 'gone.ply'}"


def test_parse_size() -> None:
    assert parse_size("800x600") == (800, 600)
    assert parse_size(" 16X16384 ") == (16, 16384)
    for bad in ["800", "800x", "x600", "800x600x2", "abc", "-1x5", "8.5x6", ""]:
        with pytest.raises(ValueError, match="expected WIDTHxHEIGHT"):
            parse_size(bad)
    for bad in ["0x600", "15x600", "800x16385"]:
        with pytest.raises(ValueError, match="must each be in 16..16384"):
            parse_size(bad)


@pytest.mark.parametrize("text, key, what", [
    ('[mapping]\nmode = "smooth"\n', "mapping.mode", "must be one of"),
    ('[mapping]\nnormal_map = "missing.png"\n', "mapping.normal_map", "file not found"),
    ('[nodes]\nsource = "file"\n', "nodes.file", "required for source 'file'"),
    ('[nodes]\nsource = "motion"\n', "nodes.motion", "required for source 'motion'"),
    ('[nodes]\nfile = "x.npy"\n', "nodes.file", "not used by source 'simulate'"),
    ('[nodes]\nsource = "motion"\n[nodes.motion]\nkind = "bend"\nalong = "y"\n', "nodes.motion.towards", "must differ"),
    ('[nodes]\nsource = "motion"\n[nodes.motion]\nkind = "wobble"\n', "nodes.motion.kind", "must be one of"),
])
def test_mapping_and_nodes_errors(scene_dir: Path, text: str, key: str, what: str) -> None:
    path = scene_dir / "bad.toml"
    path.write_text('[mesh]\npath = "assets/m.ply.gz"\n' + text)
    with pytest.raises(SceneError) as err:
        load_scene(path)
    assert f"bad.toml: {key}: " in str(err.value) and what in str(err.value)


def test_mapping_override(scene_dir: Path) -> None:
    scene = _load(FULL)
    assert scene.with_overrides(mapping="auto").mapping.mode == "auto"
    with pytest.raises(SceneError, match="--mapping: must be one of"):
        scene.with_overrides(mapping="jagged")


EXTENDED_PHYSICS = MESH + """
[physics]
integrator = "rk4"
backend = "feedback"
wind = [1.0, 0.0, 0.0]
wind_drag = 0.1

[physics.springs]
structural = { damping = 0.2 }
flexion = { stiffness = 30.0 }

[physics.ground]
at = 0.1

[[physics.sphere]]
path = [[0.5, 0.2, 0.5], [0.5, 0.4, 0.5]]
times = [0.0, 1.0]
radius = 0.25

[[physics.drag]]
path = [[1.0, 1.0, 1.0]]
stiffness = 40.0

[physics.converge]
every = 5
"""


def test_extended_physics_round_trips(scene_dir: Path) -> None:
    p = _load(EXTENDED_PHYSICS).physics
    assert (p.integrator, p.backend, p.wind, p.wind_drag, p.ground) == ("rk4", "feedback", (1.0, 0.0, 0.0), 0.1, 0.1)
    assert p.class_stiffness() == (500.0, 500.0, 30.0) and p.structural.damping == 0.2
    np.testing.assert_allclose(p.sphere[0].path.at(0.5), [0.5, 0.3, 0.5])
    np.testing.assert_allclose(p.sphere[0].path.at(7.0), [0.5, 0.4, 0.5])
    assert p.drag[0].path.times == (0.0,) and p.drag[0].stiffness == 40.0
    assert p.converge == Converge("equilibrium", every=5)


@pytest.mark.parametrize("table, expected", [
    ("", Converge()),
    ('criterion = "displacement"\nthreshold = 0.002', Converge("displacement", threshold=0.002)),
    ("threshold = 0.002\nevery = 5", Converge("displacement", threshold=0.002, every=5)),  # an older table
    ("tolerance = 0.005\ninterval = 0.05\nchecks = 4", Converge(tolerance=0.005, interval=0.05, checks=4)),
])
def test_the_convergence_table(scene_dir: Path, table: str, expected: Converge) -> None:
    assert _load(MESH + "[physics.converge]\n" + table + "\n").physics.converge == expected


@pytest.mark.parametrize("table, message", [
    ('criterion = "equilibrium"\nthreshold = 0.002', 'physics.converge.threshold: only used with criterion = '
                                                      '"displacement" (the criterion is \'equilibrium\')'),
    ('criterion = "displacement"\ntolerance = 0.1', 'physics.converge.tolerance: only used with criterion = '
                                                     '"equilibrium" (the criterion is \'displacement\')'),
    ("interval = 0.1\nevery = 3", "physics.converge.every: give either 'every' (steps) or 'interval'"),
    ('criterion = "still"', "physics.converge.criterion: must be one of"),
    ("tolerance = 0", "physics.converge.tolerance: must be > 0"),
])
def test_convergence_table_errors_name_the_key(scene_dir: Path, table: str, message: str) -> None:
    assert _error(MESH + "[physics.converge]\n" + table + "\n").startswith(f"jelly.toml: {message}")


@pytest.mark.parametrize("old, new, message", [
    ('integrator = "rk4"', 'integrator = "leapfrog"', "physics.integrator: must be one of"),
    ('backend = "feedback"', 'backend = "cuda"', "physics.backend: must be one of"),
    ("times = [0.0, 1.0]", "times = [1.0, 0.5]", "physics.sphere[0].times: must increase, got 0.5 after 1"),
    ("times = [0.0, 1.0]", "times = [0.0]", "physics.sphere[0].times: must have one time per point (2), got 1"),
    ("path = [[0.5, 0.2, 0.5], [0.5, 0.4, 0.5]]", "path = [[0.5, 0.2, 0.5], [0.5, 0.4, 0.5]]\ncentre = [0, 0, 0]",
     "physics.sphere[0]: set exactly one of 'centre' (a fixed sphere) or 'path' (a moving one)"),
    ("stiffness = 40.0", "stiffness = -1.0", "physics.drag[0].stiffness: must be > 0, got -1.0"),
    ("flexion = { stiffness = 30.0 }", "flexion = { stifness = 30.0 }",
     "physics.springs.flexion.stifness: unknown key (did you mean 'stiffness'?)"),
    ("every = 5", "every = 0", "physics.converge.every: must be >= 1, got 0"),
])
def test_extended_physics_errors_name_the_key(scene_dir: Path, old: str, new: str, message: str) -> None:
    assert old in EXTENDED_PHYSICS
    assert _error(EXTENDED_PHYSICS.replace(old, new)).startswith(f"jelly.toml: {message}")


def test_cloth_scene_rules(scene_dir: Path) -> None:
    scene = _load('[cloth]\nnodes = [8, 6]\nsize = 2.0\n')
    assert scene.cloth == ClothSpec((8, 6), 2.0) and scene.mesh is None and scene.name == "cloth 8x6"
    assert _error('[cloth]\nnodes = [8, 6]\n[grid]\nspacing = 0.1\n') == \
        "jelly.toml: grid: a cloth scene sets its nodes in cloth.nodes"
    assert _error(MESH + '[cloth]\nnodes = [8, 6]\n') == \
        "jelly.toml: mesh: set exactly one of [mesh] (a mesh to deform) or [cloth] (a cloth sheet)"
    assert _error('[cloth]\nnodes = [8, 6]\n[mapping]\nmode = "constant"\n') == \
        "jelly.toml: mapping.mode: a cloth scene has no detailed mesh: only one-to-one"
    assert _error('[cloth]\nnodes = [1, 6]\n') == "jelly.toml: cloth.nodes[0]: must be in [2, 16384], got 1"
    with pytest.raises(SceneError, match="--mesh: a cloth scene has no mesh to replace"):
        scene.with_overrides(mesh=Path("x.ply"))
    with pytest.raises(SceneError, match="--backend: must be one of"):
        scene.with_overrides(backend="gpu")
    assert scene.with_overrides(integrator="midpoint", backend="numpy").physics.backend == "numpy"


def test_schema_keeps_every_name_after_its_split():
    """scene.schema is the loader; the dataclasses (scene.spec) and the checkers (scene.checks)
    are importable from their own modules (schema no longer re-exports them: issue 43)."""
    import deformgl.scene.checks as checks
    import deformgl.scene.schema as schema
    import deformgl.scene.spec as spec

    before = ["Animation", "BACKENDS", "CameraKey", "apply_overrides", "Camera", "ClothSpec", "Converge", "DragSpec",
              "GridSpec", "Keyframes", "Light", "Safety", "UNSTABLE_POLICIES", "Material", "MeshSpec", "Output",
              "Physics", "Pull", "Region", "Render", "Scene", "SphereSpec", "SpringClass", "load_scene", "parse_size"]
    for name in before + ["AXES", "MAPPING_MODES", "MAX_SIZE", "Attach", "Mapping", "MotionSpec", "Nodes", "Vec3",
                          "REQUIRED"]:
        assert any(hasattr(module, name) for module in (schema, spec, checks)), name
    assert schema.Scene is spec.Scene and schema.REQUIRED is checks.REQUIRED
