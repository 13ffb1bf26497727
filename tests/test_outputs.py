"""A run's outputs all or none (files.OutputSet), writable checks before work, stale temporaries."""

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from deformgl.errors import InputError
from deformgl.files import OutputSet, check_writable, remove_stale_temporaries, temporary_path, write_atomic


def _write(path: Path, text: str) -> None:
    write_atomic(path, lambda stream: stream.write(text.encode()))


def _temporaries(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".tmp"))


def test_outputs_appear_together_at_the_end(tmp_path):
    a, b, cache = tmp_path / "a.png", tmp_path / "b.ply", tmp_path / "cache.npz"
    with OutputSet([a, b, None]):
        _write(a, "A")
        _write(cache, "C")  # not in the set: written at once
        assert not a.exists() and cache.read_text() == "C"
        _write(b, "B")
        assert not b.exists() and len(_temporaries(tmp_path)) == 2
    assert (a.read_text(), b.read_text()) == ("A", "B") and _temporaries(tmp_path) == []


def test_a_failure_leaves_nothing_and_old_files_as_they_were(tmp_path):
    a, b = tmp_path / "a.png", tmp_path / "b.ply"
    a.write_text("old")
    with pytest.raises(RuntimeError, match="disk full"):
        with OutputSet([a, b]):
            _write(a, "new")
            write_atomic(b, lambda stream: (stream.write(b"half"), (_ for _ in ()).throw(RuntimeError("disk full"))))
    assert a.read_text() == "old" and not b.exists() and _temporaries(tmp_path) == []


def test_a_failed_rename_undoes_the_renames_before_it(tmp_path, monkeypatch):
    a, b = tmp_path / "a.png", tmp_path / "b.ply"
    a.write_text("old a")
    real = os.replace

    def replace(src, dst):
        if Path(dst) == b:
            raise OSError(28, "No space left on device")
        return real(src, dst)

    with pytest.raises(OSError):
        with OutputSet([a, b]):
            _write(a, "new a")
            _write(b, "new b")
            monkeypatch.setattr(os, "replace", replace)
    monkeypatch.undo()
    assert a.read_text() == "old a" and not b.exists() and _temporaries(tmp_path) == []


@pytest.mark.parametrize("case, message", [
    ("folder", "the output is a folder, not a file"),
    ("missing", "the output folder .* does not exist"),
    ("proc", "cannot write the output into /proc"),
])
def test_unwritable_outputs_are_refused_before_any_work(tmp_path, case, message):
    path = {"folder": tmp_path / "x.png", "missing": tmp_path / "no" / "x.png", "proc": Path("/proc/x.png")}[case]
    if case == "folder":
        path.mkdir()
    with pytest.raises(InputError, match=message) as info:
        OutputSet([tmp_path / "fine.png", path])
    assert "\n" not in str(info.value) and str(path) in str(info.value)
    assert _temporaries(tmp_path) == []  # the probe files are gone


def test_the_write_probe_leaves_nothing(tmp_path):
    check_writable(tmp_path / "x.png")
    assert list(tmp_path.iterdir()) == []


def test_stale_temporaries_of_dead_runs_are_removed(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True, check=True)
    dead_pid = int(dead.stdout)
    old = time.time() - 60
    names = {
        f".a.png.deformgl-{dead_pid}-0123456789ab.tmp": True,       # a killed run: removed
        f".b.png.deformgl-{os.getpid()}-0123456789ab.tmp": False,   # this run's own: kept
        ".c.png.0123456789ab.tmp": True,                            # an older deformgl's: removed
        ".d.png.deformgl-1-0123456789ab.tmp": False,                # pid 1 is alive: kept
        "e.png": False, ".f.tmp": False,                            # not deformgl's
    }
    for name in names:
        (tmp_path / name).write_text("x")
        os.utime(tmp_path / name, (old, old))
    fresh = tmp_path / f".g.png.deformgl-{dead_pid}-0123456789ab.tmp"
    fresh.write_text("x")  # newer than the run that looks: kept
    # a time series' scratch folder (deformgl.scene.interchange): a killed run's is removed with
    # what it holds, a living run's is kept
    folders = {f".m.pvd.deformgl-{dead_pid}-0123456789ab.tmp": True, f".n.pvd.deformgl-1-0123456789ab.tmp": False}
    for name in folders:
        (tmp_path / name).mkdir()
        (tmp_path / name / "m_0000.vtu").write_text("x")
        os.utime(tmp_path / name, (old, old))
    names.update(folders)
    removed = remove_stale_temporaries(tmp_path, before=time.time() - 30)
    assert sorted(p.name for p in removed) == sorted(n for n, gone in names.items() if gone)
    assert fresh.exists() and all((tmp_path / n).exists() for n, gone in names.items() if not gone)


def test_temporary_names_are_recognisable(tmp_path):
    name = temporary_path(tmp_path / "x.png").name
    assert name.startswith(".x.png.deformgl-") and name.endswith(".tmp") and str(os.getpid()) in name


def test_a_failed_rename_over_existing_files_keeps_both_old_files(tmp_path, monkeypatch):
    """The old files are hard-linked aside, never moved: at no moment is a target missing, and a
    failure puts every old file back."""
    a, b = tmp_path / "a.png", tmp_path / "b.ply"
    a.write_text("old a")
    b.write_text("old b")
    real = os.replace

    def replace(src, dst):
        if Path(dst) == b and str(src).endswith(".tmp"):
            assert a.read_text() == "new a" and b.read_text() == "old b"  # b still there
            raise OSError(5, "Input/output error")
        return real(src, dst)

    with pytest.raises(OSError):
        with OutputSet([a, b]):
            _write(a, "new a")
            _write(b, "new b")
            monkeypatch.setattr(os, "replace", replace)
    monkeypatch.undo()
    assert (a.read_text(), b.read_text()) == ("old a", "old b") and _temporaries(tmp_path) == []
