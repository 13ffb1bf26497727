"""``deformgl export-web`` without a browser: a refusal leaves nothing behind, neither a file nor
a folder the export created (tests/test_web_example.py runs the export in Chromium)."""

from __future__ import annotations

from pathlib import Path

import pytest

from deformgl.errors import InputError
from deformgl.pack.export_web import export_web

ROOT = Path(__file__).resolve().parents[1]
ASSETS = ROOT / "scenes" / "assets"


def _scene(tmp_path: Path, base: str, extra: str) -> Path:
    """A shipped scene with its mesh path made absolute and ``extra`` TOML appended."""
    text = (ROOT / "scenes" / base).read_text().replace('"assets/', f'"{ASSETS.as_posix()}/')
    path = tmp_path / f"scene_{base}"
    path.write_text(text + "\n" + extra)
    return path


REFUSED = [
    ("jelly.toml", "[physics.ground]\nat = 0.0\n", "export-web supports no ground, spheres or drags"),
    ("jelly_springs.toml", "[physics.springs.flexion]\nstiffness = 2.0\n", "does not run on the foundation pass"),
]


@pytest.mark.parametrize("base, extra, message", REFUSED, ids=["ground", "flexion"])
def test_a_refused_export_leaves_no_folder_behind(ctx, tmp_path, base, extra, message):  # ctx: marks it gl
    scene = _scene(tmp_path, base, extra)
    out = tmp_path / "new" / "web"  # two folders the export would create
    with pytest.raises(InputError, match=message):
        export_web(scene, out, steps=2, mapping="constant")
    assert not (tmp_path / "new").exists()
    mine = tmp_path / "mine"  # a folder that was there stays, empty
    mine.mkdir()
    (mine / "keep.txt").write_text("x")
    with pytest.raises(InputError, match=message):
        export_web(scene, mine, steps=2, mapping="constant")
    assert sorted(p.name for p in mine.iterdir()) == ["keep.txt"]
    (mine / "shaders").mkdir()  # an empty shaders folder that was there: the subfolders go again
    with pytest.raises(InputError, match=message):
        export_web(scene, mine, steps=2, mapping="constant")
    assert sorted(p.relative_to(mine).as_posix() for p in mine.rglob("*")) == ["keep.txt", "shaders"]


def test_an_export_writes_the_set(ctx, tmp_path):
    out = tmp_path / "new" / "web"
    files = export_web(_scene(tmp_path, "jelly.toml", ""), out, steps=2, mapping="constant")
    assert (out / "scene.json").is_file() and (out / "shaders" / "pack.json").is_file()
    assert all(f.is_file() for f in files)
