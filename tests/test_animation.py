"""Animations from one run, camera paths and views, comparison grids, the run summary and record,
scene-key overrides (deformgl.scene.animation, deformgl.scene.outputs, deformgl.render.video)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, ImageSequence

from deformgl.cli import main
from deformgl.errors import InputError, SceneError
from deformgl.files import read_png

SCENES = Path(__file__).resolve().parents[1] / "scenes"


@pytest.fixture
def jelly(tmp_path):
    """A copy of the jelly scene (small: 160x120, 120 steps) and its mesh in tmp_path."""
    (tmp_path / "assets").mkdir()
    shutil.copy(SCENES / "assets" / "jelly_block.obj", tmp_path / "assets")
    scene = tmp_path / "jelly.toml"
    text = (SCENES / "jelly_springs.toml").read_text().replace("steps = 300", "steps = 120")
    scene.write_text(text.replace("size = [320, 240]", "size = [160, 120]"))
    return scene


def cli(capsys, *args):
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def gif_frames(path):
    with Image.open(path) as im:
        return [np.asarray(f.convert("RGB")) for f in ImageSequence.Iterator(im)], im.info.get("duration")


def no_temporaries(folder: Path) -> bool:
    return not [p for p in folder.rglob("*") if p.name.endswith(".tmp")]


def test_gif_frames_come_from_one_run_and_match_stills_of_the_same_step(ctx, jelly, tmp_path, capsys):
    out = tmp_path / "a.gif"
    code, _, err = cli(capsys, "render", jelly, "-o", out, "--frames", "5", "--fps", "10", "--steps-per-frame",
                       "30", "--json")
    assert code == 0, err
    frames, duration = gif_frames(out)
    assert len(frames) == 5 and frames[0].shape == (120, 160, 3) and duration == 100
    motion = [np.abs(f.astype(int) - frames[0]).mean() for f in frames]
    assert motion[0] == 0 and all(m > 0.5 for m in motion[1:])  # it moves
    record = json.loads((tmp_path / "a.json").read_text())
    assert record["frames"] == 5 and record["steps"] == 120 and record["steps_per_frame"] == 30
    assert record["node_readbacks"] == 0  # verlet on fragment: drawn from the state texture
    assert record["simulated_time_s"] == pytest.approx(120 * 5e-4)
    # the last frame is the still of the same 120 steps (GIF palettes: within a few levels)
    code, _, err = cli(capsys, "render", jelly, "-o", tmp_path / "still.png", "--steps", "120", "--quiet")
    assert code == 0, err
    still = read_png(tmp_path / "still.png").astype(int)
    assert np.abs(frames[-1].astype(int) - still).mean() < 3.0
    code, _, err = cli(capsys, "render", jelly, "-o", tmp_path / "start.png", "--steps", "0", "--quiet")
    assert np.abs(frames[0].astype(int) - read_png(tmp_path / "start.png")).mean() < 3.0
    assert no_temporaries(tmp_path)


def test_an_animation_reads_no_node_state_between_frames(ctx, jelly, tmp_path, monkeypatch):
    from deformgl.scene.animation import frame_plan, render_frames
    from deformgl.scene.schema import load_scene
    from deformgl.sim.backends.explicit_gpu import FragmentIntegrator

    def refuse(self):
        raise AssertionError("node positions were read back")

    monkeypatch.setattr(FragmentIntegrator, "positions", refuse)
    scene = load_scene(jelly)
    frames = render_frames(ctx, scene, frame_plan(scene, frames=4, steps_per_frame=10))
    assert len(frames.images) == 4 and frames.record["node_readbacks"] == 0
    # an integrator without packed normals reads its positions once per frame, and says so
    monkeypatch.undo()
    rk4 = load_scene(jelly, {"physics.integrator": "rk4", "physics.dt": 2e-4})
    frames = render_frames(ctx, rk4, frame_plan(rk4, frames=4, steps_per_frame=10))
    assert frames.record["node_readbacks"] == 4 and frames.record["integrator"] == "rk4"
    assert np.abs(frames.images[3].astype(int) - frames.images[0]).mean() > 0.3


@pytest.mark.video
def test_mp4_and_png_frames_are_written_whole(ctx, jelly, tmp_path, capsys):
    import imageio_ffmpeg

    out = tmp_path / "a.mp4"
    code, _, err = cli(capsys, "render", jelly, "-o", out, "--frames", "6", "--fps", "12", "--quiet")
    assert code == 0, err
    count, seconds = imageio_ffmpeg.count_frames_and_secs(str(out))
    assert count == 6 and seconds == pytest.approx(0.5, abs=0.1)
    (tmp_path / "frames").mkdir()
    code, _, err = cli(capsys, "render", jelly, "-o", tmp_path / "frames" / "%03d.png", "--frames", "3", "--quiet")
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "frames").iterdir()) == ["000.png", "001.png", "002.png"]
    assert no_temporaries(tmp_path)


def test_mp4_without_the_encoder_is_a_one_line_error_before_any_work(monkeypatch, tmp_path):
    import sys

    from deformgl.render.video import AnimationWriter

    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)
    with pytest.raises(InputError, match=r"a.mp4: writing MP4 needs imageio-ffmpeg .*deformgl\[video\]"):
        AnimationWriter(tmp_path / "a.mp4", 24)
    with AnimationWriter(tmp_path / "a.webp", 10) as w:  # Pillow needs nothing more
        for k in range(3):
            w.write_frame(np.full((8, 10, 3), 80 * k, np.uint8))
    with Image.open(tmp_path / "a.webp") as im:
        assert im.n_frames == 3


def test_a_failed_animation_leaves_no_file(ctx, jelly, tmp_path, capsys):
    out = tmp_path / "a.gif"
    jelly.write_text(jelly.read_text().replace("dt = 0.0005", "dt = 0.2"))
    code, _, err = cli(capsys, "render", jelly, "-o", out, "--frames", "4", "--allow-unstable", "--quiet",
                       "--check-every", "5", "--json")
    assert code == 1 and ("blew up" in err or "non-finite" in err), err
    assert not out.exists() and not (tmp_path / "a.json").exists() and no_temporaries(tmp_path)
    # the writer itself: an exception inside the block leaves nothing
    from deformgl.render.video import AnimationWriter

    with pytest.raises(RuntimeError):
        with AnimationWriter(out, 10) as w:
            w.write_frame(np.zeros((4, 4, 3), np.uint8))
            raise RuntimeError("stop")
    assert not out.exists() and no_temporaries(tmp_path)


def test_export_mesh_sequence_one_file_per_frame(ctx, jelly, tmp_path, capsys):
    import trimesh

    (tmp_path / "m").mkdir()
    code, _, err = cli(capsys, "render", jelly, "-o", tmp_path / "a.gif", "--frames", "3", "--mapping", "constant",
                       "--export-mesh", tmp_path / "m" / "%02d.ply", "--quiet")
    assert code == 0, err
    meshes = [trimesh.load(tmp_path / "m" / f"{k:02d}.ply", process=False) for k in range(3)]
    assert len({len(m.vertices) for m in meshes}) == 1
    assert np.abs(meshes[2].vertices - meshes[0].vertices).max() > 1e-3  # deformed between frames
    code, _, err = cli(capsys, "render", jelly, "-o", tmp_path / "b.gif", "--frames", "3", "--mapping", "constant",
                       "--export-mesh", tmp_path / "one.ply", "--quiet")
    assert code == 2 and "needs a pattern such as meshes/%04d.ply" in err


def test_turntable_and_camera_flag_match_the_still_from_that_camera(ctx, jelly, tmp_path, capsys):
    out = tmp_path / "t.gif"
    code, _, err = cli(capsys, "render", jelly, "-o", out, "--frames", "4", "--steps-per-frame", "0",
                       "--turntable", "360", "--quiet", "--json")
    assert code == 0, err
    frames, _ = gif_frames(out)
    assert json.loads((tmp_path / "t.json").read_text())["steps"] == 120  # physics.steps, once
    assert np.abs(frames[1].astype(int) - frames[0]).mean() > 2  # the camera turned
    # frame 1 of 4 of a 360-degree turntable is the scene's camera 90 degrees on
    from deformgl.scene.schema import load_scene

    cam = load_scene(jelly).render.camera
    view = f"{cam.azimuth + 90:g},{cam.elevation:g},{cam.distance:g}"
    code, _, err = cli(capsys, "render", jelly, "-o", tmp_path / "c.png", "--camera", view, "--quiet")
    assert code == 0, err
    assert np.abs(frames[1].astype(int) - read_png(tmp_path / "c.png")).mean() < 3.0
    code, _, err = cli(capsys, "render", jelly, "-o", tmp_path / "d.png", "--camera", "1,2", "--quiet")
    assert code == 2 and err.startswith("deformgl: error: --camera: expected AZIMUTH,ELEVATION,DISTANCE")


def test_comparison_grid_has_one_panel_per_mode_and_view_from_the_same_state(ctx, jelly, tmp_path, capsys):
    out = tmp_path / "grid.png"
    code, _, err = cli(capsys, "render", jelly, "-o", out, "--compare", "one-to-one,constant,curvature",
                       "--views", "0,15,1.6;90,15,1.6", "--quiet")
    assert code == 0, err
    grid = read_png(out)
    assert grid.shape == (3 * 120 + 2 * 4, 2 * 160 + 4, 3)
    code, _, err = cli(capsys, "render", jelly, "-o", tmp_path / "c.png", "--mapping", "constant",
                       "--camera", "90,15,1.6", "--quiet")
    panel = grid[124:244, 164:324].astype(int)  # row 2 (constant), column 2 (azimuth 90)
    still = read_png(tmp_path / "c.png").astype(int)
    assert np.abs(panel[16:] - still[16:]).max() <= 1  # identical below the label
    one_to_one = grid[124 - 124:120, 164:324].astype(int)
    assert np.abs(one_to_one[16:] - still[16:]).mean() > 1  # a different mapping looks different
    code, _, err = cli(capsys, "render", jelly, "-o", out, "--compare", "one-to-one,bogus", "--quiet")
    assert code == 2 and "'bogus' is not a mapping mode" in err


def test_summary_line_json_record_and_version(ctx, jelly, tmp_path, capsys):
    out = tmp_path / "s.png"
    code, stdout, err = cli(capsys, "render", jelly, "-o", out, "--json", tmp_path / "r.json")
    assert code == 0, err
    line = [ln for ln in err.splitlines() if ln.startswith("deformgl: ")]
    assert len(line) == 1
    assert ("jelly_block.obj: " in line[0] and " nodes, " in line[0] and " springs, verlet on fragment, 120 steps "
            "of dt 0.0005 s (1 substep), 0.06 s simulated, " in line[0] and " s wall" in line[0])
    record = json.loads((tmp_path / "r.json").read_text())
    from deformgl.scene.pipeline import build_scene_model
    from deformgl.scene.schema import load_scene

    built = build_scene_model(load_scene(jelly))
    assert record["nodes"] == built.grid.count and record["springs"] == len(built.system.i)
    assert record["steps"] == 120 and record["dt_s"] == 5e-4 and record["outputs"] == [str(out)]
    assert f"{record['nodes']} nodes, {record['springs']} springs" in line[0]
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == "deformgl 0.1.0"


def test_set_overrides_any_scene_key_and_bad_ones_are_one_line_errors(ctx, jelly, tmp_path, capsys):
    from deformgl.scene.schema import load_scene

    scene = load_scene(jelly, {"physics.integrator": "rk4", "grid.nodes_along_longest": 5,
                               "render.camera.azimuth": 75, "physics.pull.0.force": [0.0, 0.001, 0.0]})
    assert scene.physics.integrator == "rk4" and scene.grid.nodes_along_longest == 5
    assert scene.render.camera.azimuth == 75 and scene.physics.pull[0].force == (0.0, 0.001, 0.0)
    with pytest.raises(SceneError, match=r"jelly.toml: physics.dt: must be > 0, got -1"):
        load_scene(jelly, {"physics.dt": -1})
    with pytest.raises(SceneError, match=r"jelly.toml: physics.stifnes: unknown key \(did you mean 'stiffness'"):
        load_scene(jelly, {"physics.stifnes": 3})
    with pytest.raises(SceneError, match=r"--set physics.pull.5.force: .*no entry 5"):
        load_scene(jelly, {"physics.pull.5.force": [0, 0, 0]})
    out = tmp_path / "o.png"
    code, _, err = cli(capsys, "render", jelly, "-o", out, "--set", "physics.dt=-1", "--quiet")
    assert code == 2 and err == "deformgl: error: --set physics.dt=-1: must be > 0, got -1\n"  # the flag, not the file (issue 42)
    code, _, err = cli(capsys, "render", jelly, "-o", out, "--set", "physics.integrator=midpoint", "--set",
                       "physics.safety.unstable=subdivide", "--json", "--quiet")
    assert code == 0, err
    assert json.loads((tmp_path / "o.json").read_text())["integrator"] == "midpoint"


def test_animation_table_in_a_scene(ctx, jelly, tmp_path, capsys):
    from deformgl.scene.animation import frame_plan
    from deformgl.scene.schema import load_scene

    jelly.write_text(jelly.read_text() + '\n[animation]\nframes = 3\nfps = 5\nseconds_per_frame = 0.01\n'
                     'turntable = 0\n[[animation.camera]]\nat = 0.0\nazimuth = 0\n[[animation.camera]]\nat = 1.0\n'
                     'azimuth = 60\ndistance = 2.0\n')
    scene = load_scene(jelly)
    plan = frame_plan(scene)
    assert plan.frames == 3 and plan.steps_per_frame == 20 and plan.fps == 5
    assert [c.azimuth for c in plan.cameras] == [0, 30, 60]
    assert [c.distance for c in plan.cameras] == [2.0] * 3  # one key: held over the animation
    assert frame_plan(scene, frames=5, steps_per_frame=2).steps == 8  # the flags win
    out = tmp_path / "a.gif"
    code, _, err = cli(capsys, "render", jelly, "-o", out, "--quiet")
    assert code == 0, err
    assert len(gif_frames(out)[0]) == 3
    code, _, err = cli(capsys, "render", jelly, "-o", tmp_path / "still.png", "--quiet")
    assert code == 2 and "3 frames need an animation output" in err
    bad = jelly.read_text().replace("seconds_per_frame = 0.01", "seconds_per_frame = 0.01\nsteps_per_frame = 3")
    jelly.write_text(bad)
    with pytest.raises(SceneError, match=r"animation.seconds_per_frame: set at most one"):
        load_scene(jelly)


def test_bench_animation_reports_the_cost_per_frame_against_a_still(ctx, jelly, capsys):
    from studies.animation_frames import bench_animation

    jelly.write_text(jelly.read_text() + "\n[animation]\nframes = 6\nsteps_per_frame = 20\n")
    report = bench_animation(ctx, jelly)
    lines = report.splitlines()
    assert "renderer: llvmpipe" in lines[0] or "renderer:" in lines[0]
    assert lines[1] == "jelly.toml: 6 frames of 160x120, 20 steps per frame (100 steps)"
    import re

    ms = [float(re.search(r"([0-9.]+) ms", ln)[1]) for ln in lines[2:6]]
    assert all(t > 0 for t in ms)
    ratio = float(re.search(r"= ([0-9.]+) x the still", lines[4])[1])
    assert ratio == pytest.approx(ms[2] / 6 / ms[1], rel=0.02)
    assert float(re.search(r"([0-9.]+) x the animation", lines[5])[1]) == pytest.approx(ms[3] / ms[2], rel=0.05)


def test_python_api_returns_the_frames_as_an_array_and_writes_the_file(ctx, jelly, tmp_path):
    import deformgl as dg

    images, record = dg.render_animation(jelly, tmp_path / "a.gif", frames=3, steps_per_frame=15, ctx=ctx,
                                         overrides={"render.camera.azimuth": 60})
    assert images.shape == (3, 120, 160, 3) and images.dtype == np.uint8
    assert record["steps"] == 30 and record["frames"] == 3 and record["outputs"] == [str(tmp_path / "a.gif")]
    frames, _ = gif_frames(tmp_path / "a.gif")
    assert len(frames) == 3 and np.abs(frames[2].astype(int) - images[2]).mean() < 3.0
    still, _ = dg.render_animation(dg.load_scene(jelly, {"render.camera.azimuth": 60, "physics.steps": 30}),
                                   ctx=ctx)
    assert still.shape == (1, 120, 160, 3)
    assert np.abs(still[0].astype(int) - images[2]).max() <= 1  # the last frame is the still of step 30
    with dg.AnimationWriter(tmp_path / "b.gif", fps=5) as writer:
        for image in images:
            writer.write_frame(image)
    assert len(gif_frames(tmp_path / "b.gif")[0]) == 3


def read_glb(path):
    import struct

    data = path.read_bytes()
    magic, version, length = struct.unpack_from("<III", data)
    assert (magic, version, length) == (0x46546C67, 2, len(data))
    jlen, jtype = struct.unpack_from("<II", data, 12)
    gltf = json.loads(data[20:20 + jlen])
    blen, btype = struct.unpack_from("<II", data, 20 + jlen)
    assert (jtype, btype) == (0x4E4F534A, 0x004E4942)
    binary = data[28 + jlen:28 + jlen + blen]

    def accessor(i):
        a = gltf["accessors"][i]
        view = gltf["bufferViews"][a["bufferView"]]
        dtype = np.float32 if a["componentType"] == 5126 else np.uint32
        width = {"SCALAR": 1, "VEC3": 3}[a["type"]]
        flat = np.frombuffer(binary, dtype, a["count"] * width, view["byteOffset"])
        return flat.reshape(a["count"], width) if width > 1 else flat
    return gltf, accessor


def test_export_mesh_as_one_animated_gltf_with_a_morph_target_per_frame(ctx, jelly, tmp_path, capsys):
    import trimesh

    (tmp_path / "m").mkdir()
    args = ["render", jelly, "--frames", "4", "--steps-per-frame", "25", "--fps", "8", "--mapping", "constant",
            "--quiet"]
    assert cli(capsys, *args, "-o", tmp_path / "a.gif", "--export-mesh", tmp_path / "m" / "%d.ply")[0] == 0
    code, _, err = cli(capsys, *args, "-o", tmp_path / "b.gif", "--export-mesh", tmp_path / "a.glb")
    assert code == 0, err
    gltf, accessor = read_glb(tmp_path / "a.glb")
    primitive = gltf["meshes"][0]["primitives"][0]
    base = accessor(primitive["attributes"]["POSITION"])
    assert len(primitive["targets"]) == 3 and gltf["meshes"][0]["weights"] == [0.0] * 3
    for k in range(4):  # frame k = base + target k-1: the mesh of that frame, as the .ply sequence has it
        ply = trimesh.load(tmp_path / "m" / f"{k}.ply", process=False)
        frame = base + (accessor(primitive["targets"][k - 1]["POSITION"]) if k else 0)
        assert np.abs(frame - ply.vertices).max() < 1e-5
    assert np.array_equal(accessor(primitive["indices"]).reshape(-1, 3), ply.faces)
    sampler = gltf["animations"][0]["samplers"][0]
    assert np.allclose(accessor(sampler["input"]), [0, 0.125, 0.25, 0.375])
    weights = accessor(sampler["output"]).reshape(4, 3)
    assert np.array_equal(weights, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    assert gltf["animations"][0]["channels"][0]["target"] == {"node": 0, "path": "weights"}
    assert len(trimesh.load(tmp_path / "a.glb", force="mesh").faces) == len(ply.faces)  # a reader takes it


def test_an_animation_camera_that_misses_the_body_is_refused_before_the_run(tmp_path, monkeypatch):
    """A turntable that turns the camera off the body (the target 4 boxes off to the side: the
    body is in view at azimuth 90, out of it past 150) is refused when the frames are planned,
    before any step is simulated; it used to fail when the last frames were drawn, after the run."""
    from fuzz_oracle import run_cli

    scene = tmp_path / "away.toml"
    text = (SCENES / "jelly.toml").read_text()
    text = text.replace('path = "assets/', f'path = "{(SCENES / "assets").as_posix()}/')
    text = text.replace("azimuth = 35.0", "azimuth = 90.0").replace("target = [0.5, 0.45, 0.5]", "target = [4.0, 0.45, 0.5]")
    scene.write_text(text + "\n[animation]\nframes = 4\nsteps_per_frame = 100\nturntable = 120.0\n")
    out = tmp_path / "away.gif"
    import deformgl.scene.animation as animation
    runs = []
    real_run = animation.simulate_scene
    monkeypatch.setattr(animation, "simulate_scene", lambda *a, **k: runs.append(1) or real_run(*a, **k))
    outcome = run_cli(["render", scene, "-o", out], watch=tmp_path)
    assert outcome.code == 2 and not runs, outcome.describe()
    assert "the body lies wholly outside the view" in outcome.stderr and "steps of dt" not in outcome.stderr
    assert not out.exists() and outcome.new_files == set(), outcome.describe()
