"""What every study's command shares: its argument parser, the GL context, progress lines on
stderr and the optional chart."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import moderngl

from deformgl.errors import DeformglError, InputError


def parser(prog: str, description: str) -> argparse.ArgumentParser:
    """``python -m studies.NAME``'s parser with the flags every study takes: ``--quick``,
    ``--quiet``, ``--device`` and ``--out DIR``."""
    p = argparse.ArgumentParser(prog=f"python -m studies.{prog}", description=description)
    p.add_argument("--quick", action="store_true", help="a smaller, faster study")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    p.add_argument("--device", type=int, default=None, help="EGL device index")
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="also write the study's CSV and JSON (and PNG chart, with the 'plot' extra) into DIR")
    return p


def parse(p: argparse.ArgumentParser, argv: list[str] | None) -> argparse.Namespace:
    """Parse ``argv``; ``--out`` must be an existing folder."""
    args = p.parse_args(argv)
    if getattr(args, "out", None) is not None and not args.out.is_dir():
        raise InputError(f"--out: {args.out} is not a folder")
    return args


def progress(args: argparse.Namespace) -> Callable[[str], None] | None:
    """Progress lines on stderr, or None with ``--quiet``."""
    if getattr(args, "quiet", False):
        return None
    return lambda name: print(f"[study] {name} ...", file=sys.stderr, flush=True)


@contextmanager
def gl_context(args: argparse.Namespace) -> Iterator[moderngl.Context]:
    """The headless GL context of ``--device``, released at the end."""
    from deformgl.gl.context import create_context

    ctx = create_context(getattr(args, "device", None))
    try:
        yield ctx
    finally:
        ctx.release()


def chart(write: Callable[[], None]) -> None:
    """Write a chart; without matplotlib say so on stderr (the tables and files are written)."""
    try:
        write()
    except DeformglError as exc:
        print(f"study: no chart: {exc}", file=sys.stderr)


def run_main(main: Callable[[list[str] | None], int]) -> None:
    """Run a study's ``main``; a :class:`DeformglError` ends it with its one-line message."""
    try:
        raise SystemExit(main(None))
    except DeformglError as exc:
        print(f"study: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
