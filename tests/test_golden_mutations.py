"""The goldens' power, tested: small shading mutations must fail the golden comparison.

Each test copies the shader tree (the package ``deformgl.shaders``) to a temporary folder, applies
one mutation to the Blinn-Phong code of the copy (``lib/blinn_phong.glsl``, shared by every lit
path), points deformgl's shader reader (:func:`deformgl.gl.preprocessor.read_shader_file`) at the
copy, renders a few golden scenes and asserts that the comparison with their goldens, at the
tolerances of the golden tests (:data:`deformgl.testing.imagediff.SAME_RENDERER`), fails.

Measured on llvmpipe (pixels differing by more than 1/255; mean difference, out of 255), against
limits of 0.1 % and 0.05: shininess x 1.1: jelly 0.65 %, 0.028; dragon_bend_curvature 3.1 %, 0.11;
trilinear_tile 4.8 %, 0.17. Specular x 1.05: jelly 0.15 %, 0.012; dragon_bend_curvature 1.4 %,
0.064; trilinear_tile 2.2 %, 0.097. Light tilted by 1 degree: jelly 7.6 %, 0.27;
dragon_bend_curvature 13 %, 0.37; trilinear_tile 13 %, 0.43 (the tile's figures since its reframing
at 1.15 diagonals). The largest difference of any of them is 5/255 and at most 0.2 % of pixels
differ by more than 4/255: the big-difference tests alone (0.5 % over 4/255, nothing over
64/255) let all three through.
"""

from __future__ import annotations

from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path

import numpy as np
import pytest

import deformgl.gl.preprocessor as preprocessor
from deformgl.errors import ShaderError
from deformgl.files import read_png
from deformgl.scene.pipeline import render_scene
from deformgl.scene.schema import load_scene
from deformgl.testing.imagediff import SAME_RENDERER, check_golden, compare_images
from deformgl.trilinear.scenes import render_trilinear_scene

TESTS = Path(__file__).resolve().parent
SCENES = TESTS.parent / "scenes"
GOLDEN = TESTS / "golden"

_MAIN = "vec3 blinn_phong(vec3 world, vec3 n) {"
#: name: (original text, replacement) in lib/blinn_phong.glsl
MUTATIONS = {
    "shininess x 1.1": ("0.0), u_shininess)", "0.0), u_shininess * 1.1)"),
    "specular x 1.05": ("+ u_specular * spec", "+ u_specular * 1.05 * spec"),
    # rotate the light by 1 degree about an axis perpendicular to it (towards the horizon)
    "light tilted 1 degree": (_MAIN, _MAIN + """
    vec3 tilt_axis = normalize(cross(u_light_direction, vec3(0.0, 1.0, 0.0)));
    vec3 u_light_direction = u_light_direction * cos(radians(1.0))
        + cross(tilt_axis, u_light_direction) * sin(radians(1.0));"""),
}


def _copy_tree(node: Traversable, target: Path) -> None:
    target.mkdir(parents=True, exist_ok=True)
    for child in node.iterdir():
        if child.is_dir():
            if child.name != "__pycache__":
                _copy_tree(child, target / child.name)
        else:
            (target / child.name).write_bytes(child.read_bytes())


@pytest.fixture
def shader_copy(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A copy of the shader tree, which deformgl reads its shaders from during the test."""
    root = tmp_path / "shaders"
    _copy_tree(resources.files("deformgl.shaders"), root)

    def read_copy(name: str) -> str:
        path = root.joinpath(*name.split("/"))
        if not path.is_file():
            raise ShaderError(f"shaders/{name}: no such shader file in {root}")
        return path.read_text(encoding="utf-8")

    monkeypatch.setattr(preprocessor, "read_shader_file", read_copy)
    return root


def mutate(root: Path, mutation: str) -> None:
    path = root / "lib" / "blinn_phong.glsl"
    old, new = MUTATIONS[mutation]
    text = path.read_text(encoding="utf-8")
    assert text.count(old) == 1, f"the mutation {mutation!r} no longer applies to {path.name}"
    path.write_text(text.replace(old, new), encoding="utf-8")


#: golden name: render (small, fast scenes on three lighting paths)
RENDERS = {
    "jelly": lambda ctx: render_scene(ctx, load_scene(SCENES / "jelly.toml")),
    "dragon_bend_curvature": lambda ctx: render_scene(ctx, load_scene(SCENES / "dragon_bend_curvature.toml")),
    "trilinear_tile": lambda ctx: render_trilinear_scene(ctx, "tile", (320, 240)),
}


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("DEFORMGL_CACHE_DIR", str(tmp_path / "cache"))


def test_the_unmutated_copy_renders_the_goldens_exactly(ctx, shader_copy):
    """The copy is read (a missing file there is an error) and renders byte-identical images."""
    image = RENDERS["jelly"](ctx)
    np.testing.assert_array_equal(image, read_png(GOLDEN / "jelly.png"))
    (shader_copy / "lib" / "blinn_phong.glsl").unlink()
    with pytest.raises(ShaderError, match="blinn_phong"):
        RENDERS["jelly"](ctx)


@pytest.mark.parametrize("mutation", list(MUTATIONS))
def test_a_shading_mutation_fails_every_golden_tried(ctx, shader_copy, tmp_path, mutation):
    mutate(shader_copy, mutation)
    for name, render in RENDERS.items():
        image = render(ctx)
        result = compare_images(image, read_png(GOLDEN / f"{name}.png"), **SAME_RENDERER)
        assert not result.passed, f"{mutation} passes golden {name}: {result.reason}"
        assert result.max_abs <= 16, "not a small mutation any more"  # what the test is about
        with pytest.raises(AssertionError, match="does not match golden"):
            check_golden(image, GOLDEN / f"{name}.png", update=False, out_dir=tmp_path / "out",
                         **SAME_RENDERER)
