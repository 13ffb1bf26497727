"""Shared fixtures: one headless GL context per session, golden-image checks.

GL tests use the ``ctx`` fixture. Without a working EGL context they are skipped locally, but
with ``DEFORMGL_REQUIRE_GL=1`` (set by ``.ci/run``) a missing context fails the session, and
so does any skipped test (except those of an optional extra, whose skip reason says "optional
extra"; with ``DEFORMGL_REQUIRE_EXTRAS=1``, also set by ``.ci/run`` after installing the extras,
those too): CI must never pass with its GL or extras' tests skipped.

Markers (registered in pyproject.toml): every test that uses ``ctx`` — directly or through any
fixture depending on it — is marked ``gl`` here, as are the tests in ``GL_WITHOUT_CTX`` that make
their own context (the CLI and the context tests); ``SLOW`` lists the long ones, which the
README's test command leaves out (pyproject's ``addopts``: ``-m "not slow"``; ``pytest -m slow``
runs them). A test that is not marked ``gl`` gets no GL context: creating one raises in the
process, and EGL finds no driver in its subprocesses, so ``pytest -m "not gl"`` really runs
without OpenGL.

A test that needs an optional extra or system tool carries that extra's or tool's marker
(:data:`EXTRAS`, :data:`TOOLS`, :data:`FILES`: ``plot``, ``fem``, ``video``, ``sweep``, ``peers``,
``io``, ``usd``, ``glslang``, ``chromium``, ``three``); where it is missing, the test is skipped here with a reason that names it and
how to install it. ``.ci/run`` runs the README's test command without them, installs them, then
runs the marked tests (and the slow ones) with ``DEFORMGL_REQUIRE_EXTRAS=1``. ``both_ways``
marks a test whose verdict depends on which extras are installed (mypy's), run in both runs.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import sys
from pathlib import Path

import pytest

REQUIRE_GL = os.environ.get("DEFORMGL_REQUIRE_GL") == "1"
#: Set by .ci/run, which installs the extras: then the extras' tests may not skip either.
REQUIRE_EXTRAS = os.environ.get("DEFORMGL_REQUIRE_EXTRAS") == "1"
TESTS = Path(__file__).parent
# The tests of the studies import `studies` (the repository's studies/ folder, not in the wheel):
# the repository root goes last on the path, so that `deformgl` stays the installed package (the
# README installs the wheel, not the checkout; a root put first would shadow it).
if str(TESTS.parent) not in sys.path:
    sys.path.append(str(TESTS.parent))
GOLDEN_DIR = TESTS / "golden"
OUTPUT_DIR = TESTS / "output"


#: Tests that create a GL context without the ctx fixture (node-id prefixes).
GL_WITHOUT_CTX = (
    "tests/test_cli.py::",
    "tests/test_context.py::",
    "tests/test_api.py::test_a_body_releases_the_context_it_made",
    "tests/test_installed.py::",
    "tests/test_multigrid.py::test_the_multigrid_bench_prints_its_iteration_table",  # (the bench makes its own)
    "tests/test_doc_pictures.py::test_the_picture_is_what_its_command_prints",  # (the CLI's own)
    "tests/test_animation.py::test_an_animation_camera_that_misses_the_body_is_refused_before_the_run",
)
#: Tests taking more than ~3 s on 2 cores, with their fixtures' setup (node-id prefixes; measured
#: with ``pytest --durations=40``).
SLOW = (
    "tests/test_installed.py::",  # builds and installs the wheel
    "tests/test_scene_sim.py::test_finer_cloths_are_the_same_cloth[2048]",
    "tests/test_golden.py::test_cloth_on_sphere_matches_golden[rk4-feedback]",
    "tests/test_golden.py::test_cloth_on_sphere_matches_golden[verlet-fragment]",
    "tests/test_bench.py::test_bench_studies_print_their_tables_and_write_csv_json_and_the_chart",
    "tests/test_sweep.py::test_bench_trade_on_dask_workers",  # the quick trade study twice, ~30 s
    "tests/test_budget.py::test_the_estimate_is_within_30_percent_of_the_measured_peak",  # 35-55 s each
    "tests/test_budget.py::test_the_mesh_estimate_bounds_the_voxelized_grid",  # ~15 s
    "tests/test_tissue.py::test_no_cell_inverts_in_the_quick_inversion_runs",  # ~19 s
    "tests/test_glslang.py::test_the_covering_set_holds_every_value_triple",  # ~30 s
    "tests/test_materials.py::test_the_jelly_scene_is_a_material_scene_at_any_resolution",  # ~15-20 s
    "tests/test_plugin.py::test_plugin_update_pass_fail_and_a_second_accepted_baseline",  # ~9 s
    "tests/test_bending.py::test_gpu_backends_match_numpy[True-implicit-euler-0.002-backends3]",  # ~8 s
    "tests/test_tissue.py::test_the_dt_check_predicts_the_limit_at_high_nu",  # ~8 s
    "tests/test_implicit.py::test_scaled_warm_start_keeps_truncated_cg_on_the_equilibrium",  # ~7 s
    "tests/test_bending.py::test_flap_scene_settles_at_the_static_equilibrium",  # ~7 s
    # several nodes per fragment: every block shape is a program of its own (~0.4-1 s each to
    # compile on llvmpipe without Mesa's shader cache); the README's run keeps one case of each kind
    "tests/test_blocked.py::test_springs_bit_identical_in_every_block[holed-all]",  # ~7 s
    "tests/test_blocked.py::test_thin_grids_bit_identical[3x1x1]",  # ~4 s each
    "tests/test_blocked.py::test_thin_grids_bit_identical[1x1x1]",
    "tests/test_blocked.py::test_lattice_with_cells_bit_identical[box-0.45-default]",  # ~5 s
    "tests/test_blocked.py::test_lattice_with_cells_bit_identical[box-0.25-default]",  # ~4 s
    "tests/test_blocked.py::test_lattice_with_cells_bit_identical[holed-0.25-all]",  # ~8 s each
    "tests/test_blocked.py::test_lattice_with_cells_bit_identical[box-0.45-all]",
    "tests/test_blocked.py::test_spring_weights_bit_identical[levels-as-texture]",  # ~3 s
    # the README's run at 485 s with a cold Mesa shader cache (2026-12-06): these 6-8 s runs have
    # faster siblings there (the other bending case, the liver on the GPU backends, the flap on
    # the other integrators, the cantilever's other rows)
    "tests/test_bending.py::test_gpu_backends_match_numpy[False-implicit-euler-0.002-backends3]",  # ~8 s
    "tests/test_tissue.py::test_liver_scene_runs_on_every_backend_and_integrator[numpy-implicit-euler]",  # ~7 s
    "tests/test_bending.py::test_flap_scene_from_the_cli[fragment-implicit-euler-0.015-100]",  # ~6 s
    "tests/test_equilibrium.py::test_the_cantilever_stops_within_one_percent_of_its_1_s_sag[rk4-0.0001]",  # ~6 s
)
#: (test file, fixture): the tests of that file using that fixture are slow (its setup is).
SLOW_FIXTURES = (
    ("tests/test_trade.py::", "report"),  # the quick trade study, ~12 s
)


#: marker -> (module(s) it imports, the extra that installs them)
EXTRAS = {
    "plot": ("matplotlib", "plot"),
    "fem": (("skfem", "pyamg", "tetgen", "pymeshfix", "manifold3d"), "fem"),
    "video": ("imageio_ffmpeg", "video"),
    "sweep": ("distributed", "sweep"),
    "peers": ("taichi", "peers"),  # (tests/test_peers.py also skips per peer)
    "io": (("meshio", "h5py", "pygltflib"), "io"),
    "usd": ("pxr", "usd"),
}
#: marker -> (executables, any of which will do; the Debian package that installs them)
TOOLS = {
    "glslang": (("glslangValidator",), "glslang-tools"),
    "chromium": (("chromium", "chromium-browser"), "chromium"),
}
#: marker -> (a file the test needs, the command that installs it)
FILES = {
    "three": (TESTS.parent / "examples" / "web" / "three" / "node_modules" / "three" / "build" / "three.module.js",
              "npm ci --prefix examples/web/three"),
}


def missing_extra(marker: str) -> str | None:
    """The skip reason of a test carrying ``marker`` when its extra or tool is missing, else None.
    Every reason says "optional extra" (the word :func:`pytest_sessionfinish` allows)."""
    if marker in EXTRAS:
        modules, extra = EXTRAS[marker]
        for module in (modules,) if isinstance(modules, str) else modules:
            if importlib.util.find_spec(module) is None:
                return f"optional extra '{extra}': {module} is not installed (pip install '.[{extra}]')"
    elif marker in TOOLS:
        exes, package = TOOLS[marker]
        if not any(shutil.which(exe) for exe in exes):
            return f"optional extra: {exes[0]} (apt-get install {package}) not installed"
    elif marker in FILES:
        path, command = FILES[marker]
        if not path.is_file():
            return f"optional extra: three.js is not installed ({command})"
    return None


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    missing = {m: missing_extra(m) for m in (*EXTRAS, *TOOLS, *FILES)}
    for item in items:
        for marker, reason in missing.items():
            if reason and item.get_closest_marker(marker) is not None:
                item.add_marker(pytest.mark.skip(reason=reason))
        nodeid = item.nodeid.replace("\\", "/")
        if "ctx" in getattr(item, "fixturenames", ()) or nodeid.startswith(GL_WITHOUT_CTX):
            item.add_marker(pytest.mark.gl)
        if nodeid.startswith(SLOW) or any(nodeid.startswith(file) and fixture in getattr(item, "fixturenames", ())
                                          for file, fixture in SLOW_FIXTURES):
            item.add_marker(pytest.mark.slow)


@pytest.fixture(autouse=True)
def _no_gl_unless_marked(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch):
    """A test not marked gl cannot create a GL context, here or in a subprocess."""
    if request.node.get_closest_marker("gl") is None:
        import moderngl

        def refuse(*args, **kwargs):
            raise RuntimeError(f"{request.node.nodeid} is not marked gl but creates a GL context: "
                               "use the ctx fixture or list it in conftest.GL_WITHOUT_CTX")

        monkeypatch.setattr(moderngl, "create_standalone_context", refuse)
        monkeypatch.setenv("__EGL_VENDOR_LIBRARY_FILENAMES", "/nonexistent/no-gl-for-this-test.json")
    yield


_KNOWN_VARIANTS: set | None = None


@pytest.fixture(autouse=True)
def _programs_are_known_variants(monkeypatch: pytest.MonkeyPatch):
    """Every program a test builds must be one of the variants deformgl.pack.variants enumerates
    (and tests/test_glslang.py validates): a new define combination cannot escape the check."""
    from deformgl.gl.programs import Program

    built: list[tuple] = []
    original = Program.__init__

    def recording(self, ctx, vertex, fragment=None, *, defines=None, varyings=(), **kw):
        # (a program with a term chunk given as text, not shipped in shaders/ — a test's or an
        # application's own term, deformgl.sim.terms — is not the pack's to enumerate)
        if not any(name != "terms/active.glsl" for name in (kw.get("chunks") or {})):
            built.append((vertex, fragment, dict(defines or {}), tuple(varyings)))
        original(self, ctx, vertex, fragment, defines=defines, varyings=varyings, **kw)

    monkeypatch.setattr(Program, "__init__", recording)
    yield
    if built:
        global _KNOWN_VARIANTS
        from deformgl.pack.variants import all_variants, variant_key

        if _KNOWN_VARIANTS is None:
            _KNOWN_VARIANTS = {v.key for v in all_variants()}
        unknown = {variant_key(*b) for b in built} - _KNOWN_VARIANTS
        assert not unknown, (f"programs built that deformgl.pack.variants does not enumerate (so glslang "
                             f"never checks them): {sorted(map(str, unknown))[:5]}")


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    if not (REQUIRE_GL or REQUIRE_EXTRAS):
        return
    reporter = session.config.pluginmanager.get_plugin("terminalreporter")
    # tests of optional extras (peers, plot) may skip unless DEFORMGL_REQUIRE_EXTRAS=1; nothing else may
    skipped = len([r for r in reporter.stats.get("skipped", [])
                   if REQUIRE_EXTRAS or "optional extra" not in str(r.longrepr)]) if reporter else 0
    if skipped:
        if reporter:
            flags = " ".join(f for f, on in (("DEFORMGL_REQUIRE_GL=1", REQUIRE_GL),
                                             ("DEFORMGL_REQUIRE_EXTRAS=1", REQUIRE_EXTRAS)) if on)
            reporter.write_line(f"{flags}: {skipped} test(s) were skipped; failing", red=True)
        session.exitstatus = 1


@pytest.fixture(scope="session")
def ctx():
    from deformgl.gl.context import create_context
    from deformgl.errors import GLError

    try:
        context = create_context()
    except GLError as exc:
        if REQUIRE_GL:
            pytest.fail(f"no GL context and DEFORMGL_REQUIRE_GL=1: {exc}")
        pytest.skip(f"no GL context: {exc}")
    yield context
    context.release()


@pytest.fixture
def golden(request: pytest.FixtureRequest):
    """``golden(image, "name", **tolerances)`` compares a uint8 render with ``tests/golden/name.png``.

    The ``deformgl_golden`` fixture of the deformgl pytest plugin (deformgl/testing/plugin.py,
    loaded by its entry point; it owns ``--update-goldens`` and ``--golden-failures``) with the
    project's folders (failure images in ``tests/output/``) and the same-renderer tolerances
    (:data:`deformgl.testing.imagediff.SAME_RENDERER`: the goldens are llvmpipe's, which renders
    byte-identical images run to run and across thread counts).
    """
    from deformgl.testing.imagediff import SAME_RENDERER
    from deformgl.testing.plugin import make_checker

    return make_checker(request, GOLDEN_DIR, OUTPUT_DIR, **SAME_RENDERER)
