"""``bench scaling``: the power-law fit, and a tiny real study (content only: timings are never asserted)."""

import json
import math

import moderngl
import numpy as np
import pytest

from deformgl.grid import nodes as grid_module
from deformgl.bench.sim_speed import block_system
from deformgl.sim.backends.feedback import FeedbackSimulation
from studies.scaling import UPPER_NODES, ScalingReport, ScalingRow, bench_scaling, fit_power_law


def test_fit_recovers_an_exact_power_law():
    nodes = [4096, 19683, 64000, 262144, 1_000_000]
    fit = fit_power_law(nodes, [3e-4 * n ** 0.93 for n in nodes])
    assert fit.exponent == pytest.approx(0.93, abs=1e-9)
    assert fit.prefactor == pytest.approx(3e-4, rel=1e-9)
    assert fit.points == 5 and fit.rms_log < 1e-9


def test_fit_tolerates_noise():
    rng = np.random.default_rng(7)
    nodes = np.geomspace(4e3, 1e6, 12)
    ms = 1e-4 * nodes * np.exp(rng.normal(0.0, 0.1, nodes.size))  # about 10 % scatter
    fit = fit_power_law(nodes, ms)
    assert fit.exponent == pytest.approx(1.0, abs=0.05)
    assert 0.03 < fit.rms_log < 0.2


def test_fit_rejects_what_it_cannot_fit():
    with pytest.raises(ValueError, match="two distinct"):
        fit_power_law([1000, 1000], [1.0, 2.0])
    with pytest.raises(ValueError, match="positive"):
        fit_power_law([1000, 2000], [1.0, 0.0])


def test_fits_use_the_upper_sizes_only_when_asked():
    rows = [ScalingRow("b", (1, 1, n), n, 1, 1e-5 * n + 0.5) for n in (4096, 20000, 64000, 262144, 10**6)]
    report = ScalingReport(rows, "machine: test", "verlet", 3)
    all_sizes, upper = report.fits()["b"], report.fits(UPPER_NODES)["b"]
    assert all_sizes is not None and upper is not None and upper.points == 3
    # a constant per-step overhead bends the small sizes: the upper fit is nearer 1
    assert all_sizes.exponent < upper.exponent < 1.0
    assert "exponent b" in report.format()


def test_tiny_study_times_every_backend_and_counts_its_memory(ctx):
    labels = []
    report = bench_scaling(ctx, sizes=(6, (5, 4, 3)), node_steps=200, max_steps=3, repeats=2,
                           progress=labels.append)
    assert [(r.backend, r.nodes) for r in report.rows] == [
        ("foundation", 216), ("fragment", 216), ("feedback", 216),
        ("foundation", 60), ("fragment", 60), ("feedback", 60)]
    setups = [label for label in labels if label.startswith("setup")]
    assert len(setups) == 6 and "6x6x6" in setups[0] and labels[-1] == "timing round 2/2"
    for r in report.rows:
        assert r.skipped is None and r.steps == {216: 2, 60: 3}[r.nodes]  # node_steps / nodes, 2..3
        assert r.ms_per_step is not None and math.isfinite(r.ms_per_step) and r.ms_per_step > 0
        assert r.setup_s is not None and r.setup_s > 0
        assert r.ns_per_node_step == pytest.approx(r.ms_per_step * 1e6 / r.nodes)
    foundation = {r.nodes: r.bytes_per_node for r in report.rows if r.backend == "foundation"}
    # compact layout 16 texels wide: 216 nodes -> 14 rows; node + 3 state RGBA32F (full blocks
    # are dense: no neighbour-index layers)
    assert foundation[216] == pytest.approx(16 * 14 * 4 * 16 / 216)
    assert foundation[60] == pytest.approx(16 * 4 * 4 * 16 / 60)
    # the integrator backends report what they allocate; bench_scaling records exactly that
    system = block_system((6, 6, 6))
    sim = FeedbackSimulation(ctx, system, "verlet", 1e-3)
    try:
        expected = sim.bytes_per_node
    finally:
        sim.release()
    assert next(r.bytes_per_node for r in report.rows if r.backend == "feedback" and r.nodes == 216) \
        == pytest.approx(expected)
    assert report.model_s[216] > 0 and report.wall_s > 0

    text = report.format()
    assert "renderer:" in text and "exponent b =" in text and "ns/node-step" in text
    for backend in ("foundation", "fragment", "feedback"):
        assert f"{backend} ms/step" in text and f"{backend} B/node" in text
    assert f">= {UPPER_NODES}: exponent - (fewer than 2 sizes)" in text  # no upper sizes here
    records = report.to_records()
    assert len(records) == 6 and records[0]["shape"] == "6x6x6" and records[0]["ns_per_node_step"] > 0
    json.dumps(records)
    json.dumps(report.fit_records())
    assert {(f["range"], f["of"]) for f in report.fit_records()} == {
        ("all", "median"), ("upper", "median"), ("all", "fastest"), ("upper", "fastest")}
    assert "LP_NUM_THREADS=" in text


def test_sizes_a_backend_cannot_do_are_recorded_as_skipped(ctx, monkeypatch):
    def too_big(cls, grid, max_size):
        raise ValueError(f"{grid.count} nodes need more than {max_size}x{max_size} texels")

    monkeypatch.setattr(grid_module.CompactLayout, "for_grid", classmethod(too_big))
    report = bench_scaling(ctx, sizes=(4,), backends=("fragment", "feedback"), node_steps=100,
                           max_steps=2, repeats=1)
    fragment, feedback = report.rows
    assert fragment.ms_per_step is None and "texels" in fragment.skipped
    assert feedback.skipped is None and feedback.ms_per_step > 0  # no compact layout there
    text = report.format()
    assert "skipped" in text and "fragment at 64 nodes skipped: GLError" in text


def test_the_foundation_is_verlet_only_and_unknown_names_are_errors(ctx):
    report = bench_scaling(ctx, sizes=(4,), backends=("foundation",), integrator="euler", repeats=1)
    assert "Verlet only" in report.rows[0].skipped
    with pytest.raises(ValueError, match="backend"):
        bench_scaling(ctx, sizes=(4,), backends=("cuda",))
    with pytest.raises(ValueError, match="integrator"):
        bench_scaling(ctx, sizes=(4,), integrator="leapfrog")


def test_a_backend_failing_while_stepping_is_recorded_and_the_others_still_run(ctx, monkeypatch):
    def fail(self, n=1):
        raise moderngl.Error("out of memory")

    monkeypatch.setattr(FeedbackSimulation, "step", fail)
    report = bench_scaling(ctx, sizes=(4, 5), node_steps=100, max_steps=2, repeats=2)
    for r in report.rows:
        if r.backend == "feedback":
            assert r.ms_per_step is None and r.skipped == "Error: out of memory"
        else:
            assert r.skipped is None and r.ms_per_step > 0
    assert report.fits()["feedback"] is None and report.fits()["foundation"] is not None
