"""The organ-shaped heart scene (scenes/heart_organ.toml) and its mesh's generator,
examples/heart_mesh.py."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from deformgl.grid.meshio import load_mesh
from deformgl.scene.pipeline import build_scene_model, render_scene
from deformgl.scene.schema import load_scene

ROOT = Path(__file__).resolve().parent.parent
ASSET = ROOT / "scenes" / "assets" / "heart_organ.ply.gz"


def _generator():
    spec = importlib.util.spec_from_file_location("heart_mesh", ROOT / "examples" / "heart_mesh.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_generator_writes_the_shipped_mesh(tmp_path):
    """(compared as meshes, not bytes: zlib and trimesh versions may write other bytes)"""
    made, shipped = load_mesh(_generator().write(tmp_path / "heart.ply.gz")), load_mesh(ASSET)
    np.testing.assert_array_equal(made.faces, shipped.faces)
    np.testing.assert_allclose(made.vertices, shipped.vertices, rtol=0.0, atol=1e-7)  # m


def test_the_mesh_is_a_closed_outward_heart_12_cm_tall_apex_down():
    mesh = load_mesh(ASSET)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0.0  # outward normals
    assert np.ptp(mesh.vertices[:, 1]) == pytest.approx(0.12)
    # ventricles narrowing to the apex: the lowest tenth is much narrower than the middle
    y = mesh.vertices[:, 1]
    low, mid = mesh.vertices[y < y.min() + 0.012], mesh.vertices[np.abs(y - y.mean()) < 0.006]
    assert np.ptp(low[:, 0]) < 0.5 * np.ptp(mid[:, 0])


def test_the_scene_builds_a_myocardium_body():
    scene = load_scene(ROOT / "scenes" / "heart_organ.toml")
    built = build_scene_model(scene)
    rest = built.grid.rest_positions
    assert built.system.count == len(rest) > 1000
    assert scene.physics.material is not None and scene.physics.material.name == "heart"


@pytest.mark.slow
def test_the_scene_renders_a_sagging_heart(ctx):
    scene = load_scene(ROOT / "scenes" / "heart_organ.toml")
    image = render_scene(ctx, scene)
    rest = render_scene(ctx, scene.with_overrides(steps=0))
    assert image.shape == (360, 480, 3) and (image != rest).any()
