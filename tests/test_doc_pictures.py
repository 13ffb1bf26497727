"""The scene pictures of README.md and docs/ are what the commands printed beside them make
(issue 42, defect 1: docs/dragon.png had drifted from `deformgl render scenes/dragon.toml`, 15.7 %
of its pixels, the head's pose).

Every picture a page shows (not the benchmark charts under docs/bench/, which their benchmarks
write) must have a ``deformgl render ... -o docs/NAME`` command in the pages' text; the slow test
runs each command, writing elsewhere, and diffs the result against the file with the goldens'
tolerances (:data:`deformgl.testing.imagediff.SAME_RENDERER`; an animation frame by frame).
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, ImageSequence

from deformgl.testing.imagediff import SAME_RENDERER, compare_images

from fuzz_oracle import run_cli

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
#: a picture shown by a page: ![alt](path)
PICTURE = re.compile(r"!\[[^\]]*\]\(([^)\s]+)\)")
#: a command printed in a page that writes a picture of docs/
COMMAND = re.compile(r"`(deformgl render [^`]*-o docs/[^`\s]+[^`]*)`")


def shown_pictures() -> dict[Path, Path]:
    """Every picture a page shows, resolved against the page, but the benchmark charts."""
    shown = {}
    for page in PAGES:
        for target in PICTURE.findall(page.read_text(encoding="utf-8")):
            path = (page.parent / target).resolve()
            if (ROOT / "docs" / "bench") not in path.parents:
                shown[path] = page
    return shown


def printed_commands() -> dict[Path, list[str]]:
    """The picture each printed command writes (relative to the checkout, as the README runs
    them) and the command's arguments."""
    commands = {}
    for page in PAGES:
        for text in COMMAND.findall(page.read_text(encoding="utf-8")):
            argv = shlex.split(text)[1:]
            commands[(ROOT / argv[argv.index("-o") + 1]).resolve()] = argv
    return commands


def test_every_picture_shown_has_its_command_printed():
    shown, commands = shown_pictures(), printed_commands()
    assert shown, "the pages show no picture: the pattern no longer finds them"
    missing = {str(p.relative_to(ROOT)): str(page.relative_to(ROOT)) for p, page in shown.items()
               if p not in commands}
    assert not missing, f"pictures without the command that makes them printed beside them: {missing}"
    for picture in shown:
        assert picture.is_file(), f"{picture.relative_to(ROOT)} is shown but missing"


def frames(path: Path) -> list[np.ndarray]:
    with Image.open(path) as image:
        return [np.asarray(frame.convert("RGB")) for frame in ImageSequence.Iterator(image)]


@pytest.mark.slow
@pytest.mark.parametrize("picture", sorted(printed_commands()), ids=lambda p: p.name)
def test_the_picture_is_what_its_command_prints(tmp_path, monkeypatch, picture):
    argv = printed_commands()[picture]
    argv[argv.index("-o") + 1] = str(tmp_path / picture.name)
    monkeypatch.chdir(ROOT)  # the commands are printed to run in the checkout
    outcome = run_cli(argv)
    assert outcome.code == 0, outcome.describe()
    made, shipped = frames(tmp_path / picture.name), frames(picture)
    assert len(made) == len(shipped), f"{picture.name}: {len(made)} frames, the file has {len(shipped)}"
    for k, (a, b) in enumerate(zip(made, shipped)):
        result = compare_images(a, b, **SAME_RENDERER)
        assert result.passed, f"{picture.name}, frame {k}: {result.reason}"
