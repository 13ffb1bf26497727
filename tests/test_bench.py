"""The benchmark commands produce complete tables (content, not speed: timings are never asserted)."""

from deformgl.bench import bench_integrators, bench_sim, format_integrators, format_sim, machine_line
from deformgl.integrators import INTEGRATORS


def test_bench_integrators_covers_every_integrator_and_names_the_renderer(ctx):
    rows = bench_integrators(ctx, cloths=(8,), volumes=((3, 4, 5),), steps=1)
    assert len(rows) == 2 and rows[0].nodes == 64 and rows[1].nodes == 60
    assert {name for _, name in rows[0].ms} == set(INTEGRATORS)
    assert {backend for backend, _ in rows[1].ms} == {"fragment", "feedback", "numpy"}
    assert all(ms > 0 for ms in rows[0].ms.values()) and rows[0].baseline_ms > 0
    # Verlet keeps no velocity state: it needs less memory per node than RK4
    assert rows[0].bytes_per_node["feedback", "verlet"] < rows[0].bytes_per_node["feedback", "rk4"]
    text = format_integrators(rows, machine_line(ctx))
    assert rows[0].bytes_per_node["fragment", "verlet"] < rows[0].bytes_per_node["fragment", "rk4"]
    assert "renderer:" in text and "8x8 cloth" in text and "3x4x5 volume" in text
    backends = [line.split()[0] for line in text.splitlines() if line.startswith("  ")]
    for backend in ("fragment", "feedback", "numpy"):
        assert backends.count(backend) == 2 * len(INTEGRATORS)


def test_bench_sim_table_has_every_variant_and_the_numpy_ratio(ctx):
    rows = bench_sim(ctx, steps=1, grids=((4, 4, 4),))
    text = format_sim(rows, machine_line(ctx))
    for variant in ("compact", "compact+branch", "atlas rects", "atlas quad", "atlas points"):
        assert variant in text
    assert "speed-up vs numpy" in text and rows[0].numpy_ms > 0
