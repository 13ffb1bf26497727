"""The speed/accuracy trade study (``bench trade``): Pareto front, convergence, backends agree,
output files. Timings are never asserted (shared CI machines), only that they are positive."""

from __future__ import annotations

import dataclasses
import math
import re
import sys
from dataclasses import dataclass

import numpy as np
import pytest

from deformgl.errors import DeformglError
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.integrators import EXPLICIT_INTEGRATORS
from deformgl.sim.springs import cloth
from deformgl.bench.trade import (TradeReport, TradeRow, Workload, pareto_front, read_csv,
                            trade_study)

VOLUME, CLOTH = "volume under a drag", "cloth on a sphere"


def test_pareto_front_on_hand_points():
    points = [(1.0, 10.0), (2.0, 5.0), (2.0, 6.0), (3.0, 5.0), (4.0, 1.0), (0.5, 20.0),
              (5.0, 0.5), (3.5, 0.9), (6.0, 0.5), (0.5, 30.0), (7.0, math.nan),
              (math.inf, 0.01), (2.0, 5.0)]
    front = pareto_front(points)
    # (2, 6), (3, 5), (4, 1), (6, 0.5), (0.5, 30) are dominated; non-finite points dropped;
    # the duplicate (2, 5) is kept once
    assert front == [(0.5, 20.0), (1.0, 10.0), (2.0, 5.0), (3.5, 0.9), (5.0, 0.5)]
    assert pareto_front([]) == []
    assert pareto_front([(1.0, 1.0)]) == [(1.0, 1.0)]


def test_pareto_front_with_a_key():
    @dataclass
    class P:
        name: str
        cost: float
        error: float

    pts = [P("a", 3, 1), P("b", 1, 3), P("c", 2, 4), P("d", 2, 2)]
    front = pareto_front(pts, key=lambda p: (p.cost, p.error))
    assert [p.name for p in front] == ["b", "d", "a"]


@pytest.fixture(scope="module")
def report(ctx) -> TradeReport:
    return trade_study(ctx, quick=True)


def rows_of(report, workload, backend, integrator):
    return sorted((r for r in report.rows if (r.workload, r.backend, r.integrator)
                   == (workload, backend, integrator)), key=lambda r: -r.dt)  # largest dt first


def test_quick_study_errors_are_finite_and_converge(report):
    assert {r.backend for r in report.rows} == {"fragment", "feedback", "numpy"}
    assert {r.workload for r in report.rows} == {VOLUME, CLOTH}
    for r in report.rows:
        assert r.status == "ok", r
        assert all(math.isfinite(v) for v in (r.rms, r.max, r.dt, r.limit))
        assert 0 < r.rms <= r.max and r.ms_per_step > 0
        assert r.ms_per_sim_s == pytest.approx(r.ms_per_step / r.dt)
        assert r.dt * r.steps == pytest.approx(report.sim_time) and r.dt <= 0.6 * r.limit
    ratio = {}
    for backend in ("fragment", "feedback", "numpy"):
        for name in EXPLICIT_INTEGRATORS:
            big, small = rows_of(report, VOLUME, backend, name)
            assert small.dt < big.dt / 3.5
            ratio[backend, name] = big.rms / small.rms
            if name in ("rk4", "verlet"):
                assert ratio[backend, name] > 2.0, (backend, name)  # error falls with dt
    # dt 4x smaller: semi-implicit (first order) error falls ~4x; rk4 (fourth order) ~200x in
    # float64 (float32 positions floor the GPU backends near 3e-7 spacings)
    assert 2.0 < ratio["numpy", "semi-implicit"] < 8.0
    assert ratio["numpy", "rk4"] > 10 * ratio["numpy", "semi-implicit"]
    assert ratio["fragment", "rk4"] > 4 * ratio["fragment", "semi-implicit"]
    # the reference resolves the smooth volume far below every measured error
    ref = {r.workload: r for r in report.references}
    assert ref[VOLUME].error < 0.05 * min(r.rms for r in report.rows if r.workload == VOLUME)


def test_gpu_backends_agree_with_numpy_within_float32_tolerance(report):
    """Same integrator, same dt: the GPU result differs from the float64 one by float32
    roundoff, so its error does too. Tolerance, in grid spacings: 1e-4 on the smooth volume
    (observed <= 3e-5; bound ~ steps x eps32 x |x| / h = 400 x 1.2e-7 x 5); on the cloth the
    sphere contact amplifies roundoff (a node is in or out of the sphere a step earlier), so
    10 % of the error plus 1e-4."""
    for r in report.rows:
        if r.backend == "numpy":
            assert math.isnan(r.vs_numpy)
            continue
        ref = next(n for n in report.rows if n.backend == "numpy" and
                   (n.workload, n.integrator, n.steps) == (r.workload, r.integrator, r.steps))
        tol = 1e-4 if r.workload == VOLUME else 0.1 * ref.rms + 1e-4
        assert abs(r.rms - ref.rms) <= tol, (r, ref.rms)
        assert abs(r.max - ref.max) <= tol + (0 if r.workload == VOLUME else 0.1 * ref.max)
        assert r.vs_numpy < (1e-4 if r.workload == VOLUME else 1e-2)


def same(a: TradeRow, b: TradeRow) -> bool:
    return all(x == y or (isinstance(x, float) and math.isnan(x) and math.isnan(y))
               for x, y in zip(dataclasses.astuple(a), dataclasses.astuple(b)))


def test_csv_and_json_round_trip(report, tmp_path):
    report.write_csv(tmp_path / "trade.csv")
    report.write_json(tmp_path / "trade.json")
    back = read_csv(tmp_path / "trade.csv")
    assert len(back) == len(report.rows) and all(map(same, back, report.rows))
    again = TradeReport.read_json(tmp_path / "trade.json")
    assert len(again.rows) == len(report.rows) and all(map(same, again.rows, report.rows))
    assert (again.machine, again.date, again.references) == \
        (report.machine, report.date, report.references)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["trade.csv", "trade.json"]  # no temps


@pytest.mark.plot
def test_chart_is_a_png(report, tmp_path):
    report.write_chart(tmp_path / "trade.png")
    data = (tmp_path / "trade.png").read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000


def test_chart_without_matplotlib_names_the_extra(report, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    monkeypatch.setitem(sys.modules, "matplotlib.figure", None)
    monkeypatch.setitem(sys.modules, "matplotlib.backends.backend_agg", None)
    with pytest.raises(DeformglError, match=re.escape("pip install 'deformgl[plot]'")):
        report.write_chart(tmp_path / "trade.png")
    assert not list(tmp_path.iterdir())


def test_front_in_words(report):
    text = report.format()
    assert "renderer:" in text and "Pareto front" in text
    for workload in (VOLUME, CLOTH):
        for backend in ("fragment", "feedback", "numpy"):
            words = report.front_words(workload, backend)
            assert words in " ".join(text.split()) or words.split(":")[0] in text
            assert words.startswith(f"{workload}, {backend} backend: for errors above ")
            assert any(f"use {name} at dt = " in words for name in EXPLICIT_INTEGRATORS)
            front = report.front(workload, backend)
            # the thresholds: the error reached by the last point of each integrator's stretch
            ends = [r for k, r in enumerate(front)
                    if k + 1 == len(front) or front[k + 1].integrator != r.integrator]
            for r in ends:
                assert f"{r.error:.1e}" in words and f"use {r.integrator} at" in words
            assert re.search(r"more accurate than \d\.\de-0\d spacings", words)
            assert "ms per simulated second" in words
            costs = [r.cost for r in front]
            errors = [r.error for r in front]
            assert costs == sorted(costs) and errors == sorted(errors, reverse=True)


def test_unstable_runs_are_reported_not_dropped(ctx):
    fixed = np.zeros(9, bool)
    fixed[0] = True
    sheet = cloth(3, 3, 0.1, k_structural=10.0, k_shear=5.0, mass=0.01, fixed=fixed)  # undamped
    grid = NodeGrid(np.zeros(3), 0.1, np.ones((3, 1, 3), bool))
    rep = trade_study(ctx, backends=("numpy", "feedback"), fractions=(0.5, 4.0), quick=True,
                      workloads=[Workload("tiny cloth", sheet, grid, time=0.5)])
    status = {(r.backend, r.integrator, r.fraction <= 1): r.status for r in rep.rows}
    for backend in ("numpy", "feedback"):
        # forward Euler and midpoint have no stable dt without damping: one row each, no runs
        for name in ("euler", "midpoint"):
            assert [r.status for r in rep.rows if (r.backend, r.integrator) == (backend, name)] \
                == ["no stable dt"]
        for name in ("semi-implicit", "rk4", "verlet"):
            assert status[backend, name, True] == "ok"
            assert status[backend, name, False] == "diverged"  # 4x the limit blows up
    text = " ".join(rep.format().split())
    assert "euler no stable dt" in text and "| diverged" in text
    assert all(r.status == "ok" for r in rep.front("tiny cloth", "numpy"))
