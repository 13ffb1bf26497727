"""Image-diff regression tests of the shipped scenes against golden PNGs made on llvmpipe.

A render fails when more than 0.5 % of pixels differ by more than 4/255 in any channel, or any
pixel by more than 64/255. Failures leave actual, expected and diff images in tests/output/.
Goldens change only with ``pytest --update-goldens`` (then look at them).
"""

from pathlib import Path

import pytest

from deformgl.scene.pipeline import render_scene
from deformgl.scene.schema import load_scene

SCENES = Path(__file__).resolve().parent.parent / "scenes"


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("DEFORMGL_CACHE_DIR", str(tmp_path / "cache"))


@pytest.mark.parametrize("name", ["jelly", "dragon", "dragon_bend_constant", "dragon_bend_curvature",
                                  "dragon_bend_auto", "fin", "heart"])
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
