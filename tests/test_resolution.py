"""The resolution study (issue 12, item 4): the FEM-checked cantilever at two grids x two
integrators x two dts, its three errors kept apart, the front, and the CLI."""

from __future__ import annotations

import dataclasses

import pytest

from deformgl.bench.fem import WORKLOADS, lattice_case, lattice_value
from deformgl.bench.resolution import FEM_TIP, ResolutionReport, resolution_study

pytestmark = pytest.mark.slow  # the quick study: ~15 s on 2 cores


@pytest.fixture(scope="module")
def report(ctx):
    return resolution_study(ctx, quick=True)


def test_every_configuration_is_measured(report):
    keys = {(r.across, r.integrator, r.fraction) for r in report.rows}
    assert keys == {(n, i, f) for n in (2, 3) for i in ("verlet", "semi-implicit") for f in (0.5, 0.9)}
    assert all(r.ms_per_step > 0 and r.ms_per_sim_s == pytest.approx(r.ms_per_step / r.dt) for r in report.rows)


def test_the_three_errors_are_kept_apart(report):
    for n in (2, 3):
        static = lattice_value(lattice_case(WORKLOADS["cantilever"], n))
        rows = [r for r in report.rows if r.across == n]
        for r in rows:  # discretisation: the static lattice against FEM, whatever the dt
            assert r.discretisation == pytest.approx(abs(static - FEM_TIP) / FEM_TIP, rel=1e-9)
            assert r.error == pytest.approx(r.discretisation + r.time_stepping + r.float32)
            assert r.float32 < 1e-3          # float32 drift of the fragment backend
            assert 0 < r.time_stepping < 5e-3
        for name in ("verlet", "semi-implicit"):  # the time-stepping error grows with dt
            small, large = sorted((r for r in rows if r.integrator == name), key=lambda r: r.dt)
            assert large.time_stepping > 1.3 * small.time_stepping
    coarse = [r.discretisation for r in report.rows if r.across == 2]
    fine = [r.discretisation for r in report.rows if r.across == 3]
    assert min(coarse) > 2 * max(fine) > 0.2   # 46 % and 19 % short of FEM (python -m studies.accuracy)


def test_the_front_names_the_cheapest_grid_for_an_accuracy(report):
    front = report.front()
    assert front and all(a.ms_per_sim_s <= b.ms_per_sim_s and a.error > b.error
                         for a, b in zip(front, front[1:]))
    best = report.cheapest(0.3)
    assert best is not None and best.across == 3
    assert report.cheapest(0.01) is None       # needs a finer grid than measured
    text = report.format()
    assert "Pareto front" in text and "3 nodes across" in text


def test_resolution_is_an_option_of_bench_trade_only(capsys):
    from deformgl.cli import main

    assert main(["bench", "sim", "--resolution"]) == 2
    assert "--resolution" in capsys.readouterr().err


def test_bench_trade_resolution_prints_the_study_and_writes_its_files(ctx, tmp_path, capsys):
    """(``ctx``: a GL test; the command makes its own context.)"""
    import json

    from deformgl.cli import main

    assert main(["bench", "trade", "--resolution", "--quick", "--quiet", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "Pareto front" in out and "discr." in out and "float32" in out
    rows = json.loads((tmp_path / "resolution.json").read_text())["rows"]
    assert len(rows) == 8 and {r["across"] for r in rows} == {2, 3}
    again = ResolutionReport.read_json(tmp_path / "resolution.json")  # (the written report reads back)
    assert [dataclasses.asdict(r) for r in again.rows] == rows and again.fem_tip > 0
    assert (tmp_path / "resolution.csv").read_text().startswith("across,spacing,nodes")
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        return
    assert (tmp_path / "resolution.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
