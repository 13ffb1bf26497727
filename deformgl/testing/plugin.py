"""A pytest plugin for image regression tests: the ``deformgl_golden`` fixture.

Installed with deformgl and loaded by pytest through the ``pytest11`` entry point ``deformgl``
(``-p no:deformgl`` turns it off; ``-p deformgl.testing.plugin`` loads it from a checkout)::

    def test_render(deformgl_golden):
        image = render_something()          # uint8 (H, W, 3) or (H, W, 4), or a PNG path
        deformgl_golden(image)              # baseline: <test folder>/golden/<test name>.png
        deformgl_golden(image, "closeup", max_mean=0.05)   # a named baseline, own tolerances

* A baseline passes when the image matches it within the tolerances of
  :func:`deformgl.testing.imagediff.compare_images` (keyword arguments of the call, see
  :data:`~deformgl.testing.imagediff.TOLERANCE_NAMES`). Several baselines may be accepted,
  VTK-style: ``name.png``, ``name_1.png``, ``name_2.png``... (one per renderer); matching any
  passes.
* ``pytest --update-goldens`` writes the images as baselines instead of comparing (with
  numbered alternatives present, only when none matches, into ``name.png``).
* On failure the actual image, the closest baseline and a magnified difference are written to
  the failure folder as ``name-actual.png``, ``name-expected.png`` and ``name-diff.png``, for CI
  to upload; the terminal summary lists them.

Settings (command-line option, or ini setting of the same name with underscores):

* ``--golden-dir`` / ``golden_dir``: the baseline folder, relative to each test file's folder
  (default ``golden``); an absolute path is used as is.
* ``--golden-failures`` / ``golden_failures``: the failure folder, relative to the rootdir
  (default ``golden-failures``).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from deformgl.testing.imagediff import ImageDiff, check_golden

__all__ = ["GoldenChecker", "deformgl_golden"]

DEFAULT_GOLDEN_DIR = "golden"
DEFAULT_FAILURES_DIR = "golden-failures"

_failures_key = pytest.StashKey[list[Path]]()


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("deformgl", "image regression (deformgl_golden fixture)")
    group.addoption("--update-goldens", action="store_true", default=False,
                    help="write the current images as the new baselines (then look at them)")
    group.addoption("--golden-dir", default=None,
                    help=f"baseline folder, relative to each test file (default {DEFAULT_GOLDEN_DIR})")
    group.addoption("--golden-failures", default=None,
                    help=f"folder for failure images, relative to the rootdir (default {DEFAULT_FAILURES_DIR})")
    parser.addini("golden_dir", f"baseline folder, relative to each test file (default {DEFAULT_GOLDEN_DIR})",
                  default=DEFAULT_GOLDEN_DIR)
    parser.addini("golden_failures", "folder for failure images, relative to the rootdir "
                  f"(default {DEFAULT_FAILURES_DIR})", default=DEFAULT_FAILURES_DIR)


def pytest_configure(config: pytest.Config) -> None:
    config.stash[_failures_key] = []


def golden_failures_dir(config: pytest.Config) -> Path:
    """The folder failure images go to (``--golden-failures`` / ``golden_failures``)."""
    value = config.getoption("--golden-failures") or config.getini("golden_failures")
    return Path(config.rootpath, str(value))


def _load(image: Any) -> np.ndarray:
    if isinstance(image, (str, Path)):
        from deformgl.files import read_png

        return read_png(Path(image))
    if isinstance(image, (bytes, bytearray)):
        import io

        from PIL import Image

        with Image.open(io.BytesIO(image)) as opened:
            return np.asarray(opened.convert("RGBA" if "A" in opened.getbands() else "RGB"))
    return np.asarray(image)


class GoldenChecker:
    """Compares images with baselines in one folder; the object behind ``deformgl_golden``.

    Args:
        baseline_dir: Where the baselines ``<name>.png`` (and ``<name>_N.png``) are.
        failures_dir: Where failure images go.
        update: Write baselines instead of comparing.
        default_name: The name used when a call gives none (the test's name).
        tolerances: Defaults for every call; a call's keyword arguments override them.
        on_failure: Called with the failure images' paths when a comparison fails.
    """

    def __init__(self, baseline_dir: Path, failures_dir: Path, *, update: bool, default_name: str = "image",
                 tolerances: dict[str, float] | None = None,
                 on_failure: Callable[[list[Path]], None] | None = None) -> None:
        self.baseline_dir = Path(baseline_dir)
        self.failures_dir = Path(failures_dir)
        self.update = update
        self.default_name = default_name
        self.tolerances = dict(tolerances or {})
        self.on_failure = on_failure
        self._used: set[str] = set()

    def __call__(self, image: Any, name: str | None = None, **tolerances: float) -> ImageDiff:
        """Compare ``image`` (uint8 array, PNG path or PNG bytes) with the baseline ``name``.

        Raises:
            AssertionError: no baseline, or no match (failure images are written).
        """
        if name is None:
            name = self.default_name
            if name in self._used:  # a second unnamed image in one test gets its own baseline
                n = 2
                while f"{name}-{n}" in self._used:
                    n += 1
                name = f"{name}-{n}"
        self._used.add(name)
        merged = {**self.tolerances, **tolerances}
        try:
            return check_golden(_load(image), self.baseline_dir / f"{name}.png", update=self.update,
                                out_dir=self.failures_dir, **merged)
        except AssertionError:
            if self.on_failure is not None:
                written = [self.failures_dir / f"{name}-{kind}.png" for kind in ("actual", "expected", "diff")]
                self.on_failure([p for p in written if p.is_file()])
            raise


def default_name(node: pytest.Item) -> str:
    """A file name for a test: its name with parameters, anything odd replaced by ``_``."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", node.name).strip("_") or "image"


def make_checker(request: pytest.FixtureRequest, baseline_dir: Path | None = None,
                 failures_dir: Path | None = None, **tolerances: float) -> GoldenChecker:
    """A :class:`GoldenChecker` configured from pytest's settings, for a project's own fixture.

    ``baseline_dir`` defaults to ``--golden-dir`` / ``golden_dir`` next to the test file, and
    ``failures_dir`` to ``--golden-failures`` / ``golden_failures``; ``tolerances`` are the
    defaults of every call.
    """
    config = request.config
    if baseline_dir is None:
        folder = config.getoption("--golden-dir") or config.getini("golden_dir")
        baseline_dir = Path(request.path).parent / str(folder)
    if failures_dir is None:
        failures_dir = golden_failures_dir(config)
    elif config.getoption("--golden-failures"):
        failures_dir = golden_failures_dir(config)  # the command line wins, for CI
    failures = config.stash.get(_failures_key, [])
    return GoldenChecker(baseline_dir, failures_dir, update=bool(config.getoption("--update-goldens")),
                         default_name=default_name(request.node), tolerances=tolerances,
                         on_failure=failures.extend)


@pytest.fixture
def deformgl_golden(request: pytest.FixtureRequest) -> GoldenChecker:
    """``deformgl_golden(image, name=None, **tolerances)`` compares an image with its baseline."""
    return make_checker(request)


def pytest_terminal_summary(terminalreporter: Any, exitstatus: int, config: pytest.Config) -> None:
    failures = config.stash.get(_failures_key, [])
    if failures:
        terminalreporter.section("deformgl golden images")
        terminalreporter.write_line(f"{len(failures)} failure image(s) written:")
        for path in failures:
            terminalreporter.write_line(f"  {path}")
