"""The deformgl pytest plugin (``deformgl_golden``) used from a throwaway project, and the
``deformgl diff`` command (deformgl.testing.diff_cli)."""

from __future__ import annotations

import os
import subprocess
import sys
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest

from deformgl.files import read_png, write_png_atomic

TEST_FILE = '''
import numpy as np

def picture(shift=0):
    y, x = np.mgrid[0:40, 0:60]
    return np.stack([(x * 4 + shift) % 256, (y * 6) % 256, (x + y) % 256], axis=2).astype(np.uint8)

def test_picture(deformgl_golden):
    import os
    deformgl_golden(picture(int(os.environ.get("SHIFT", "0"))))

def test_named_with_tolerance(deformgl_golden):
    deformgl_golden(picture(), "named", max_mean=0.5)
'''


def _plugin_args() -> list[str]:
    """``-p deformgl.testing.plugin`` unless the entry point loads the plugin by itself."""
    names = {ep.name for ep in metadata.entry_points(group="pytest11")}
    return [] if "deformgl" in names else ["-p", "deformgl.testing.plugin"]


def run_pytest(project: Path, *args: str, shift: int = 0) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "SHIFT": str(shift)}
    env.pop("PYTEST_ADDOPTS", None)
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *_plugin_args(), *args],
                          cwd=project, env=env, capture_output=True, text=True, timeout=120)


@pytest.fixture
def project(tmp_path: Path) -> Path:
    root = tmp_path / "project"
    (root / "tests").mkdir(parents=True)
    (root / "pytest.ini").write_text("[pytest]\ngolden_failures = ci-artifacts/images\n")
    (root / "tests" / "test_pictures.py").write_text(TEST_FILE)
    return root


def test_plugin_update_pass_fail_and_a_second_accepted_baseline(project: Path) -> None:
    golden = project / "tests" / "golden"
    failures = project / "ci-artifacts" / "images"

    # no baseline: fails and says how to create it
    first = run_pytest(project)
    assert first.returncode == 1, first.stdout + first.stderr
    assert "--update-goldens" in first.stdout

    # update writes the baselines, named after the test or the call
    update = run_pytest(project, "--update-goldens")
    assert update.returncode == 0, update.stdout + update.stderr
    assert sorted(p.name for p in golden.iterdir()) == ["named.png", "test_picture.png"]

    # pass; nothing written
    assert run_pytest(project).returncode == 0
    assert not failures.exists()

    # a change of 40/255 in one channel everywhere fails, and leaves the three images
    failed = run_pytest(project, shift=40)
    assert failed.returncode == 1, failed.stdout + failed.stderr
    assert "does not match golden image" in failed.stdout
    names = sorted(p.name for p in failures.iterdir())
    assert names == ["test_picture-actual.png", "test_picture-diff.png", "test_picture-expected.png"]
    assert "deformgl golden images" in failed.stdout and "test_picture-diff.png" in failed.stdout
    np.testing.assert_array_equal(read_png(failures / "test_picture-expected.png"), read_png(golden / "test_picture.png"))

    # the other renderer's image, accepted as a second baseline: both renderers pass
    (failures / "test_picture-actual.png").rename(golden / "test_picture_1.png")
    assert run_pytest(project, shift=40).returncode == 0
    assert run_pytest(project).returncode == 0

    # with alternatives, updating leaves a matching baseline alone
    before = (golden / "test_picture.png").read_bytes()
    assert run_pytest(project, "--update-goldens", shift=40).returncode == 0
    assert (golden / "test_picture.png").read_bytes() == before

    # --golden-failures on the command line wins over the ini setting
    other = project / "elsewhere"
    assert run_pytest(project, "--golden-failures", str(other), shift=80).returncode == 1
    assert (other / "test_picture-diff.png").is_file()


def test_plugin_golden_dir_option(project: Path) -> None:
    assert run_pytest(project, "--update-goldens", "--golden-dir", "baselines").returncode == 0
    assert (project / "tests" / "baselines" / "test_picture.png").is_file()
    assert run_pytest(project, "--golden-dir", "baselines").returncode == 0


# --- deformgl diff ---------------------------------------------------------------------------

def diff(*argv: str) -> int:
    """``deformgl diff ...`` through the command line's own entry point."""
    from deformgl.cli import main

    return main(["diff", *argv])


def picture(shift: int = 0, size: tuple[int, int] = (40, 60)) -> np.ndarray:
    y, x = np.mgrid[0:size[0], 0:size[1]]
    return np.stack([(x * 4 + shift) % 256, (y * 6) % 256, (x + y) % 256], axis=2).astype(np.uint8)


def test_diff_command_exit_codes_and_figures(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a, b, c = tmp_path / "a.png", tmp_path / "b.png", tmp_path / "c.png"
    write_png_atomic(a, picture())
    slightly = picture()
    slightly[::3, :, 1] += 2   # a third of the pixels 2/255 off: renderer noise by default, not by --strict
    write_png_atomic(b, slightly)
    write_png_atomic(c, picture(size=(41, 60)))

    assert diff(str(a), str(a)) == 0
    assert capsys.readouterr().out.startswith("MATCH: images match: 0 of 2400 pixels")
    assert diff(str(a), str(b)) == 0
    capsys.readouterr()
    out = tmp_path / "d.png"
    assert diff(str(a), str(b), "--strict", "--diff", str(out)) == 1
    text = capsys.readouterr().out
    assert text.startswith("DIFFER: images differ: 840 pixels (35.00 %) differ by more than 1/255")
    assert f"diff image: {out}" in text and len(text.splitlines()) == 2
    assert read_png(out)[0, 0].tolist() == [16, 16, 16]
    assert diff(str(a), str(b), "--channel-tolerance", "1") == 1
    assert diff(str(a), str(b), "--channel-tolerance", "1", "--max-fraction", "0.5") == 0
    assert diff(str(a), str(b), "--max-mean", "0.5") == 1
    assert diff(str(a), str(b), "--pixel-max", "1", "--max-fraction", "1") == 1
    capsys.readouterr()

    assert diff(str(a), str(c)) == 2  # bad input: one line on stderr
    assert capsys.readouterr().err.startswith(f"deformgl: error: {c}: sizes differ")
    assert diff(str(tmp_path / "missing.png"), str(a)) == 2
    assert "missing.png: the expected image: no such file" in capsys.readouterr().err
    (tmp_path / "text.png").write_text("not a png")
    assert diff(str(a), str(tmp_path / "text.png")) == 2
    err = capsys.readouterr().err
    assert "cannot be read as PNG" in err and len(err.strip().splitlines()) == 1
    with pytest.raises(SystemExit):
        diff(str(a), str(b), "--max-fraction", "2")
