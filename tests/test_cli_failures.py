"""Failures of a run, as a user meets them: one line on stderr, the documented exit code, no
output left behind (all of a run's outputs or none), killed runs cleaned up by the next one."""

import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from deformgl import cli
from deformgl.cli import EXIT_FAILURE, EXIT_INPUT, EXIT_TERMINATED, main

SCENES = Path(__file__).resolve().parent.parent / "scenes"
REPO = Path(__file__).resolve().parent.parent


@pytest.fixture
def jelly(tmp_path):
    (tmp_path / "assets").mkdir()
    shutil.copy(SCENES / "assets" / "jelly_block.obj", tmp_path / "assets")
    scene = tmp_path / "jelly.toml"
    scene.write_text((SCENES / "jelly.toml").read_text().replace("steps = 300", "steps = 20"))
    return scene


def run_cli(capsys, *args):
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def left_over(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.rglob("*") if p.name.endswith(".tmp") or p.suffix in (".png", ".ply"))


def one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("deformgl: error: ") and "Traceback" not in err, err
    return lines[0]


@pytest.fixture
def no_gl(monkeypatch):
    """Fail the test if the command starts a GL context: the check must come before any work."""
    import deformgl.gl.context as context

    def refuse(*a, **k):
        raise AssertionError("a GL context was created before the check")
    monkeypatch.setattr(context, "create_context", refuse)


@pytest.mark.parametrize("case", ["folder", "proc", "missing"])
def test_bad_output_paths_are_refused_before_any_work(jelly, tmp_path, capsys, no_gl, case):
    out = {"folder": tmp_path / "x.png", "proc": Path("/proc/x.png"), "missing": tmp_path / "no" / "x.png"}[case]
    if case == "folder":
        out.mkdir()
    extra = ["--export-mesh", tmp_path / "x.ply", "--pack-inputs", tmp_path / "x.npz"]
    code, _, err = run_cli(capsys, "render", jelly, "-o", out, "--quiet", "--mapping", "constant", *extra)
    assert code == EXIT_INPUT and str(out) in one_error_line(err)
    assert not [n for n in left_over(tmp_path) if n != "x.png"]


def test_a_failed_write_leaves_no_output_at_all(ctx, jelly, tmp_path, capsys, monkeypatch):
    """ENOSPC while the mesh is written, after the PNG: neither appears (no half output set)."""
    import deformgl.render.mapped_setup as setup

    def full_disk(path, *a, **k):
        raise OSError(28, "No space left on device", str(path))
    monkeypatch.setattr(setup, "export_mesh", full_disk)
    import deformgl.scene.pipeline as pipeline
    monkeypatch.setattr(pipeline, "export_mesh", full_disk)
    out, mesh = tmp_path / "a.png", tmp_path / "a.ply"
    code, _, err = run_cli(capsys, "render", jelly, "-o", out, "--export-mesh", mesh, "--mapping", "constant",
                           "--quiet")
    line = one_error_line(err)
    assert code == EXIT_FAILURE and "No space left on device" in line and "a.ply" in line
    assert left_over(tmp_path) == []


def test_an_unexpected_error_is_one_line_and_debug_shows_the_traceback(jelly, tmp_path, capsys, monkeypatch):
    def bug(args):
        raise ZeroDivisionError("float division by zero")
    monkeypatch.setattr(cli, "_render", bug)
    code, _, err = run_cli(capsys, "render", jelly, "-o", tmp_path / "a.png")
    line = one_error_line(err)
    assert code == EXIT_FAILURE and "internal error: ZeroDivisionError" in line and "--debug" in line
    with pytest.raises(ZeroDivisionError):
        main(["--debug", "render", str(jelly), "-o", str(tmp_path / "a.png")])


def test_messages_stay_on_one_line_and_warnings_too(tmp_path, capsys, monkeypatch):
    weird = tmp_path / "a\nb.toml"
    code, _, err = run_cli(capsys, "render", weird)
    assert code == EXIT_INPUT and "a\\nb.toml" in one_error_line(err)

    def warns(args):
        import warnings

        from deformgl.errors import DeformglWarning
        warnings.warn("cache.npz: rebuilt\nsecond line", DeformglWarning)
        return 0
    monkeypatch.setattr(cli, "_info", warns)
    code, _, err = run_cli(capsys, "info")
    assert code == 0 and err.strip() == "deformgl: warning: cache.npz: rebuilt\\nsecond line"


def test_numpy_warnings_do_not_print_before_the_error(capsys, monkeypatch):
    def noisy(args):
        import numpy as np

        from deformgl.errors import SimulationError
        np.array([1.0]) / np.array([0.0])
        np.sqrt(np.array([-1.0]))
        raise SimulationError("scene.toml: blew up")
    monkeypatch.setattr(cli, "_info", noisy)
    code, _, err = run_cli(capsys, "info")
    assert code == EXIT_FAILURE and one_error_line(err) == "deformgl: error: scene.toml: blew up"


# --- real signals at each phase of a run ------------------------------------------------------

KILLER = textwrap.dedent("""
    import os, signal, sys
    import deformgl.scene.node_state as node_state
    import deformgl.scene.pipeline as pipeline
    from deformgl import cli, files
    phase, sig = sys.argv[1], getattr(signal, sys.argv[2])
    def kill(*a, **k):
        os.kill(os.getpid(), sig)
        raise AssertionError("the signal did not stop the run")
    if phase == "simulate":          # while the nodes are stepped
        real = node_state.simulate_scene
        def simulate_scene(*a, **k):
            kill()
        node_state.simulate_scene = simulate_scene
    elif phase == "draw":            # simulated, drawing
        pipeline.make_draw_pass = kill
    elif phase == "write":           # the PNG is written (staged), the mesh is next
        pipeline.export_mesh = kill
    elif phase == "commit":          # the first output renamed, the second not yet
        real_replace = os.replace
        count = [0]
        def replace(src, dst):
            if str(src).endswith(".tmp") and not str(dst).endswith(".tmp"):
                count[0] += 1
                if count[0] == 2:
                    os.kill(os.getpid(), sig)  # deferred until the set is renamed, whole
            return real_replace(src, dst)
        os.replace = replace
    sys.exit(cli.main(sys.argv[3:]))
""")


def run_killed(tmp_path, jelly, phase, sig):
    out, mesh = tmp_path / "a.png", tmp_path / "a.ply"
    script = tmp_path / "killer.py"
    script.write_text(KILLER)
    env = {**os.environ, "DEFORMGL_CACHE_DIR": str(tmp_path / "cache")}
    proc = subprocess.run([sys.executable, str(script), phase, sig, "render", str(jelly), "-o", str(out),
                           "--export-mesh", str(mesh), "--mapping", "constant", "--quiet"],
                          capture_output=True, text=True, timeout=300, env=env, cwd=REPO)
    return proc, out, mesh


@pytest.mark.parametrize("phase", ["simulate", "draw", "write", "commit"])
def test_sigterm_at_each_phase_leaves_nothing_or_everything(ctx, jelly, tmp_path, phase):
    """Before the outputs are renamed a SIGTERM leaves nothing; one that arrives between two
    renames waits for the set to be complete (never one output without the other)."""
    proc, out, mesh = run_killed(tmp_path, jelly, phase, "SIGTERM")
    assert proc.returncode == EXIT_TERMINATED, proc.stderr
    assert one_error_line(proc.stderr) == "deformgl: error: terminated (SIGTERM)"
    if phase == "commit":
        assert left_over(tmp_path) == ["a.ply", "a.png"]
        assert out.stat().st_size > 0 and trimesh_faces(mesh) > 0
    else:
        assert left_over(tmp_path) == [], phase  # no PNG, no mesh, no temporary file anywhere


def trimesh_faces(path: Path) -> int:
    import trimesh

    return len(trimesh.load(path, force="mesh").faces)


def test_sigkill_leftovers_are_removed_by_the_next_run(ctx, jelly, tmp_path, capsys, monkeypatch):
    proc, out, mesh = run_killed(tmp_path, jelly, "write", "SIGKILL")
    assert proc.returncode == -signal.SIGKILL
    stale = [n for n in left_over(tmp_path) if n.endswith(".tmp")]
    assert len(stale) == 1 and stale[0].startswith(".a.png.deformgl-") and not out.exists()
    time.sleep(0.05)
    monkeypatch.setattr(cli, "_STARTED", time.time())
    monkeypatch.setenv("DEFORMGL_CACHE_DIR", str(tmp_path / "cache"))
    code, _, err = run_cli(capsys, "render", jelly, "-o", out, "--quiet")
    assert code == 0, err
    assert left_over(tmp_path) == ["a.png"]


def test_sigint_while_writing_leaves_nothing(ctx, jelly, tmp_path):
    proc, out, mesh = run_killed(tmp_path, jelly, "write", "SIGINT")
    assert proc.returncode == cli.EXIT_INTERRUPTED, proc.stderr
    assert one_error_line(proc.stderr) == "deformgl: error: interrupted"
    assert left_over(tmp_path) == []


def test_a_signal_whose_exception_is_swallowed_still_stops_the_run(ctx, jelly, tmp_path, capsys, monkeypatch):
    """trimesh catches BaseException around some of its imports: a SIGTERM arriving there was
    swallowed and the run went on to write everything. Now the stop is recorded and the outputs
    are not committed."""
    import deformgl.scene.pipeline as pipeline
    real = pipeline.render

    def render_after_a_swallowed_sigterm(*a, **k):
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.1)
        except BaseException:  # what trimesh's import guards do
            pass
        return real(*a, **k)
    monkeypatch.setattr(pipeline, "render", render_after_a_swallowed_sigterm)
    out, mesh = tmp_path / "a.png", tmp_path / "a.ply"
    code, _, err = run_cli(capsys, "render", jelly, "-o", out, "--export-mesh", mesh, "--mapping", "constant", "--quiet")
    assert code == EXIT_TERMINATED and one_error_line(err) == "deformgl: error: terminated (SIGTERM)"
    assert left_over(tmp_path) == []


def test_usage_errors_are_one_line_too(capsys):
    with pytest.raises(SystemExit) as info:
        main(["render", "x.toml", "--no-such-flag"])
    assert info.value.code == EXIT_INPUT
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("deformgl: error: unrecognized arguments: --no-such-flag")


def test_a_file_name_too_long_is_an_input_error(jelly, tmp_path, capsys, no_gl):
    code, _, err = run_cli(capsys, "render", jelly, "-o", tmp_path / ("a" * 300 + ".png"))
    assert code == EXIT_INPUT and "File name too long" in one_error_line(err)
    ok = tmp_path / ("b" * 240 + ".png")  # a legal name: its temporary name is shortened to fit
    from deformgl.files import check_writable, temporary_path

    check_writable(ok)
    assert len(temporary_path(ok).name) < 255
