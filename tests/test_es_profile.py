"""The GLSL ES 3.00 profile runs: the same simulations, mappings and scene graphs on an OpenGL ES
3 context (EGL, llvmpipe's "OpenGL ES 3.2") as on the desktop core context, within the GPU
tolerances the desktop tests use. The ES run is a subprocess (python -m deformgl.pack.es_check):
its context becomes the thread's current one."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from deformgl.pack import es_check
from deformgl.sim import integrators as I
from deformgl.testing.imagediff import compare_images

from conftest import GOLDEN_DIR

SCENES = GOLDEN_DIR.parent.parent / "scenes"
#: foundation Verlet + constant mapping; curvature mapping (Mosegaard & Sorensen 2005, eq. 8);
#: the general fragment stages with flexion and a sphere; the trilinear grid path (3D atlas);
#: the FXAA pass (render/fxaa.frag)
CASES = [str(SCENES / "dragon_bend_constant.toml"), str(SCENES / "dragon_bend_curvature.toml"),
         str(SCENES / "cloth_64.toml"), str(SCENES / "jelly.toml"), "trilinear:tubes",
         f"fxaa:{SCENES / 'jelly.toml'}"]


@pytest.fixture(scope="module")
def es_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("es") / "es.npz"
    # (a working folder outside the checkout: python -m puts it first on sys.path, and the
    # checkout's package has no shaders folder of its own)
    proc = subprocess.run([sys.executable, "-m", "deformgl.pack.es_check", str(out), "--integrators", *CASES],
                          capture_output=True, text=True, timeout=600, cwd=out.parent)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return dict(np.load(out))


def test_the_context_is_opengl_es_3(es_run):
    assert str(es_run["version"]).startswith("OpenGL ES 3.")


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(CASES)), ids=[("fxaa-" if c.startswith("fxaa:") else "") + c.rsplit("/", 1)[-1] for c in CASES])
def test_es_render_matches_the_desktop_render(ctx, es_run, index):
    name = CASES[index]
    desktop = es_check.render_named(ctx, name)
    es = es_run[f"image_{index}"]
    diff = compare_images(desktop, es)  # the golden-image tolerances
    assert diff.passed, diff.reason
    assert (desktop != desktop[0, 0]).any(axis=2).mean() > 0.02  # something was drawn


@pytest.mark.parametrize("backend", ["fragment", "feedback"])
@pytest.mark.parametrize("name", I.EXPLICIT_INTEGRATORS)
def test_es_integrators_match_the_reference_like_desktop(es_run, backend, name):
    """The one-step bound of tests/test_fragment_integrators.py (1e-5 of the coordinate scale), after
    es_check.STEPS steps against the float64 reference, for every constraint kind."""
    for constraint in es_check.CONSTRAINTS:
        system, _, state, c = es_check.integrator_case(constraint)
        ref = state
        for k in range(es_check.STEPS):
            ref = I.step(system, name, ref, 1e-3, k * 1e-3, constraints=c)
        x = es_run[f"x_{backend}_{name}_{constraint}"].astype(np.float64)
        scale = np.abs(ref.x).max()
        assert np.abs(x - ref.x).max() <= 1e-5 * scale, (constraint, np.abs(x - ref.x).max())
        assert np.abs(ref.x - state.x).max() > 100 * np.abs(x - ref.x).max()


@pytest.mark.parametrize("name", list(es_check.STABLE))
def test_es_stable_integrators_match_the_reference(es_run, name):
    """Implicit Euler and XPBD on the ES context against their float64 NumPy references, every
    constraint kind, within the desktop tests' bounds of the motion (tests/test_implicit.py: 1e-5;
    tests/test_xpbd.py over several steps: 1e-4; measured 8e-7 and 1.4e-5)."""
    bound = {"implicit-euler": 1e-5, "xpbd": 1e-4}[name]
    ref = es_check.stable_integrators(None, "numpy")
    for constraint in es_check.CONSTRAINTS:
        key = f"{name}_{constraint}"
        _, _, state, _ = es_check.integrator_case(constraint)
        x, r = es_run[f"x_fragment_{key}"].astype(np.float64), ref[f"x_numpy_{key}"]
        moved = np.abs(r - state.x).max()
        assert moved > 1e-3, (constraint, moved)
        assert np.abs(x - r).max() <= bound * moved, (constraint, np.abs(x - r).max() / moved)


def test_es_programs_are_es_sources(es_run):
    from deformgl.gl.preprocessor import preprocess

    text = preprocess("sim/verlet.frag", {"COMPACT": True}, "es").text
    assert text.startswith("#version 300 es\nprecision highp float;\n")
    assert "#define COMPACT" in text and "#line 2 0" in text
