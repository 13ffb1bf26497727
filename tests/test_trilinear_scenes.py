"""The paper's scenes (figures 1 and 9, the helix), their renders and the benchmark."""

import numpy as np
import pytest
import trimesh

from deformgl.errors import InputError
from deformgl.files import read_png
from studies.trilinear_speed import BenchSetup, bench_depth, bench_trilinear, format_trilinear
from deformgl.trilinear.scenes import render_trilinear_scene, write_trilinear_scene
from deformgl.trilinear.shapes import hall_tile, tube, uv_sphere

SIZE = (320, 240)


def test_tubes_linear_vs_trilinear_matches_golden(ctx, golden):
    image = render_trilinear_scene(ctx, "tubes", SIZE)
    assert image.shape == (240, 320, 3)
    golden(image, "trilinear_tubes")
    left, right = image[:, :160].astype(int), image[:, 160:].astype(int)
    # the same tubes, differently placed: the halves differ
    assert np.abs(left - right).max() > 100


def test_tile_on_torus_matches_golden(ctx, golden):
    golden(render_trilinear_scene(ctx, "tile", SIZE), "trilinear_tile")


def test_scene_names_and_sizes_are_checked(ctx, tmp_path):
    with pytest.raises(InputError, match="unknown trilinear scene 'donut'"):
        render_trilinear_scene(ctx, "donut", SIZE)
    with pytest.raises(InputError, match="too small"):
        render_trilinear_scene(ctx, "helix", (8, 8))
    out = write_trilinear_scene(ctx, "helix", tmp_path / "helix.png", (64, 48), samples=0)
    image = read_png(out)
    assert image.shape[:2] == (48, 64)
    assert (image[..., :3].astype(int).sum(2) < 700).mean() > 0.02  # spheres were drawn


def test_meshes_are_closed_and_have_the_stated_triangle_counts():
    for geo, count in ((uv_sphere(0.5, 6, 4), 36), (uv_sphere(0.5, 16, 9), 256), (uv_sphere(0.5, 64, 64), 8064),
                       (tube(1.0, 0.5, sections=12, rings=5), 2 * 12 * 4 + 2 * 12)):
        assert len(geo.triangles) == count
        mesh = trimesh.Trimesh(geo.vertices, geo.triangles, process=True)
        assert mesh.is_watertight and mesh.volume > 0  # closed and outward oriented
    sphere = uv_sphere(2.0, 12, 8)
    assert np.allclose(sphere.normals * 2.0, sphere.vertices)
    tile = hall_tile(resolution=8)
    assert np.allclose(tile.box.lo[:2], 0.0, atol=1e-3) and np.allclose(tile.box.hi[:2], 1.0, atol=1e-3)


def test_benchmark_runs_both_modes_and_reports_them(ctx):
    setups = (BenchSetup("helix", 30, 6, 4, (16.5, 13.3)), BenchSetup("spheres", 74, 8, 6, (19.5, 14.9)))
    rows = bench_trilinear(ctx, size=(64, 64), repeats=1, setups=setups)
    helix, spheres = rows
    assert helix.triangles == 30 * 36 and spheres.triangles == 74 * 2 * 8 * 5
    for row in rows:
        assert row.paths["linear"]["affine"] == row.setup.objects   # linear scenes: the plain path
        assert row.paths["trilinear"]["affine"] == 0                # trilinear ones are deformed
        assert all(v > 0 for v in (*row.compose_ms.values(), *row.draw_ms.values()))
        assert row.ratio() == pytest.approx(row.fps("trilinear") / row.fps("linear"))
    assert helix.paths["trilinear"]["cuboid"] == 30 and spheres.paths["trilinear"]["grid"] == 74
    depth = bench_depth(ctx, size=(64, 64), repeats=1, depths=(1, 3))
    assert depth[0].defines == depth[1].defines and depth[0].cells == depth[1].cells == (8, 8, 8)
    text = format_trilinear(rows, depth, "machine: test", size=(64, 64), repeats=1)
    assert text.splitlines()[0] == "machine: test"
    assert "fps ratio" in text and "helix" in text and "spheres" in text and "TRANSFORM_PATH" in text
