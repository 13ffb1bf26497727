"""examples/web: the browser example runs the exported scene with the pack's ES shaders in
headless Chromium (Debian chromium, software WebGL2 through SwiftShader) and draws the frame
deformgl renders, within the golden-image tolerances, logging no WebGL error. Needs chromium
(an optional system tool: apt-get install chromium; installed by .ci/run)."""

from __future__ import annotations

import functools
import http.server
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from chromium_pipe import Chromium, canvas_image, check_canvas, run_page
from conftest import TESTS
from deformgl.pack.export_web import web_scene
from deformgl.scene.pipeline import render
from deformgl.testing.imagediff import compare_images

ROOT = TESTS.parent
SCENE = ROOT / "scenes" / "dragon.toml"
STEPS, SIZE = 300, (320, 240)  # 0.06 s at the dragon's 2e-4 s

pytestmark = pytest.mark.chromium  # skipped with the reason where Chromium is missing (tests/conftest.py)


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


def export(out, *args):
    # (a working folder outside the checkout: python -m puts it first on sys.path, and the
    # checkout's package has no shaders folder of its own)
    return subprocess.run([sys.executable, "-m", "deformgl", "export-web", str(SCENE), str(out), *args],
                          capture_output=True, text=True, timeout=300, cwd=Path(out).parent)


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    """The page's result after STEPS steps: served over HTTP (fetch needs it) with the export."""
    root = tmp_path_factory.mktemp("web")
    for name in ("index.html", "main.js"):
        shutil.copy(ROOT / "examples" / "web" / name, root / name)
    proc = export(root / "data", "--steps", str(STEPS), "--size", f"{SIZE[0]}x{SIZE[1]}", "--mapping", "curvature")
    assert proc.returncode == 0, proc.stderr
    return run_page(root, f"data=data&steps={STEPS}")


def test_the_page_runs_the_steps_and_logs_no_webgl_error(page):
    assert page["errors"] == [], page["errors"]
    assert page["steps"] == STEPS and page["step_ms"] > 0 and page["frame_ms"] > 0
    # errors, exceptions and any WebGL/GL error report; performance notes ("GPU stall due to
    # ReadPixels", the page's own one-pixel waits for timing) are warnings, not errors
    bad = [m for m in page["messages"] if m.startswith(("log.error", "console.error", "exception"))
           or "INVALID" in m or "GL ERROR" in m.upper()]
    assert bad == [], bad
    print(f"\nheadless Chromium (SwiftShader): {page['step_ms']:.3f} ms per step, frame {page['frame_ms']:.1f} ms")


def test_deformgls_own_step_and_frame_of_the_same_scene(ctx):
    """The figures the page's are compared with (printed, not asserted: a measurement, as the page's):
    the same scene, steps and mapping on llvmpipe, timed the way main.js times them (the steps
    after the first, synchronised by a one-texel read; the best of 4 frames after a first)."""
    import time as _time

    from deformgl.render.passes import RenderTarget
    from deformgl.scene.pipeline import build_scene_model, make_draw_pass, scene_lighting, scene_view
    from deformgl.sim.simulation import make_simulation

    scene = web_scene(SCENE, steps=STEPS, size=SIZE, mapping="curvature")
    built = build_scene_model(scene)
    sim = make_simulation(built.system, "verlet", "fragment", dt=scene.physics.dt, ctx=ctx, loads=built.loads)
    try:
        assert sim.fast is not None  # the page runs the same pass
        sim.step(1)
        sim.positions()
        t0 = _time.perf_counter()
        sim.step(STEPS - 1)
        sim.position_texture.read()
        step_ms = (_time.perf_counter() - t0) * 1e3 / (STEPS - 1)
        draw = make_draw_pass(ctx, scene, built, sim.textures.layout)
        target = RenderTarget(ctx, SIZE, 0)
        try:
            view, lighting = scene_view(scene, built.bbox), scene_lighting(scene)
            frames = []
            for _ in range(5):
                t = _time.perf_counter()
                target.begin((1.0, 1.0, 1.0))
                draw.draw(sim.position_texture, view, lighting)
                target.read_rgb()
                frames.append((_time.perf_counter() - t) * 1e3)
            assert np.isfinite(frames).all()
        finally:
            draw.release()
            target.release()
    finally:
        sim.release()
    print(f"\ndeformgl on llvmpipe, the same scene: {step_ms:.3f} ms per step, frame {min(frames[1:]):.1f} ms")


def test_the_canvas_is_deformgls_frame(ctx, page):
    """The golden tolerances (chromium_pipe.check_canvas), after the steps moved the body."""
    scene = web_scene(SCENE, steps=STEPS, size=SIZE, mapping="curvature")
    ours = render(ctx, scene).image
    assert ours.shape == (SIZE[1], SIZE[0], 3)
    figures = check_canvas(ours, canvas_image(page))
    # the steps moved it: the start frame differs
    start = render(ctx, web_scene(SCENE, steps=1, size=SIZE, mapping="curvature")).image
    assert not compare_images(start, ours).passed
    print(f"\nbrowser vs deformgl: {figures}")


def test_export_web_refuses_what_the_page_cannot_run(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "deformgl", "export-web", str(ROOT / "scenes" / "dragon_grid.toml"),
                           str(tmp_path / "a")], capture_output=True, text=True, timeout=300, cwd=tmp_path)  # one-to-one
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "mapping.mode" in proc.stderr
    proc = subprocess.run([sys.executable, "-m", "deformgl", "export-web", str(ROOT / "scenes" / "cloth_64.toml"),
                           str(tmp_path / "b")], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert proc.returncode == 2 and proc.stderr.startswith("deformgl: error: ")
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_a_node_follows_the_mouse_while_dragged(ctx, tmp_path):  # (ctx: marks it gl, for the export)
    """The interactive page (no steps=): press on the mesh, move, the nearest node is held under
    the pointer while the simulation runs, and is let go on release."""
    root = tmp_path
    for name in ("index.html", "main.js"):
        shutil.copy(ROOT / "examples" / "web" / name, root / name)
    proc = export(root / "data", "--steps", "2", "--size", "320x240", "--mapping", "constant")
    assert proc.returncode == 0, proc.stderr
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(_QuietHandler, directory=str(root)))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    browser = Chromium()
    try:
        browser.open(f"http://127.0.0.1:{server.server_port}/index.html?data=data")
        browser.wait_for("window.deformglPage && window.deformglPage.steps() > 20", 60)
        left, top, width, height = browser.evaluate(
            "(() => { const r = document.getElementById('canvas').getBoundingClientRect();"
            " return [r.left, r.top, r.width, r.height]; })()")
        x, y = left + 0.45 * width, top + 0.5 * height
        browser.mouse("pressed", x, y)
        node = browser.evaluate("window.deformglPage.dragged()")
        assert node is not None, browser.messages
        start = browser.evaluate(f"window.deformglPage.position({node})")
        target = (x + 0.15 * width, y - 0.1 * height)
        browser.mouse("moved", *target)
        steps = browser.evaluate("window.deformglPage.steps()")
        browser.wait_for(f"window.deformglPage.steps() > {steps + 30}", 60)
        ndc = browser.evaluate(f"window.deformglPage.ndc({node})")
        want = (2 * (target[0] - left) / width - 1, 1 - 2 * (target[1] - top) / height)
        assert abs(ndc[0] - want[0]) < 0.01 and abs(ndc[1] - want[1]) < 0.01, (ndc, want)
        moved = browser.evaluate(f"window.deformglPage.position({node})")
        assert np.linalg.norm(np.subtract(moved, start)) > 0.01
        browser.mouse("released", *target)
        assert browser.evaluate("window.deformglPage.dragged()") is None
        steps = browser.evaluate("window.deformglPage.steps()")
        browser.wait_for(f"window.deformglPage.steps() > {steps + 30}", 60)
        assert browser.evaluate(f"window.deformglPage.position({node})") != moved  # free again
        assert not [m for m in browser.messages if m.startswith(("log.error", "exception")) or "INVALID" in m]
    finally:
        browser.close()
        server.shutdown()
        server.server_close()
