"""docs/EQUATIONS.md stays true: every test, GLSL function and Python symbol its tables name exists.

Each table row maps one paper equation (or integrator) to ``module.symbol`` (Python), to
``shaders/file:function`` (GLSL) and to ``tests/file.py::test_name``. When code moves, these
tests name the row to fix.
"""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
EQUATIONS = ROOT / "docs" / "EQUATIONS.md"
COLUMNS = ["eq.", "what", "Python", "GLSL", "test"]
PAPERS = ["Mosegaard & Sørensen 2005", "Movania & Feng 2012", "Knuth, Kohlhammer & Kuijper"]
_CODE = re.compile(r"`([^`]+)`")


def _cells(line: str) -> list[str]:
    return [c.strip() for c in re.split(r"(?<!\\)\|", line.strip().strip("|"))]


def equation_tables() -> dict[str, list[dict[str, str]]]:
    """Rows of each ``## <paper>`` section's table, keyed by column name."""
    tables: dict[str, list[dict[str, str]]] = {}
    section = None
    header: list[str] | None = None
    for line in EQUATIONS.read_text(encoding="utf-8").splitlines():
        if line.startswith("## "):
            section, header = line[3:].strip(), None
            continue
        if not line.startswith("|") or section is None:
            header = None if not line.startswith("|") else header
            continue
        cells = _cells(line)
        if header is None:
            header = cells
        elif set("".join(cells)) <= set("-: "):
            continue
        elif header == COLUMNS:
            tables.setdefault(section, []).append(dict(zip(header, cells)))
    return tables


def _names(cell: str) -> list[str]:
    return _CODE.findall(cell)


def _rows():
    for paper, rows in equation_tables().items():
        for row in rows:
            yield pytest.param(paper, row, id=f"{paper} {row['eq.']} {row['what'][:30]}")


def test_one_table_per_paper_with_the_five_columns():
    tables = equation_tables()
    assert sorted(tables) == sorted(PAPERS)
    for paper, rows in tables.items():
        assert len(rows) >= 4, paper
        for row in rows:
            assert _names(row["test"]), f"{paper} {row['eq.']}: no test named"
            assert _names(row["Python"]), f"{paper} {row['eq.']}: no Python symbol named"


def test_the_lost_formulas_have_the_sections_the_code_points_at():
    """Comments cite these headings ('docs/EQUATIONS.md, "Stability"')."""
    text = EQUATIONS.read_text(encoding="utf-8")
    for heading in ("Spring force and damping", "The five integrators", "Constraints after the step",
                    "Stability"):
        assert re.search(rf"^#+ {re.escape(heading)}", text, re.MULTILINE), heading


@pytest.mark.parametrize("paper, row", list(_rows()))
def test_named_tests_exist(paper, row):
    for name in _names(row["test"]):
        path, _, func = name.partition("::")
        file = ROOT / path
        assert file.is_file(), f"{paper} eq. {row['eq.']}: no file {path}"
        assert re.search(rf"^def {re.escape(func)}\(", file.read_text(encoding="utf-8"), re.MULTILINE), \
            f"{paper} eq. {row['eq.']}: no {func} in {path}"


@pytest.mark.parametrize("paper, row", list(_rows()))
def test_named_glsl_functions_exist(paper, row):
    for name in _names(row["GLSL"]):
        path, _, func = name.partition(":")
        file = ROOT / path
        assert file.is_file(), f"{paper} eq. {row['eq.']}: no file {path}"
        pattern = rf"^[ \t]*\w+[ \t]+{re.escape(func)}[ \t]*\([^;]*?\)\s*\{{"
        assert re.search(pattern, file.read_text(encoding="utf-8"), re.MULTILINE), \
            f"{paper} eq. {row['eq.']}: no function {func} in {path}"


def resolve(dotted: str) -> object:
    """Import the longest module prefix of ``dotted`` and walk the rest as attributes."""
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ModuleNotFoundError:
            continue
        for attr in parts[i:]:
            obj = getattr(obj, attr)
        return obj
    raise ModuleNotFoundError(dotted)


@pytest.mark.parametrize("paper, row", list(_rows()))
def test_named_python_symbols_resolve(paper, row):
    for name in _names(row["Python"]):
        try:
            resolve(name)
        except (ImportError, AttributeError) as e:
            pytest.fail(f"{paper} eq. {row['eq.']}: {name} does not resolve ({e})")
