"""The package's shape is a fact too: layers point down, no import cycle, no oversized module."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import grimp
import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "deformgl"
MAX_LINES = 550  # "no module over ~500 lines"


def test_layers_point_down():
    """The import-linter contract in pyproject.toml: cli -> bench -> scene -> trilinear -> render ->
    mapping -> sim -> grid -> gl -> base, nothing importing upwards."""
    exe = shutil.which("lint-imports", path=str(Path(sys.executable).parent)) or shutil.which("lint-imports")
    assert exe, "lint-imports (import-linter, in the 'test' extra) is not installed"
    done = subprocess.run([exe, "--no-cache", "--config", str(ROOT / "pyproject.toml")], cwd=ROOT,
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-2000:]
    assert "KEPT" in done.stdout and "BROKEN" not in done.stdout


def _cycle(graph: grimp.ImportGraph) -> list[str] | None:
    """A module-level import cycle (imports inside functions included), or None."""
    colour: dict[str, int] = {}
    stack: list[str] = []

    def visit(module: str) -> list[str] | None:
        colour[module] = 1
        stack.append(module)
        for nxt in sorted(graph.find_modules_directly_imported_by(module)):
            if colour.get(nxt) == 1:
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in colour and (found := visit(nxt)):
                return found
        stack.pop()
        colour[module] = 2
        return None

    for module in sorted(graph.modules):
        if module not in colour and (found := visit(module)):
            return found
    return None


def test_no_import_cycle():
    graph = grimp.build_graph("deformgl", cache_dir=None)
    cycle = _cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_cycle_finder_finds_a_cycle():
    graph = grimp.ImportGraph()
    for name in ("p", "p.a", "p.b", "p.c"):
        graph.add_module(name)
    graph.add_import(importer="p.a", imported="p.b")
    graph.add_import(importer="p.b", imported="p.c")
    assert _cycle(graph) is None
    graph.add_import(importer="p.c", imported="p.a")
    assert _cycle(graph) == ["p.a", "p.b", "p.c", "p.a"]


STUDIES = ROOT / "studies"
#: What the wheel may hold of benchmark code (issue 43, item 5): ``deformgl bench sim|trade``.
#: The FEM references of ``bench trade``'s accuracy rows (``bench/fem.py``, the 'fem' extra's
#: module) are counted apart.
BENCH_BUDGET = 2500


@pytest.mark.parametrize("path", sorted(PACKAGE.rglob("*.py")) + sorted(STUDIES.rglob("*.py")),
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_module_size(path: Path):
    lines = len(path.read_text(encoding="utf-8").splitlines())
    assert lines <= MAX_LINES, f"{path.relative_to(ROOT)} has {lines} lines; split it by what it does"


def test_no_benchmark_or_study_module_shares_a_name():
    """A module's name says what it does, once: no module of the studies or of deformgl/bench has
    the basename of another module in the package or the studies (issue 43, item 4)."""
    every = [p for p in sorted(PACKAGE.rglob("*.py")) + sorted(STUDIES.rglob("*.py"))
             if p.name not in ("__init__.py", "__main__.py")]
    names = [p.name for p in every]
    ours = [p for p in every if STUDIES in p.parents or PACKAGE / "bench" in p.parents]
    twice = sorted(str(p.relative_to(ROOT)) for p in ours if names.count(p.name) > 1)
    assert not twice, twice


def test_the_wheel_holds_at_most_its_budget_of_benchmark_code():
    """deformgl/bench (but its FEM references), the bench CLI and the trade's Dask tasks: the
    studies live in the repository's studies/, outside the package."""
    files = [p for p in PACKAGE.joinpath("bench").rglob("*.py") if p.name != "fem.py"]
    files += [PACKAGE / "cli_bench.py", PACKAGE / "sweep" / "trade_tasks.py"]
    lines = sum(len(p.read_text(encoding="utf-8").splitlines()) for p in files)
    assert lines <= BENCH_BUDGET, f"the wheel's benchmark code is {lines} lines (budget {BENCH_BUDGET})"
    import tomllib

    packages = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["setuptools"]["packages"]
    assert all(p == "deformgl" or p.startswith("deformgl.") for p in packages), packages


def test_the_float64_model_needs_no_gl():
    """The spring system, its terms' float64 forms and the NumPy solvers import no GL: a CPU-only
    user (the "numpy" backend, the studies' float64 references) loads no moderngl; a term's GPU
    passes are imported when a GPU backend builds them."""
    code = ("import sys; import deformgl.sim.springs, deformgl.sim.integrators, deformgl.sim.xpbd, "
            "deformgl.sim.implicit, deformgl.sim.terms.volume.xpbd_form, deformgl.sim.terms.bending; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('moderngl', 'glcontext') "
            "or m in ('deformgl.gl.programs', 'deformgl.gl.resources', 'deformgl.gl.context')))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]", done.stdout


def test_subpackages_mirror_the_shaders():
    """Every shader folder has the package folder that uses it (shaders/sim -> deformgl/sim, ...)."""
    shader_dirs = {p.name for p in (ROOT / "shaders").iterdir() if p.is_dir() and p.name != "lib"}
    homes = {"census": "sim", "feedback": "sim/backends", "terms": "sim/terms"}
    for name in shader_dirs:
        assert (PACKAGE / homes.get(name, name)).is_dir(), f"shaders/{name} has no package folder"


def test_every_dotted_reference_in_the_docstrings_resolves():
    """``:func:`deformgl.x.y``` (and ``studies.x.y``) names in code comments and docstrings follow
    the modules when they move (the flat modules' old paths such as ``deformgl.springs.forces`` fail)."""
    import importlib
    import re

    missing = set()
    for path in sorted((ROOT / "deformgl").rglob("*.py")) + sorted(STUDIES.rglob("*.py")):
        for m in re.finditer(r"`~?((?:deformgl|studies)(?:\.\w+)+)`", path.read_text(encoding="utf-8")):
            parts = m.group(1).split(".")
            for i in range(len(parts), 0, -1):
                try:
                    obj = importlib.import_module(".".join(parts[:i]))
                except ImportError:
                    continue
                try:
                    for attr in parts[i:]:
                        obj = getattr(obj, attr)
                except AttributeError:
                    missing.add(f"{path.relative_to(ROOT)}: {m.group(1)}")
                break
    assert not missing, sorted(missing)
