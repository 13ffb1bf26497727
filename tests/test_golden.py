"""Image-diff regression tests of the shipped scenes against golden PNGs made on llvmpipe.

The ``golden`` fixture (tests/conftest.py, on the deformgl pytest plugin) compares with the
same-renderer tolerances (:data:`deformgl.testing.imagediff.SAME_RENDERER`): a render fails when
more than 0.5 % of pixels differ by more than 4/255 in any channel, or any pixel by more than
64/255 (broken geometry), or more than 0.1 % of pixels by more than 1/255, or the mean difference
exceeds 0.05/255 (shading: tests/test_golden_mutations.py checks that a specular exponent x 1.1,
a specular strength x 1.05 and a light tilted by 1 degree each fail). llvmpipe renders these
byte-identical run to run and with any LP_NUM_THREADS. Failures leave actual, expected and diff
images in tests/output/. Goldens change only with ``pytest --update-goldens`` (then look at them).

Lighting paths covered: per-vertex grid surface (jelly, jelly_rest, cloth, and dragon_grid with its
node-grid overlay), mapped meshes with the constant, curvature-corrected and auto bases (dragon,
the default scene: auto) and tangent-space normal mapping (dragon_bend_*),
the one-node-thin fin, the trilinear scene graph with direct normals (test_trilinear_scenes.py:
trilinear_tile, trilinear_tubes) and with tangent-frame normals (trilinear_tile_tangent, here).
"""

import dataclasses
from pathlib import Path

import pytest

from deformgl.scene.pipeline import render_scene
from deformgl.scene.schema import load_scene
from deformgl.trilinear.scenes import render_trilinear_scene

SCENES = Path(__file__).resolve().parent.parent / "scenes"


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("DEFORMGL_CACHE_DIR", str(tmp_path / "cache"))


@pytest.mark.parametrize("name", ["jelly", "dragon", "dragon_grid", "dragon_bend_constant", "dragon_bend_curvature",
                                  "dragon_bend_auto", "fin", "dragon_heart_scale"])
def test_scene_matches_golden(ctx, golden, name):
    image = render_scene(ctx, load_scene(SCENES / f"{name}.toml"))
    golden(image, name)


def test_rest_state_matches_golden(ctx, golden):
    """Zero steps: the undeformed grid surface, so a failure separates render from simulation."""
    scene = load_scene(SCENES / "jelly.toml").with_overrides(steps=0)
    golden(render_scene(ctx, scene), "jelly_rest")


@pytest.mark.parametrize("integrator, backend", [("verlet", "fragment"), ("rk4", "feedback")])
def test_cloth_on_sphere_matches_golden(ctx, golden, integrator, backend):
    """The paper's cloth (64 x 64, corners pinned) draped on its sphere, by two integrators on the
    two GPU backends; the sphere is drawn."""
    scene = load_scene(SCENES / "cloth_64.toml").with_overrides(integrator=integrator, backend=backend)
    golden(render_scene(ctx, scene), f"cloth_64_{integrator}")


def test_trilinear_tangent_frame_normals_match_golden(ctx, golden):
    """The figure 9 tile on its torus with the tangent-frame normals of section 4.2 (orthogonal
    to the deformed surface, seams at cell borders): the trilinear goldens of
    test_trilinear_scenes.py use the direct normals."""
    golden(render_trilinear_scene(ctx, "tile", (320, 240), normals="tangent"), "trilinear_tile_tangent")


def test_fxaa_scene_matches_golden(ctx, golden):
    """The default scene with ``[render] aa = "fxaa"``: the post-process pass of
    shaders/render/fxaa.frag on the single-sampled image (the msaa goldens above are untouched)."""
    scene = load_scene(SCENES / "dragon.toml")
    scene = dataclasses.replace(scene, render=dataclasses.replace(scene.render, aa="fxaa"))
    golden(render_scene(ctx, scene), "dragon_fxaa")
