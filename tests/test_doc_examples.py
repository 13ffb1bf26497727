"""Every Python example in the documentation runs in a test: each ```python block of README.md,
docs/*.md and examples/**/*.md is listed in RUN_BY with the test that executes it, and a new block
that no test runs fails here. The blocks whose test lives elsewhere are run there with their
asserts on the result (the API example by tests/test_api.py, the scene-graph example by
tests/test_graph_render.py); this file runs the rest."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
TESTS = ROOT / "tests"
BLOCK = re.compile(r"^```(?:python|py)[ \t]*\n(.*?)^```", re.S | re.M)

#: (document, index of its python block) -> "test file::test function" that executes it.
RUN_BY = {
    ("docs/API.md", 0): "tests/test_api.py::test_doc_example_runs",
    ("docs/SCENEGRAPH.md", 0): "tests/test_graph_render.py::test_the_docs_python_example_runs",
    ("docs/IMAGEDIFF.md", 0): "tests/test_doc_examples.py::test_the_imagediff_plugin_example_runs",
}


def documents() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), *sorted(p for p in (ROOT / "examples").rglob("*.md") if "node_modules" not in p.parts)]


def python_blocks() -> dict[tuple[str, int], str]:
    return {(doc.relative_to(ROOT).as_posix(), i): code
            for doc in documents() for i, code in enumerate(BLOCK.findall(doc.read_text(encoding="utf-8")))}


def block(doc: str, index: int = 0) -> str:
    return python_blocks()[(doc, index)]


def test_every_python_block_is_run_by_a_test():
    blocks = python_blocks()
    assert set(blocks) == set(RUN_BY), (f"python blocks no test runs: {sorted(set(blocks) - set(RUN_BY))}; "
                                        f"listed but gone: {sorted(set(RUN_BY) - set(blocks))}")
    for (doc, _), test in RUN_BY.items():
        file, name = test.split("::")
        text = (ROOT / file).read_text(encoding="utf-8")
        funcs = {f.name: f for f in ast.walk(ast.parse(text)) if isinstance(f, ast.FunctionDef)}
        assert name in funcs, f"{test} does not exist"
        source = ast.get_source_segment(text, funcs[name]) or ""
        # the test file reads the document and the test executes what it read
        assert Path(doc).name in text and "exec(" in source, f"{test} does not run {doc}'s example"


def test_every_block_compiles():
    for (doc, i), code in python_blocks().items():
        compile(code, f"{doc} block {i}", "exec")


def test_the_imagediff_plugin_example_runs(tmp_path):
    """docs/IMAGEDIFF.md's test, run with the plugin's checker (what ``deformgl_golden`` gives):
    the first run writes the baselines (``--update-goldens``), the second compares and passes,
    a changed image fails."""
    from deformgl.testing import plugin

    code = block("docs/IMAGEDIFF.md")
    assert "def test_my_render(deformgl_golden)" in code and hasattr(plugin, "deformgl_golden")
    y, x = np.mgrid[0:40, 0:60]
    picture = np.stack([x * 4 % 256, y * 6 % 256, (x + y) % 256], axis=2).astype(np.uint8)
    namespace: dict = {"render": lambda: picture}
    exec(compile(code, "IMAGEDIFF.md", "exec"), namespace)
    golden, failures = tmp_path / "golden", tmp_path / "failures"

    def checker(update: bool) -> plugin.GoldenChecker:
        return plugin.GoldenChecker(golden, failures, update=update, default_name="test_my_render")

    namespace["test_my_render"](checker(update=True))
    assert sorted(p.name for p in golden.iterdir()) == ["closeup.png", "test_my_render.png"]
    namespace["test_my_render"](checker(update=False))
    assert not failures.exists()
    namespace["render"] = lambda: np.ascontiguousarray(picture[:, ::-1])
    with pytest.raises(AssertionError):
        namespace["test_my_render"](checker(update=False))
