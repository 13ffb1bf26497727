"""Scene graphs rendered (issue 17): a hand-written graph of depth >= 4 with grids and instancing
from Python and the CLI, keyframed frames, the composed mesh exported from the GPU against a
float64 Knuth, Kohlhammer & Kuijper, eq. 1, and a graph attached to a simulated body."""

from pathlib import Path

import numpy as np
import pytest
import trimesh

from deformgl.cli import main
from deformgl.files import read_png
from deformgl.scene.graphs import render_graph_file
from deformgl.trilinear.cuboid import CORNERS, trilinear_corners
from deformgl.trilinear.graphbuild import compose_graph, graph_mesh, render_graph_frames, render_graph
from deformgl.trilinear.graphfile import load_graph, save_graph
from deformgl.trilinear.graphspec import Deformation, Keyframe, GraphMesh, NodeSpec, SceneGraph, GraphTransform, GraphView

SCENES = Path(__file__).resolve().parent.parent / "scenes"
SIZE = (160, 120)


def run_cli(capsys, *args):
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def deep_graph() -> SceneGraph:
    """Depth 6: tilt -> torus-wrap grid -> array (instancing) -> twist grid (keyframed) -> scale ->
    sphere; the twist node is shared by all 24 instances."""
    return SceneGraph(
        roots=["tilt"], view=GraphView(size=SIZE, azimuth=10.0, elevation=40.0, distance=1.1, samples=0),
        meshes={"ball": GraphMesh("sphere", {"radius": 0.5, "segments": 12, "rings": 8})},
        deformations={"wrap": Deformation("torus", {"length": 8.0, "width": 3.0, "major": 3.0, "minor": 0.8}),
                      "tw": Deformation("twist", {"rate": 0.0}, [Keyframe(0.0, {"rate": 0.0}), Keyframe(2.0, {"rate": 3.0})])},
        nodes={"tilt": NodeSpec(GraphTransform("trs", axis=(1.0, 0.0, 0.0), degrees=-90.0), ["wrap"]),
               "wrap": NodeSpec(GraphTransform("grid", deformation="wrap", cells=(16, 6, 1),
                                          box=((0.0, 0.0, 0.0), (8.0, 3.0, 1.0))), ["cells"]),
               "cells": NodeSpec(GraphTransform("array", count=(8, 3, 1), step=(1.0, 1.0, 0.0), offset=(0.5, 0.5, 0.5),
                                           colours=((0.8, 0.3, 0.2), (0.2, 0.4, 0.8))), ["twisted"]),
               "twisted": NodeSpec(GraphTransform("grid", deformation="tw", cells=(2, 2, 4)), ["squash"]),
               "squash": NodeSpec(GraphTransform("trs", scale=(0.9, 0.5, 0.9)), ["ball"]),
               "ball": NodeSpec(mesh="ball")})


def _depth(graph: SceneGraph, name: str) -> int:
    return 1 + max((_depth(graph, c) for c in graph.nodes[name].children), default=0)


def test_a_deep_graph_renders_the_same_from_python_from_its_file_and_from_the_cli(ctx, tmp_path, capsys):
    graph = deep_graph()
    assert _depth(graph, "tilt") == 6
    (scene,) = compose_graph(graph)
    assert scene.leaf_count == 24 and scene.paths()["grid"] == 24  # every ball deformed by a grid
    image = render_graph(ctx, graph, time=1.0)
    assert image.shape == (120, 160, 3)
    assert (image.astype(int).sum(2) < 600).mean() > 0.05  # balls drawn on the white background
    path = save_graph(graph, tmp_path / "deep.toml")
    assert np.array_equal(render_graph(ctx, load_graph(path), tmp_path, time=1.0), image)
    out = tmp_path / "deep.png"
    code, stdout, err = run_cli(capsys, "render", path, "-o", out, "--time", "1.0")
    assert code == 0, err
    assert np.array_equal(read_png(out)[..., :3], image) and "wrote" in stdout


def test_frames_follow_the_keyframes_and_match_the_stills(ctx):
    graph = deep_graph()
    assert graph.frame_times(3) == [0.0, 1.0, 2.0] and graph.frame_times(1) == [0.0]
    frames = render_graph_frames(ctx, graph, graph.frame_times(3))
    assert len(frames) == 3
    assert all(np.abs(a.astype(int) - b).max() > 50 for a, b in zip(frames, frames[1:]))  # it moves
    # the frame at t = 1 s is the still with the twist rate set to the interpolated 1.5 rad/m
    still = deep_graph()
    still.deformations["tw"] = Deformation("twist", {"rate": 1.5})
    assert np.array_equal(frames[1], render_graph(ctx, still))
    assert np.array_equal(frames[1], render_graph(ctx, graph.at(1.0)))
    # after the last key the graph holds still
    assert np.array_equal(render_graph(ctx, graph, time=5.0), frames[2])


def test_exported_one_cell_cuboid_matches_float64_eq1(ctx, tmp_path, capsys):
    rng = np.random.default_rng(17)
    corners = CORNERS * np.array([2.0, 1.0, 1.5]) + rng.uniform(-0.3, 0.3, (8, 3))
    graph = SceneGraph(roots=["cell"], view=GraphView(size=(64, 48), samples=0),
                       meshes={"ball": GraphMesh("sphere", {"radius": 0.5, "segments": 24, "rings": 16})},
                       nodes={"cell": NodeSpec(GraphTransform("cuboid", corners=corners,
                                                         box=((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5))), ["ball"]),
                              "ball": NodeSpec(mesh="ball")})
    path = save_graph(graph, tmp_path / "cell.toml")
    out, ply = tmp_path / "cell.png", tmp_path / "cell.ply"
    code, stdout, err = run_cli(capsys, "render", path, "-o", out, "--export-mesh", ply)
    assert code == 0, err
    mesh = trimesh.load(ply, process=False)
    from deformgl.trilinear.shapes import uv_sphere

    ball = uv_sphere(0.5, 24, 16)
    want = trilinear_corners(corners, ball.vertices + 0.5)          # Knuth, Kohlhammer & Kuijper, eq. 1, float64, box -> unit cube
    diagonal = float(np.linalg.norm(want.max(0) - want.min(0)))
    assert mesh.vertices.shape == want.shape and np.array_equal(mesh.faces, ball.triangles)
    assert np.abs(mesh.vertices - want).max() <= 1e-6 * diagonal
    # the same from Python, without the file
    v, n, f = graph_mesh(ctx, compose_graph(graph))
    assert np.abs(v - want).max() <= 1e-6 * diagonal and np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5)


def test_a_graph_attached_to_a_simulated_body_renders_from_the_cli_and_python(ctx, tmp_path, capsys):
    source = SCENES / "graph_dragon_beads.toml"
    graph = load_graph(source)
    assert _depth(graph, "world") >= 4 and graph.body is not None
    out0, out2, ply = tmp_path / "b0.png", tmp_path / "b2.png", tmp_path / "b.ply"
    code, _, err = run_cli(capsys, "render", source, "-o", out0, "--size", "240x180", "--export-mesh", ply)
    assert code == 0, err
    code, _, err = run_cli(capsys, "render", source, "-o", out2, "--size", "240x180", "--time", "2")
    assert code == 0, err
    a, b = read_png(out0)[..., :3].astype(int), read_png(out2)[..., :3].astype(int)
    blue = (a[..., 2] > a[..., 0] + 60).mean()
    assert blue > 0.002  # the blue beads on the orange dragon
    assert np.abs(a - b).max() > 50  # the keyframed bend moved them
    beads = trimesh.load(ply, process=False)
    assert len(beads.vertices) == 2 * 12 * (2 + 16 * 8)  # 2 strings x 12 beads x sphere(16, 9): 2 poles + 8 rings
    rendered, mesh = render_graph_file(ctx, source, size=(240, 180), mesh=True)
    assert np.array_equal(rendered.image, a) and mesh is not None
    assert np.allclose(mesh[0], beads.vertices, atol=1e-6)


@pytest.mark.parametrize("args, message", [
    (("--steps", "3"), "--steps applies to simulation scenes"),
    (("--time", "-1"), "--time: must be a finite time >= 0 s"),
    (("-o", "x.jpg"), "x.jpg: the output must be a .png file"),
])
def test_cli_refuses_bad_options_for_graphs_in_one_line(tmp_path, capsys, args, message):
    code, _, err = run_cli(capsys, "render", SCENES / "trilinear_tile.toml", *args)
    assert code == 2 and message in err and err.count("\n") == 1


def test_cli_bad_graph_file_and_time_on_a_simulation_scene_are_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('[graph]\nroots = ["r"]\n[nodes.r]\ntranslat = [0, 0, 0]\n')
    code, _, err = run_cli(capsys, "render", bad, "-o", tmp_path / "x.png")
    assert code == 2 and "bad.toml: nodes.r.translat: unknown key (did you mean 'translate'?)" in err
    assert err.count("\n") == 1 and not (tmp_path / "x.png").exists()
    code, _, err = run_cli(capsys, "render", SCENES / "jelly.toml", "--time", "1", "-o", tmp_path / "y.png")
    assert code == 2 and "--time applies to scene-graph files" in err


def test_the_docs_python_example_runs(ctx, tmp_path, monkeypatch):  # ctx: marked gl (the example makes its own)
    """docs/SCENEGRAPH.md's example, in a folder where scenes/ is the shipped one."""
    text = (SCENES.parent / "docs" / "SCENEGRAPH.md").read_text()
    code = text.split("```python\n", 1)[1].split("```", 1)[0]
    (tmp_path / "scenes").symlink_to(SCENES)
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(code, "SCENEGRAPH.md", "exec"), namespace)
    assert namespace["image"].shape == (480, 960, 3) and len(namespace["frames"]) == 3
    assert load_graph(tmp_path / "helix_side.toml").view.azimuth == 60.0


def test_a_bad_lattice_file_is_named_with_its_key(tmp_path):
    np.save(tmp_path / "flat.npy", np.zeros((2, 2, 3)))
    graph = SceneGraph(roots=["g"], meshes={"b": GraphMesh("sphere", {"radius": 0.5})},
                       nodes={"g": NodeSpec(GraphTransform("grid", file="flat.npy", box=((0.0,) * 3, (1.0,) * 3)), ["b"]),
                              "b": NodeSpec(mesh="b")})
    from deformgl.errors import SceneError

    with pytest.raises(SceneError, match=r"g\.toml: nodes\.g\.grid\.file: 'flat\.npy': a lattice must have shape"):
        compose_graph(graph, tmp_path, file="g.toml")
    graph.nodes["g"].transform.file = "none.npy"
    with pytest.raises(SceneError, match=r"g\.toml: nodes\.g\.grid\.file: cannot read .*none\.npy"):
        compose_graph(graph, tmp_path, file="g.toml")


def test_the_shipped_demo_files_render_the_goldens(ctx, golden):
    """The goldens of test_trilinear_scenes.py, rendered from the files as deformgl render does."""
    for name in ("tubes", "tile"):
        graph = load_graph(SCENES / f"trilinear_{name}.toml")
        golden(render_graph(ctx, graph, SCENES, size=(320, 240)), f"trilinear_{name}")


def test_a_keyframed_graph_animates_through_the_animation_writer(ctx, tmp_path, capsys):
    """``deformgl render GRAPH.toml -o frames/%02d.png --frames N``: frame k is the still at the
    k-th of N times from 0 to the last keyframe (the graph's own ``--time`` stills), and a GIF
    holds the N frames."""
    from PIL import Image

    scene = SCENES / "graph_bend_twist.toml"
    graph = load_graph(scene)
    times = graph.frame_times(3)
    assert times == [0.0, 1.0, 2.0]
    (tmp_path / "f").mkdir()
    code, _, err = run_cli(capsys, "render", scene, "-o", tmp_path / "f" / "%02d.png", "--frames", 3)
    assert code == 0, err
    frames = [read_png(tmp_path / "f" / f"{k:02d}.png") for k in range(3)]
    for k, t in enumerate(times):
        code, _, err = run_cli(capsys, "render", scene, "-o", tmp_path / f"still{k}.png", "--time", t)
        assert code == 0, err
        assert np.array_equal(frames[k], read_png(tmp_path / f"still{k}.png"))
    assert not np.array_equal(frames[0], frames[2])  # the bend and twist move it
    code, _, err = run_cli(capsys, "render", scene, "-o", tmp_path / "bar.gif", "--frames", 3, "--fps", 6)
    assert code == 0, err
    with Image.open(tmp_path / "bar.gif") as gif:
        assert gif.n_frames == 3


@pytest.mark.parametrize("args, message", [
    (["--frames", "2", "-o", "x.png"], "an animation must end in .mp4, .gif or .webp"),
    (["--frames", "2", "-o", "x.gif", "--time", "1"], "--time: not with --frames"),
    (["--frames", "0", "-o", "x.gif"], "--frames: must be in 1.."),
    (["--frames", "2", "-o", "x.gif", "--fps", "0"], "--fps: must be in (0, 1000]"),
    (["-o", "x.png", "--camera", "90,10,2"], "--camera applies to simulation scenes"),
    (["-o", "x.png", "--json"], "--json applies to simulation scenes"),
])
def test_graph_animation_options_are_checked_in_one_line(ctx, tmp_path, capsys, args, message):
    args = [a if not a.startswith("x.") else str(tmp_path / a) for a in args]
    code, _, err = run_cli(capsys, "render", SCENES / "graph_bend_twist.toml", *args)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    code, _, err = run_cli(capsys, "render", SCENES / "graph_dragon_beads.toml", "--frames", "2", "-o",
                           str(tmp_path / "b.gif"))
    assert code == 2 and "renders stills" in err
