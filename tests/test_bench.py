"""The benchmark commands (``deformgl bench sim|trade``) and the studies of the repository's
``studies/`` folder produce complete tables (content, not speed: timings are never asserted)."""

import importlib
from pathlib import Path

import pytest

from deformgl.bench.sim_speed import bench_sim, format_sim, machine_line
from deformgl.sim.integrators import EXPLICIT_INTEGRATORS
from studies.integrator_speed import bench_integrators, format_integrators

SCENES = Path(__file__).resolve().parent.parent / "scenes"


def test_bench_integrators_covers_every_integrator_and_names_the_renderer(ctx):
    rows = bench_integrators(ctx, cloths=(8,), volumes=((3, 4, 5),), steps=1)
    assert len(rows) == 2 and rows[0].nodes == 64 and rows[1].nodes == 60
    assert {name for _, name in rows[0].ms} == set(EXPLICIT_INTEGRATORS)
    assert {backend for backend, _ in rows[1].ms} == {"fragment", "feedback", "numpy"}
    assert all(ms > 0 for ms in rows[0].ms.values()) and rows[0].baseline_ms > 0
    # Verlet keeps no velocity state: it needs less memory per node than RK4
    assert rows[0].bytes_per_node["feedback", "verlet"] < rows[0].bytes_per_node["feedback", "rk4"]
    text = format_integrators(rows, machine_line(ctx))
    assert rows[0].bytes_per_node["fragment", "verlet"] < rows[0].bytes_per_node["fragment", "rk4"]
    assert "renderer:" in text and "8x8 cloth" in text and "3x4x5 volume" in text
    backends = [line.split()[0] for line in text.splitlines() if line.startswith("  ")]
    for backend in ("fragment", "feedback", "numpy"):
        assert backends.count(backend) == 2 * len(EXPLICIT_INTEGRATORS)


def test_bench_sim_table_has_every_variant_and_the_numpy_ratio(ctx):
    from studies.pass_variants import PASS_VARIANTS

    rows = bench_sim(ctx, steps=1, grids=((4, 4, 4),), variants=PASS_VARIANTS)
    text = format_sim(rows, machine_line(ctx))
    for variant in ("compact", "compact indexed", "blocked 1x2x2"):
        assert variant in text
    assert "speed-up vs numpy" in text and rows[0].numpy_ms > 0


def test_deformgl_bench_sim_times_the_layouts_a_scene_gets(ctx, capsys):
    """``deformgl bench sim``: the compact layout and the blocked one the backend picks, against NumPy."""
    rows = bench_sim(ctx, steps=1, grids=((4, 4, 4),))
    assert list(rows[0].variant_ms) == ["compact", "blocked (default)"] and rows[0].numpy_ms > 0
    assert "speed-up vs numpy" in format_sim(rows, machine_line(ctx))


@pytest.mark.parametrize("argv", [["render"], ["scaling", "--quick"], ["accuracy"], ["profile"], ["integrators"],
                                  ["sim", "--bending"], ["sim", "--poisson", "0.45"]])
def test_a_former_bench_choice_names_its_study_in_one_line(argv, capsys):
    from deformgl.cli import main
    from deformgl.cli_bench import MOVED

    assert main(["bench", *argv]) == 2
    err = capsys.readouterr().err.strip()
    key = argv[0] if argv[0] != "sim" else argv[1]
    assert len(err.splitlines()) == 1 and MOVED[key] in err and "Traceback" not in err, err


def test_every_study_the_bench_points_to_is_a_command():
    from deformgl.cli_bench import MOVED

    for command in MOVED.values():
        module = importlib.import_module(command.removeprefix("python -m "))
        assert callable(module.main), command


def test_bench_studies_print_their_tables_and_write_csv_json_and_the_chart(ctx, tmp_path, capsys, monkeypatch):
    """``deformgl bench trade``, ``python -m studies.mapping_accuracy`` and ``python -m
    studies.scaling`` with ``--out DIR`` (shrunk: quick trade on the volume only, two small scaling
    sizes, mappings on 4 nodes) print the table and write the files."""
    import json

    import studies.mapping_accuracy as mapping_accuracy
    import studies.scaling as scaling
    import deformgl.bench.trade as trade
    from deformgl.cli import main

    monkeypatch.setattr(scaling, "QUICK_SIZES", (8, 10))
    volume = trade.standard_workloads()[:1]
    study = trade.trade_study
    monkeypatch.setattr(trade, "trade_study", lambda ctx, **kw: study(ctx, workloads=volume, **kw))
    accuracy = mapping_accuracy.mapping_accuracy
    monkeypatch.setattr(mapping_accuracy, "mapping_accuracy",
                        lambda ctx, **kw: accuracy(ctx, **kw, grids=(4,), repeats=1))
    commands = {"trade": lambda argv: main(["bench", "trade", *argv]), "mappings": mapping_accuracy.main,
                "scaling": scaling.main}
    for what, words in (("trade", "Pareto front"), ("mappings", "one-to-one"), ("scaling", "ns/node-step")):
        assert commands[what](["--quick", "--quiet", "--out", str(tmp_path)]) == 0
        out = capsys.readouterr().out
        assert words in out and "renderer" in out, out
        assert json.loads((tmp_path / f"{what}.json").read_text())
        assert (tmp_path / f"{what}.csv").read_text().count("\n") >= 2
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        return
    for what in ("trade", "mappings", "scaling"):
        assert (tmp_path / f"{what}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bench_out_must_be_a_folder(tmp_path, capsys):
    from deformgl.cli import main

    assert main(["bench", "trade", "--out", str(tmp_path / "missing")]) == 2  # an input error
    assert "--out:" in capsys.readouterr().err


def test_bench_profile_rebuilds_the_step_stage_by_stage(ctx):
    from studies.step_profile import STAGES, format_profile, profile_step

    rows = profile_step(ctx, grids=((6, 5, 4),), passes=2, repeats=1)
    assert [r.what for r in rows if r.lookup == "index"] == [*STAGES, "full step"]
    assert [r.what for r in rows if r.lookup == "offsets"][2] == "+ neighbour offsets"
    assert all(r.ms > 0 and r.nodes == 120 for r in rows)
    text = format_profile(rows, machine_line(ctx))
    assert "neighbours by index" in text and "neighbours by offsets" in text and "renderer" in text


def test_bench_profile_times_the_lattice_weights_both_ways(ctx):
    from studies.step_profile import format_lattice_weights, lattice_weights

    rows = lattice_weights(ctx, grids=((6, 5, 4),), steps=2, rounds=2)
    assert [(name, nodes) for name, nodes, _, _ in rows] == [("6x5x4", 120)]
    assert all(t > 0 and lv > 0 for _, _, t, lv in rows)
    text = "\n".join(format_lattice_weights(rows))
    assert "texture" in text and "levels" in text and "6x5x4 (120 nodes)" in text


def test_bench_render_times_every_draw_path_and_the_renderers_frame(ctx):
    """On the jelly's closed box mesh: the static baseline, the node surface, both mappings in
    each of the three mapping passes, the culled draw, and the frame budgets with and without
    culling, on the mapping pass the renderer uses."""
    from studies.render_speed import bench_render, format_render
    from deformgl.scene.pipeline import RENDER_MAPPING_PASS

    rows, frame_ms, info = bench_render(ctx, SCENES / "jelly.toml", size=64, repeats=1, frame_size=32,
                                        frame_steps=2)
    names = [r.name for r in rows]
    assert names == ["static mesh", "one-to-one", "constant", "constant 2-stage", "constant fragment",
                     "curvature", "curvature 2-stage", "curvature fragment", "curvature, culled"]
    assert all(r.ms > 0 for r in rows) and set(frame_ms) == {4, 0}
    assert info["culled"] and info["mapping_pass"] == RENDER_MAPPING_PASS
    assert set(info["budgets"]) == {"no AA", "4x MSAA", "FXAA", "no AA + cull", "4x MSAA + cull", "FXAA + cull"}
    text = format_render(rows, frame_ms, info, "machine")
    assert "curvature, culled" in text and f"the frame below: {RENDER_MAPPING_PASS}" in text


def test_the_ablation_shader_has_every_stage_of_the_study():
    """The step profile's own shader (studies/shaders/step_ablation.frag, out of the package) stops
    after each of the study's stages and defaults to the whole cut-down step."""
    import re

    from studies.step_profile import STAGES, ablation_source

    text = ablation_source()
    assert re.search(r"#define STAGE (\d+)", text).group(1) == str(len(STAGES) - 1)
    assert {int(n) for n in re.findall(r"#(?:el)?if STAGE (?:>=|==) (\d+)", text)} == set(range(1, len(STAGES)))
