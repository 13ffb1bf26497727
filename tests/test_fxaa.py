"""The FXAA post-process pass (shaders/render/fxaa.frag), ``[render] aa``, and the AA part of
``bench render`` (studies.aa)."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from studies.aa import AA_MODES, format_budgets, frame_budgets, image_difference, reference_image
from deformgl.errors import GLError, SceneError
from deformgl.render.camera import View
from deformgl.render.mapped import StaticMeshPass
from deformgl.render.passes import Lighting, RenderTarget
from deformgl.scene.budget import estimate as scene_budget
from deformgl.scene.schema import load_scene

SCENES = Path(__file__).resolve().parent.parent / "scenes"
SIZE = 96
BACKGROUND = (1.0, 1.0, 1.0)
#: a dark triangle with edges at three odd slopes, in clip space (identity camera)
TRIANGLE = np.array([[-0.8, -0.7, 0.0], [0.75, -0.3, 0.0], [-0.1, 0.85, 0.0]])
IDENTITY = View(eye=np.array([0.0, 0.0, 5.0]), view=np.eye(4), projection=np.eye(4))
LIGHT = Lighting(direction=(0.0, 0.0, 1.0), material=(0.1, 0.1, 0.1), ambient=0.0, specular=0.0)


@pytest.fixture
def triangle(ctx):
    mesh = StaticMeshPass(ctx, TRIANGLE, np.tile([0.0, 0.0, 1.0], (3, 1)), np.array([[0, 1, 2]]))
    yield lambda: mesh.draw(IDENTITY, LIGHT)
    mesh.release()


def render(ctx, draw, samples=0, fxaa=False, size=SIZE, background=BACKGROUND):
    target = RenderTarget(ctx, (size, size), samples, fxaa=fxaa)
    try:
        target.begin(background)
        draw()
        return target.read_rgb()
    finally:
        target.release()


def test_fxaa_smooths_the_edges_and_leaves_flat_areas(ctx, triangle):
    plain = render(ctx, triangle)
    fxaa = render(ctx, triangle, fxaa=True)
    msaa8 = reference_image(ctx, triangle, SIZE, BACKGROUND)
    levels = lambda im: len(np.unique(im[..., 0]))  # noqa: E731
    assert levels(plain) == 2  # aliased: background and triangle only
    assert levels(fxaa) > 10  # blended edge pixels
    # far from the edges (flat colour) FXAA changes nothing
    edge = np.abs(np.diff(plain[..., 0].astype(int), axis=0)).astype(bool)
    near = np.zeros(plain.shape[:2], bool)
    near[:-1] |= edge
    near[1:] |= edge
    edge = np.abs(np.diff(plain[..., 0].astype(int), axis=1)).astype(bool)
    near[:, :-1] |= edge
    near[:, 1:] |= edge
    grown = near.copy()
    for axis in (0, 1):
        for shift in (-2, -1, 1, 2):
            grown |= np.roll(near, shift, axis=axis)
    assert np.array_equal(fxaa[~grown], plain[~grown])
    changed = np.abs(fxaa.astype(int) - plain.astype(int)).max(axis=2) > 0
    assert changed.sum() > 0.3 * near.sum()
    # nearer to 8x MSAA than the aliased image, on the edge pixels
    d_plain, _ = image_difference(plain, msaa8)
    d_fxaa, _ = image_difference(fxaa, msaa8)
    assert d_fxaa < 0.75 * d_plain


def test_fxaa_of_a_flat_image_is_the_image(ctx):
    image = render(ctx, lambda: None, fxaa=True, background=(0.25, 0.5, 0.75))
    assert np.array_equal(np.unique(image.reshape(-1, 3), axis=0), [[64, 128, 191]])


def test_fxaa_and_msaa_together_is_an_error(ctx):
    with pytest.raises(GLError, match="FXAA and 4x MSAA"):
        RenderTarget(ctx, (8, 8), 4, fxaa=True)


def test_render_aa_key(tmp_path):
    base = (SCENES / "jelly.toml").read_text().replace('path = "assets/', f'path = "{SCENES}/assets/')
    assert "[render]" in base and str(SCENES) in base
    good = tmp_path / "fxaa.toml"
    good.write_text(base.replace("[render]", '[render]\naa = "fxaa"'))
    render = load_scene(good).render
    assert render.aa == "fxaa" and render.fxaa and render.samples == 0
    default = load_scene(SCENES / "jelly.toml").render
    assert default.aa == "msaa" and not default.fxaa and default.samples == default.msaa
    none = dataclasses.replace(default, aa="none")
    assert none.samples == 0 and not none.fxaa
    bad = tmp_path / "bad.toml"
    bad.write_text(base.replace("[render]", '[render]\naa = "smaa"'))
    with pytest.raises(SceneError, match=r"bad.toml.*render\.aa"):
        load_scene(bad)


def test_budget_counts_the_fxaa_buffers():
    scene = load_scene(SCENES / "jelly.toml")
    w, h = scene.render.size
    msaa = scene_budget(scene).gpu["render target"]
    fxaa = scene_budget(dataclasses.replace(scene, render=dataclasses.replace(scene.render, aa="fxaa")))
    none = scene_budget(dataclasses.replace(scene, render=dataclasses.replace(scene.render, aa="none")))
    assert none.gpu["render target"] == w * h * 8 and none.samples == 0
    assert fxaa.gpu["render target"] == w * h * 12 and fxaa.samples == 0
    assert msaa == w * h * scene.render.msaa * 8 + w * h * 4


def test_frame_budgets_split_and_quality(ctx, triangle):
    steps = []
    budgets = frame_budgets(ctx, lambda: steps.append(1), triangle, 64, BACKGROUND, repeats=3)
    assert list(budgets) == list(AA_MODES) and len(steps) == 3 * len(AA_MODES)
    for b in budgets.values():
        assert min(b.steps_ms, b.draw_ms, b.aa_ms, b.read_ms) >= 0
        assert b.frame_ms == pytest.approx(b.steps_ms + b.draw_ms + b.aa_ms + b.read_ms)
    # against the reference (8x MSAA, or 16 samples per pixel where the renderer has at most 4x):
    # 4x MSAA is closest, FXAA nearer than no AA
    diff = {name: b.mean_diff for name, b in budgets.items()}
    assert diff["4x MSAA"] < diff["FXAA"] < diff["no AA"]
    assert 0 < budgets["4x MSAA"].differing < budgets["no AA"].differing
    text = "\n".join(format_budgets(budgets, {"frame_size": 64, "frame_steps": 15}))
    assert "frame budget at 64x64, 15 steps" in text and "FXAA" in text and "4x MSAA" in text


def test_frame_budgets_time_and_compare_the_culled_draw_too(ctx, triangle):
    """culled=: each AA mode again as "<mode> + cull", its image against the reference of the
    unculled draw: here a stand-in that draws nothing (as if every face were culled), so the
    culled rows are as far off as an empty image."""
    calls = []

    def empty() -> None:
        calls.append(1)

    budgets = frame_budgets(ctx, lambda: None, triangle, 64, BACKGROUND, repeats=2, culled=empty)
    assert list(budgets) == [*AA_MODES, *(f"{m} + cull" for m in AA_MODES)]
    assert len(calls) == len(AA_MODES) * (1 + 2)  # (one image each, then 2 rounds)
    for mode in AA_MODES:
        assert budgets[f"{mode} + cull"].mean_diff > 5 * budgets[mode].mean_diff
    text = "\n".join(format_budgets(budgets, {"frame_size": 64, "frame_steps": 15}))
    assert "FXAA + cull" in text
