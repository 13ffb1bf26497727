"""The command line: render to PNG, overrides, info, help, and bad input (one-line errors, no PNG)."""

import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from deformgl.cli import main
from deformgl.files import read_png

SCENES = Path(__file__).resolve().parent.parent / "scenes"


@pytest.fixture
def jelly(tmp_path):
    """A copy of the jelly scene and its mesh in tmp_path."""
    (tmp_path / "assets").mkdir()
    shutil.copy(SCENES / "assets" / "jelly_block.obj", tmp_path / "assets")
    scene = tmp_path / "jelly.toml"
    scene.write_text((SCENES / "jelly_springs.toml").read_text())
    return scene


def run_cli(capsys, *args):
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_render_writes_png_of_the_scene_size(ctx, jelly, tmp_path, capsys):
    out = tmp_path / "out.png"
    code, stdout, err = run_cli(capsys, "render", jelly, "-o", out, "--steps", "20", "--quiet")
    assert code == 0, err
    img = read_png(out)
    assert img.shape == (240, 320, 3)
    background = np.array([0.96, 0.96, 0.94]) * 255
    object_pixels = np.any(np.abs(img.astype(float) - background) > 10, axis=2).mean()
    assert 0.1 < object_pixels < 0.9
    assert not list(tmp_path.glob("*.tmp")) and not list(tmp_path.glob(".*tmp"))


def test_size_steps_and_mesh_overrides(ctx, jelly, tmp_path, capsys):
    box = tmp_path / "tall_box.stl"
    trimesh.creation.box(extents=[0.02, 0.1, 0.02]).export(box)
    out = tmp_path / "box.png"
    code, _, err = run_cli(capsys, "render", jelly, "-o", out, "--steps", "0", "--size", "200x100",
                           "--mesh", box, "--quiet")
    assert code == 0, err
    img = read_png(out)
    assert img.shape == (100, 200, 3)
    # a tall thin box: its image is taller than wide, unlike the jelly block's
    mask = np.any(np.abs(img.astype(int) - img[0, 0].astype(int)) > 10, axis=2)
    rows, cols = np.nonzero(mask)
    assert np.ptp(rows) > np.ptp(cols)


def test_default_output_path_from_scene(ctx, jelly, capsys):
    code, stdout, err = run_cli(capsys, "render", jelly, "--steps", "1", "--quiet")
    assert code == 0, err
    assert (jelly.parent / "jelly.png").is_file()
    assert "wrote" in stdout


def write_obj(path, vertices, faces):
    lines = [f"v {x} {y} {z}" for x, y, z in vertices] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("case", ["missing", "empty", "nan", "thin", "too_large", "dt", "typo", "size"])
def test_bad_input_gives_one_line_error_and_no_png(ctx, jelly, tmp_path, capsys, case):
    out = tmp_path / "bad.png"
    extra = []
    if case == "missing":
        extra = ["--mesh", tmp_path / "nope.ply"]
        expect = "nope.ply"
    elif case == "empty":
        (tmp_path / "empty.obj").write_text("")
        extra = ["--mesh", tmp_path / "empty.obj"]
        expect = "empty.obj"
    elif case == "nan":
        box = trimesh.creation.box()
        v = box.vertices.copy()
        v[3, 1] = np.nan
        write_obj(tmp_path / "nan.obj", v, box.faces)
        extra = ["--mesh", tmp_path / "nan.obj"]
        expect = "vertex 3"
    elif case == "thin":
        # a thin rod: at the scene's 9 nodes along its length it is a single row of nodes
        rod = trimesh.creation.box(extents=[0.1, 0.001, 0.001])
        rod.export(tmp_path / "rod.stl")
        extra = ["--mesh", tmp_path / "rod.stl"]
        expect = "too thin"
    elif case == "too_large":
        jelly.write_text(jelly.read_text().replace("nodes_along_longest = 9", "nodes_along_longest = 20000"))
        expect = "grid"
    elif case == "dt":
        jelly.write_text(jelly.read_text().replace("dt = 0.0005", "dt = -1"))
        expect = "physics.dt: must be > 0, got -1"
    elif case == "typo":
        jelly.write_text(jelly.read_text().replace("stiffness =", "stifness ="))
        expect = "physics.stifness: unknown key (did you mean 'stiffness'?)"
    else:
        extra = ["--size", "640by480"]
        expect = "--size"
    code, stdout, err = run_cli(capsys, "render", jelly, "-o", out, "--quiet", *extra)
    assert code != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("deformgl: error: ")
    assert expect in lines[0]
    assert "Traceback" not in err
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.suffix == ".png" or "tmp" in p.name]


def test_texture_limit_error_names_scene_key(jelly):
    from deformgl.errors import InputError
    from deformgl.scene.pipeline import build_scene_model, check_texture_limit
    from deformgl.scene.schema import load_scene

    scene = load_scene(jelly)
    built = build_scene_model(scene)
    with pytest.raises(InputError, match=r"jelly.toml: grid.nodes_along_longest: .*texture limit"):
        check_texture_limit(scene, built.grid, max_size=16)  # 378 nodes need 16 x 24 texels
    check_texture_limit(scene, built.grid, max_size=16384)


def test_unstable_dt_is_refused_run_anyway_or_subdivided_and_a_blow_up_writes_no_png(ctx, jelly, tmp_path, capsys):
    jelly.write_text(jelly.read_text().replace("dt = 0.0005", "dt = 0.05"))
    out = tmp_path / "nan.png"
    code, _, err = run_cli(capsys, "render", jelly, "-o", out, "--quiet")
    assert code == 2 and not out.exists()  # the scene's dt: an input error, refused before any work
    assert re.search(r"jelly.toml: physics.dt: dt 0.05 s is above the verlet limit [0-9.e-]+ s, w = [0-9.e+]+ rad/s "
                     r"at node \d+ \(spring \d+, k = 6 N/m, m = 0.0005 kg; lanczos bound\).*--allow-unstable", err), err
    assert len(err.strip().replace(str(jelly), "")) < 300, err  # a line a person reads (it was about 500 characters)
    code, _, err = run_cli(capsys, "render", jelly, "-o", out, "--quiet", "--allow-unstable", "--check-every", "20")
    assert code == 1 and not out.exists()
    assert re.search(r"blew up: at step 20 \(dt 0.05 s\) \d+ node\(s\) are non-finite or beyond .* first node "
                     r"\d+ \(grid \(\d+, \d+, \d+\)\) at", err), err
    jelly.write_text(jelly.read_text().replace("dt = 0.05", "dt = 0.2"))
    code, _, err = run_cli(capsys, "render", jelly, "-o", out, "--quiet", "--subdivide")
    assert code == 2 and not out.exists() and "more than --subdivide's 16" in err, err
    jelly.write_text(jelly.read_text().replace("dt = 0.2", "dt = 0.008"))
    code, _, err = run_cli(capsys, "render", jelly, "-o", out, "--subdivide", "--steps", "40")
    assert code == 0 and out.exists(), err
    assert re.search(r"above the verlet limit [0-9.e-]+ s: 2 substeps of 0.004 s per step", err), err
    with pytest.raises(SystemExit):
        run_cli(capsys, "render", jelly, "--allow-unstable", "--subdivide")


def test_info_and_help_from_the_console_script():
    exe = shutil.which("deformgl") or None
    cmd = [exe] if exe else [sys.executable, "-m", "deformgl"]
    info = subprocess.run(cmd + ["info"], capture_output=True, text=True, timeout=60)
    assert info.returncode == 0, info.stderr
    assert "renderer: " in info.stdout and "RGBA32F render targets: yes" in info.stdout
    for sub in ([], ["render"], ["info"], ["bench"]):
        h = subprocess.run(cmd + sub + ["--help"], capture_output=True, text=True, timeout=60)
        assert h.returncode == 0 and "usage: deformgl" in h.stdout


def test_trilinear_command_writes_png_and_rejects_bad_size(ctx, tmp_path, capsys):
    out = tmp_path / "tubes.png"
    code, _, err = run_cli(capsys, "trilinear", "tubes", "-o", out, "--size", "160x80")
    assert code == 0, err
    assert read_png(out).shape == (80, 160, 3)
    code, _, err = run_cli(capsys, "trilinear", "tile", "-o", tmp_path / "t.png", "--size", "big")
    assert code == 2 and "--size" in err and not (tmp_path / "t.png").exists()


def test_pack_inputs_and_export_are_checked_before_work_and_not_private(ctx, tmp_path, capsys):
    scene = SCENES / "dragon_bend_auto.toml"
    code, _, err = run_cli(capsys, "render", scene, "-o", tmp_path / "a.png", "--pack-inputs",
                           tmp_path / "missing" / "p.npz", "--quiet")
    assert code == 2 and "does not exist" in err and not (tmp_path / "a.png").exists()
    code, _, err = run_cli(capsys, "render", scene, "-o", tmp_path / "a.png", "--pack-inputs",
                           tmp_path / "p.txt", "--quiet")
    assert code == 2 and "must end in .npz" in err
    code, _, err = run_cli(capsys, "render", scene, "-o", tmp_path / "a.png", "--size", "64x48",
                           "--export-mesh", tmp_path / "m.ply", "--pack-inputs", tmp_path / "p.npz", "--quiet")
    assert code == 0, err
    for name in ("a.png", "m.ply", "p.npz"):
        mode = (tmp_path / name).stat().st_mode & 0o777
        assert mode & 0o044, f"{name} is private ({oct(mode)}): written like any new file"


def test_msaa_beyond_the_renderer_is_an_early_scene_error(ctx, jelly, tmp_path, capsys):
    jelly.write_text(jelly.read_text().replace("msaa = 4", "msaa = 16"))
    code, _, err = run_cli(capsys, "render", jelly, "-o", tmp_path / "x.png", "--quiet")
    max_samples = int(ctx.info.get("GL_MAX_SAMPLES", 1))
    if max_samples >= 16:
        pytest.skip(f"this renderer supports {max_samples}x MSAA")
    assert code == 2 and "render.msaa: 16x is more than this renderer's" in err


def test_bench_rejects_zero_steps(capsys):
    code, _, err = run_cli(capsys, "bench", "sim", "--steps", "0")
    assert code == 2 and "--steps: must be >= 1" in err


def test_a_scene_not_in_the_working_folder_is_the_shipped_one(ctx, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    for given in ("jelly.toml", "scenes/jelly.toml", "jelly"):
        code, stdout, err = run_cli(capsys, "render", given, "--steps", "2", "--size", "32x24", "--quiet")
        assert code == 0, err
        # a shipped scene writes into the working folder, never into the package
        assert read_png(tmp_path / "jelly.png").shape == (24, 32, 3)
        (tmp_path / "jelly.png").unlink()
    assert not (SCENES / "jelly.png").exists()


def test_a_scene_found_nowhere_is_a_one_line_error(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    for given in ("nope.toml", "some/where/dragon.toml"):
        code, stdout, err = run_cli(capsys, "render", given)
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1, err
        assert f"{given}: scene file not found" in lines[0] and "dragon.toml" in lines[0]
    from studies.common import run_main
    from studies.render_speed import main as render_speed

    with pytest.raises(SystemExit) as done:  # (the study that was `deformgl bench render`)
        run_main(lambda argv: render_speed(["--scene", "nope.toml"]))
    code, err = done.value.code, capsys.readouterr().err
    assert code == 2 and "--scene: scene file not found" in err


def test_shipped_scenes_and_assets_are_the_repository_ones():
    from deformgl import data

    # the checkout's folder in an editable install, a copy in site-packages otherwise (CI)
    assert set(data.scene_names()) == {p.name for p in SCENES.glob("*.toml")}
    assert {p.name for p in (data.scenes_dir() / "assets").iterdir()} >= {p.name for p in (SCENES / "assets").iterdir()}
    assert data.asset("dragon_vrip_res3.ply.gz").is_file()
    found = data.find_scene("scenes/dragon_heart_scale.toml")
    assert found.name == "dragon_heart_scale.toml" and found.is_file()
    assert data.is_packaged(data.packaged_scene("dragon_heart_scale")) and not data.is_packaged(Path("elsewhere.toml"))
    with pytest.raises(data.DeformglError, match=r"no packaged scene .*there are: .*dragon.toml"):
        data.packaged_scene("nope")


# -- issue 42, defect 7: messages that point the right way -----------------------------------


@pytest.mark.parametrize("out, message", [
    ("afile/out.png", "afile/out.png: afile is a file, not a folder: the output cannot be written inside it"),
    ("afile/sub/out.png", "afile/sub/out.png: afile is a file, not a folder: the output cannot be written inside it"),
    ("nodir/out.png", "nodir/out.png: the output folder nodir does not exist"),
])
def test_an_output_inside_a_regular_file_says_so(jelly, tmp_path, monkeypatch, capsys, out, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("not a folder")
    code, _, err = run_cli(capsys, "render", jelly, "-o", out, "--quiet")
    assert code == 2 and err.strip() == f"deformgl: error: {message}", err


def test_an_output_in_a_system_folder_says_no_file_can_be_created_there(jelly, capsys):
    code, _, err = run_cli(capsys, "render", jelly, "-o", "/proc/out.png", "--quiet")
    assert code == 2 and err.count("\n") == 1
    assert "/proc/out.png: cannot write the output into /proc: no file can be created there (" in err, err


@pytest.mark.parametrize("flag, message", [
    ("physics.dtt=1e-3", "--set physics.dtt=1e-3: unknown key 'dtt' (did you mean 'dt'?)"),
    ("physics.dt=-1", "--set physics.dt=-1: must be > 0, got -1"),
    ("render.size=[0,1]", "--set render.size=[0,1]: render.size[0]: must be in [16, 16384], got 0"),
    ("physics=3", "--set physics=3: must be a table, got integer 3"),
    ("physics.fixed.7.at=1", "--set physics.fixed.7.at=1: physics.fixed.7: no entry 7 (the array has 1)"),
])
def test_a_bad_set_key_blames_the_set_flag_not_the_scene_file(jelly, capsys, flag, message):
    code, _, err = run_cli(capsys, "render", jelly, "--set", flag, "--quiet")
    assert code == 2 and err.strip() == f"deformgl: error: {message}", err


def test_a_bad_scene_key_still_blames_the_scene_file(jelly, capsys):
    jelly.write_text(jelly.read_text().replace("[physics]", "[physics]\ndtt = 1e-3", 1))
    code, _, err = run_cli(capsys, "render", jelly, "--set", "physics.steps=3", "--quiet")
    assert code == 2 and err.strip() == f"deformgl: error: {jelly}: physics.dtt: unknown key (did you mean 'dt'?)"


def test_help_names_every_output_format_and_every_peer():
    from deformgl.bench.peers import PEERS
    from deformgl.cli import _parser

    parser = _parser()
    top = parser.format_help()
    render = next(a for a in parser._subparsers._group_actions[0].choices.items() if a[0] == "render")[1]
    text = " ".join(render.format_help().split())
    summary = " ".join(top.split())
    for fmt in ("PNG", "GIF", "WebP", "MP4", "PNG frames"):
        assert fmt in summary.split("render", 1)[1].split("sweep")[0], f"render's summary leaves out {fmt}"
        assert fmt in text.split("-o OUTPUT, --output OUTPUT", 1)[1].split("--steps")[0], f"-o leaves out {fmt}"
    bench = parser._subparsers._group_actions[0].choices["bench"]
    peers = " ".join(bench.format_help().split()).split("--peers", 2)[2].split("--blocks")[0].lower()
    for peer in PEERS:
        assert peer in peers, f"bench --peers leaves out {peer}"


def test_the_readme_first_command_output_is_ignored_by_git():
    root = SCENES.parent
    first = next(line for line in (root / "README.md").read_text().splitlines() if "deformgl render" in line
                 and line.lstrip().startswith("python3 -m venv"))
    written = first.split(" -o ", 1)[1].split()[0]
    ignored = (root / ".gitignore").read_text().splitlines()
    assert f"/{written}" in ignored or written in ignored, f"{written} (the README's first command) is not in .gitignore"


def test_a_toml_syntax_error_is_reported_before_the_heavy_imports(tmp_path):
    """The scene's TOML is parsed before NumPy, moderngl and trimesh are imported (about 0.1 s
    instead of 1 s), with load_scene's message."""
    bad = tmp_path / "bad.toml"
    bad.write_text("[physics\ndt = 1\n")
    code = ("import sys\nfrom deformgl.cli import main\nrc = main(['render', sys.argv[1], '--quiet'])\n"
            "print(rc, sorted(m for m in ('numpy', 'moderngl', 'trimesh') if m in sys.modules))")
    done = subprocess.run([sys.executable, "-c", code, str(bad)], capture_output=True, text=True, timeout=120)
    assert done.stdout.split("\n")[0] == "2 []", done.stdout + done.stderr
    from deformgl.errors import SceneError
    from deformgl.scene.schema import load_scene

    with pytest.raises(SceneError) as info:
        load_scene(bad)
    assert done.stderr.strip() == f"deformgl: error: {info.value}"


def test_a_mesh_not_in_the_working_folder_is_the_shipped_one(ctx, tmp_path, monkeypatch, capsys):
    """--mesh takes a shipped mesh by name, as the API's Body.from_mesh does (deformgl.data.find_mesh)."""
    monkeypatch.chdir(tmp_path)
    code, _, err = run_cli(capsys, "render", "jelly_springs.toml", "--mesh", "jelly_block.obj", "-o", "bar.png",
                           "--steps", "2", "--size", "64x48", "--quiet")
    assert code == 0, err
    code, _, err = run_cli(capsys, "render", "jelly_springs.toml", "--mesh", "no_such_mesh.obj", "-o", "x.png",
                           "--quiet")
    assert code == 2 and "no_such_mesh.obj" in err and not (tmp_path / "x.png").exists()
