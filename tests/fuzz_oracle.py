"""The fuzzers' oracle (issue 42): a run of deformgl on any input either succeeds with a real
image and every input used, or fails in one clean line having written nothing.

Runners:

* :func:`run_cli` calls :func:`deformgl.cli.main` in this process (tens of milliseconds a render
  against about a second for a subprocess), capturing stdout, stderr, the exit code (also of an
  argparse ``SystemExit``) and the files of a watched folder before and after.
* :func:`run_api` calls any Python function and records its result or the exception it raised.

Oracles:

* :func:`check_outcome` for a CLI run: exit 0 with every requested output a readable, non-blank
  PNG (:func:`assert_not_blank`) and no Traceback on stderr; or a non-zero exit (not an
  interrupt) with exactly one stderr line ``deformgl: error: ...`` that is not an internal
  error and does not repeat its prefix, and the watched folder exactly as it was (no output, no
  temporary file).
* :func:`check_api` for an API call: a result, or a :class:`deformgl.errors.DeformglError` whose
  message is one line (naming what it must name, when given); any other exception fails.
* :func:`assert_differs` for "every input used": the same run with and without an input (or with
  it changed) must give images that differ in at least a few pixels.

A test using :func:`run_cli` renders, so it must be marked gl: request the ``ctx`` fixture (the CLI
makes its own context; the fixture marks the test, tests/conftest.py).
"""

from __future__ import annotations

import contextlib
import ctypes.util
import functools
import io
import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from unittest import mock

import numpy as np

from deformgl.errors import DeformglError

#: A pixel differs from the background when a channel differs by more than this (of 255).
LEVEL = 8
#: Exit codes that are never an acceptable answer to an input: interrupted, terminated.
STOPPED = (130, 143)


@dataclass
class Outcome:
    """One CLI run: exit code, captured streams, and the watched folder's files before and after
    (relative paths; empty when no folder was watched)."""

    code: int
    stdout: str
    stderr: str
    before: set[str] = field(default_factory=set)
    after: set[str] = field(default_factory=set)
    watch: Path | None = None

    @property
    def new_files(self) -> set[str]:
        return self.after - self.before

    def describe(self) -> str:
        return f"exit {self.code}\n--- stdout\n{self.stdout}--- stderr\n{self.stderr}--- new files {sorted(self.new_files)}"


_find_library = functools.lru_cache(maxsize=None)(ctypes.util.find_library)


def _files(folder: Path | None) -> set[str]:
    if folder is None or not folder.exists():
        return set()
    return {str(p.relative_to(folder)) for p in folder.rglob("*") if not p.is_dir()}


def run_cli(argv: Sequence[str | os.PathLike], watch: Path | None = None) -> Outcome:
    """``deformgl ARGV`` in this process: the exit code (``main``'s return, or ``SystemExit``'s for
    argparse usage errors), stdout, stderr, and the files of ``watch`` before and after."""
    from deformgl.cli import main

    before = _files(watch)
    out, err = io.StringIO(), io.StringIO()
    # glcontext looks its libraries up anew for every context, forking ldconfig twice (tens of
    # ms, the most of a small render's time): remembered for the fuzzers' thousands of runs
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), \
            mock.patch.object(ctypes.util, "find_library", _find_library):
        try:
            code = main([str(a) for a in argv])
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    return Outcome(int(code), out.getvalue(), err.getvalue(), before, _files(watch), watch)


def background_of(image: np.ndarray) -> np.ndarray:
    """The background colour: the most common of the four corner pixels (a render frames its
    content in the middle)."""
    corners = [tuple(int(v) for v in image[y, x, :3]) for y in (0, -1) for x in (0, -1)]
    return np.array(max(set(corners), key=corners.count), dtype=np.int64)


def foreground_pixels(image: np.ndarray, background: Sequence[int] | None = None) -> int:
    """How many pixels differ from ``background`` (default :func:`background_of`) by more than
    :data:`LEVEL` on some channel."""
    img = np.asarray(image)[..., :3].astype(np.int64)
    bg = background_of(img) if background is None else np.asarray(background, dtype=np.int64)
    return int((np.abs(img - bg).max(-1) > LEVEL).sum())


def assert_not_blank(image: np.ndarray, *, min_fraction: float = 0.002, min_pixels: int = 8,
                     background: Sequence[int] | None = None, what: str = "image") -> None:
    """At least ``max(min_pixels, min_fraction * pixels)`` pixels differ from the background:
    a single colour, or a background with a few stray pixels, is blank."""
    img = np.asarray(image)
    assert img.ndim == 3 and img.shape[0] > 0 and img.shape[1] > 0, f"{what}: not an image, shape {img.shape}"
    need = max(min_pixels, int(min_fraction * img.shape[0] * img.shape[1]))
    got = foreground_pixels(img, background)
    assert got >= need, f"{what}: blank ({got} pixels differ from the background, need {need})"


def read_image(path: Path) -> np.ndarray:
    """A PNG written by deformgl as (H, W, 3|4) uint8 (fails the test if unreadable)."""
    from deformgl.files import read_png

    try:
        return read_png(path)
    except Exception as exc:  # the oracle's point: an unreadable output is a failure
        raise AssertionError(f"{path}: not a readable PNG: {type(exc).__name__}: {exc}") from None


def check_outcome(outcome: Outcome, outputs: Iterable[Path] = (), *, expect: str | None = None,
                  codes: Sequence[int] | None = None, blank_ok: bool = False) -> str:
    """The oracle for one :func:`run_cli` outcome; returns ``"ok"`` or ``"error"``.

    Success (exit 0): every path of ``outputs`` exists and is a readable PNG that is not blank
    (unless ``blank_ok``), no Traceback and no internal error on stderr. Failure (any other
    exit but an interrupt): exactly one stderr line starting ``deformgl: error: ``, no
    Traceback, not an internal error (a bug), not an interrupt, nothing new in the watched
    folder; ``codes``: the exit codes allowed (default: 1 or 2); ``expect``: "ok" or "error"
    when the verdict is known in advance.
    """
    why = outcome.describe()
    assert "Traceback" not in outcome.stderr and "Traceback" not in outcome.stdout, why
    assert "internal error" not in outcome.stderr, why
    if outcome.code == 0:
        assert expect in (None, "ok"), f"expected an error, got success\n{why}"
        for path in outputs:
            assert Path(path).is_file(), f"{path}: not written\n{why}"
            if Path(path).suffix.lower() == ".png" and not blank_ok:
                assert_not_blank(read_image(Path(path)), what=f"{path}\n{why}")
        return "ok"
    assert expect in (None, "error"), f"expected success, got exit {outcome.code}\n{why}"
    assert outcome.code not in STOPPED, why
    assert outcome.code in (codes or (1, 2)), why
    lines = outcome.stderr.rstrip("\n").split("\n")
    assert len(lines) == 1 and lines[0].startswith("deformgl: error: "), f"not one error line\n{why}"
    assert len(lines[0]) > len("deformgl: error: "), why
    assert_no_repeated_prefix(lines[0][len("deformgl: error: "):])
    assert not outcome.new_files, f"a failed run left files\n{why}"
    for path in outputs:
        inside = outcome.watch is not None and Path(path).resolve().is_relative_to(outcome.watch.resolve())
        assert inside or not Path(path).exists(), f"{path}: written\n{why}"
    return "error"


def assert_no_repeated_prefix(message: str) -> None:
    """A message names its file (or argument) once: ``a.toml: k: a.toml: k.f: ...`` is a wrapped
    error whose wrapper repeated the prefix."""
    head, sep, rest = message.partition(": ")
    assert not (sep and head and f"{head}: " in rest), f"the message repeats its prefix {head!r}: {message}"


@dataclass
class ApiOutcome:
    """One API call: its result, or the exception it raised."""

    result: Any = None
    error: BaseException | None = None


def run_api(fn: Callable[..., Any], *args: Any, **kwargs: Any) -> ApiOutcome:
    """Call ``fn(*args, **kwargs)``, recording its result or any exception (not BaseException:
    an interrupt still stops the test run)."""
    try:
        return ApiOutcome(result=fn(*args, **kwargs))
    except Exception as exc:
        return ApiOutcome(error=exc)


def check_api(outcome: ApiOutcome, *, names: Sequence[str] = (), expect: str | None = None) -> str:
    """The oracle for one :func:`run_api` outcome; returns ``"ok"`` or ``"error"``. An error must
    be a DeformglError with a one-line, non-empty message containing every string of ``names``
    (the argument names the caller passed, a file, a key)."""
    if outcome.error is None:
        assert expect in (None, "ok"), f"expected an error, got {outcome.result!r}"[:2000]
        return "ok"
    exc = outcome.error
    assert expect in (None, "error"), f"expected success, got {type(exc).__name__}: {exc}"
    assert isinstance(exc, DeformglError), f"not a DeformglError: {type(exc).__name__}: {exc}"
    msg = str(exc)
    assert msg and "\n" not in msg and "\r" not in msg, f"not one line: {msg!r}"
    for name in names:
        assert name in msg, f"{name!r} not named in {msg!r}"
    assert_no_repeated_prefix(msg)
    return "error"


def assert_differs(a: np.ndarray, b: np.ndarray, *, min_pixels: int = 4, what: str = "input") -> None:
    """Every input used: two images rendered with and without ``what`` (or with it changed) differ
    in at least ``min_pixels`` pixels by more than :data:`LEVEL`."""
    a, b = np.asarray(a)[..., :3].astype(np.int64), np.asarray(b)[..., :3].astype(np.int64)
    if a.shape != b.shape:
        return
    n = int((np.abs(a - b).max(-1) > LEVEL).sum())
    assert n >= min_pixels, f"{what} had no visible effect ({n} pixels differ, need {min_pixels})"
