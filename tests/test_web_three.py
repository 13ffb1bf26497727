"""examples/web/three: the three.js client of the shader pack runs N spring steps in headless
Chromium (software WebGL2 through SwiftShader) with the pack's ES shaders as RawShaderMaterials,
and its canvas matches ``deformgl render --steps N`` of the same scene within the golden-image
tolerances (tests/test_web_example.py's: at most 0.5 % of the pixels over 4/255, none over
64/255 away from silhouette and crease pixels). Needs chromium and three.js (``npm ci --prefix
examples/web/three``; both installed by .ci/run's extras step)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import pytest

from chromium_pipe import canvas_image, check_canvas, run_page
from conftest import TESTS
from deformgl.cli import main
from deformgl.files import read_png
from deformgl.testing.imagediff import compare_images

ROOT = TESTS.parent
CLIENT = ROOT / "examples" / "web" / "three"
SCENE = ROOT / "scenes" / "dragon.toml"
STEPS, SIZE = 300, (320, 240)  # 0.06 s at the dragon's 2e-4 s

pytestmark = [pytest.mark.chromium, pytest.mark.three]


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    """The three.js page's result after STEPS steps, served over HTTP with the export and three."""
    root = tmp_path_factory.mktemp("three")
    for name in ("index.html", "main.js"):
        shutil.copy(CLIENT / name, root / name)
    build = root / "node_modules" / "three" / "build"
    build.mkdir(parents=True)
    for name in ("three.module.js", "three.core.js"):
        shutil.copy(CLIENT / "node_modules" / "three" / "build" / name, build / name)
    proc = subprocess.run([sys.executable, "-m", "deformgl", "export-web", str(SCENE), str(root / "data"), "--steps",
                           str(STEPS), "--size", f"{SIZE[0]}x{SIZE[1]}", "--mapping", "curvature"],
                          capture_output=True, text=True, timeout=300, cwd=root)
    assert proc.returncode == 0, proc.stderr
    return run_page(root, f"data=data&steps={STEPS}")


def test_the_three_page_runs_the_steps_with_the_pinned_three(page):
    assert page["errors"] == [], page["errors"]
    lock = json.loads((CLIENT / "package-lock.json").read_text())
    assert page["three"] == lock["packages"]["node_modules/three"]["version"].split(".")[1]  # r187 of 0.187.0
    assert page["steps"] == STEPS and page["step_ms"] > 0 and page["frame_ms"] > 0
    bad = [m for m in page["messages"] if m.startswith(("log.error", "console.error", "exception"))
           or "INVALID" in m or "GL ERROR" in m.upper() or "THREE.WebGLProgram" in m]
    assert bad == [], bad
    print(f"\nthree.js r{page['three']} in headless Chromium (SwiftShader): {page['step_ms']:.3f} ms per step, "
          f"frame {page['frame_ms']:.1f} ms")


def test_the_three_canvas_is_deformgl_render_of_the_same_steps(ctx, page, tmp_path, capsys):
    """The canvas against ``deformgl render --steps N`` of the same scene, size and mapping,
    without MSAA (the canvas has none: export-web renders without it too)."""
    common = ["--size", f"{SIZE[0]}x{SIZE[1]}", "--mapping", "curvature", "--set", "render.msaa=1", "--quiet"]
    assert main(["render", str(SCENE), "--steps", str(STEPS), *common, "-o", str(tmp_path / "n.png")]) == 0
    assert main(["render", str(SCENE), "--steps", "1", *common, "-o", str(tmp_path / "start.png")]) == 0
    capsys.readouterr()
    ours = read_png(tmp_path / "n.png")
    assert ours.shape == (SIZE[1], SIZE[0], 3)
    figures = check_canvas(ours, canvas_image(page))
    assert not compare_images(read_png(tmp_path / "start.png"), ours).passed  # the steps moved it
    print(f"\nthree.js vs deformgl render: {figures}")
