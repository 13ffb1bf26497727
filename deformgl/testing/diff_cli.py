"""``deformgl diff EXPECTED.png ACTUAL.png``: the golden-image comparison as a command.

Exit status 0 when the images match within the tolerances, 1 when they differ, 2 for bad input
(a missing or unreadable file, images of different sizes or channel counts). The figures are
printed in one line (two with ``--diff``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from deformgl.testing.imagediff import (
    DEFAULT_CHANNEL_TOL, DEFAULT_MAX_FRACTION, DEFAULT_PIXEL_MAX, DEFAULT_SMALL_TOL, SAME_RENDERER,
    compare_images, diff_image,
)

__all__ = ["add_parser", "run"]


def _level(text: str) -> int:
    value = int(text)
    if not 0 <= value <= 255:
        raise argparse.ArgumentTypeError(f"must be between 0 and 255, got {value}")
    return value


def _fraction(text: str) -> float:
    value = float(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"must be between 0 and 1, got {value}")
    return value


def _mean(text: str) -> float:
    value = float(text)
    if not value >= 0.0:
        raise argparse.ArgumentTypeError(f"must be at least 0, got {value}")
    return value


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Adds the ``diff`` command to a CLI's subparsers; returns its parser."""
    p = subparsers.add_parser(
        "diff", help="compare two PNG images with the golden-image tolerances",
        description="Compare ACTUAL.png with EXPECTED.png. Exit 0 when they match, 1 when they "
                    "differ, 2 for bad input (missing file, different sizes). Defaults tolerate "
                    "renderer noise (see docs/IMAGEDIFF.md); --strict adds the same-renderer "
                    "small-difference tests of deformgl's own goldens.")
    p.add_argument("expected", type=Path, metavar="EXPECTED.png")
    p.add_argument("actual", type=Path, metavar="ACTUAL.png")
    p.add_argument("--diff", type=Path, metavar="OUT.png", default=None,
                   help="write a magnified difference image (grey x8, red above --pixel-max)")
    p.add_argument("--max-fraction", type=_fraction, default=DEFAULT_MAX_FRACTION, metavar="F",
                   help=f"largest fraction of pixels over --channel-tolerance (default {DEFAULT_MAX_FRACTION})")
    p.add_argument("--channel-tolerance", type=_level, default=DEFAULT_CHANNEL_TOL, metavar="T",
                   help=f"per-channel difference, of 255, that counts as unchanged (default {DEFAULT_CHANNEL_TOL})")
    p.add_argument("--pixel-max", type=_level, default=DEFAULT_PIXEL_MAX, metavar="M",
                   help=f"per-channel difference, of 255, no pixel may exceed (default {DEFAULT_PIXEL_MAX})")
    p.add_argument("--max-small-fraction", type=_fraction, default=None, metavar="F",
                   help="largest fraction of pixels over --small-tolerance (default: no limit)")
    p.add_argument("--small-tolerance", type=_level, default=None, metavar="T",
                   help=f"per-channel difference, of 255, for --max-small-fraction (default {DEFAULT_SMALL_TOL})")
    p.add_argument("--max-mean", type=_mean, default=None, metavar="D",
                   help="largest mean difference, of 255 (default: no limit)")
    p.add_argument("--strict", action="store_true",
                   help="same-renderer tolerances: --small-tolerance 1 --max-small-fraction 0.001 --max-mean 0.05 "
                        "(explicit options win)")
    p.set_defaults(run=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Runs ``deformgl diff``; returns the exit status (0 match, 1 differ); bad input (a missing
    or unreadable image, different sizes) raises InputError, which the CLI prints as one line
    with exit status 2."""
    from deformgl.errors import DeformglError, InputError
    from deformgl.files import read_png, write_png_atomic

    from deformgl.files import check_writable

    if args.diff is not None:  # before the comparison: a bad path is an input error, not "differ"
        if Path(args.diff).suffix.lower() != ".png":
            raise InputError(f"{args.diff}: --diff must end in .png")
        check_writable(args.diff, "difference image")
    images = []
    for label, path in (("expected", args.expected), ("actual", args.actual)):
        if not Path(path).exists():
            raise InputError(f"{path}: the {label} image: no such file")
        if not Path(path).is_file():
            raise InputError(f"{path}: the {label} image is not a regular file")
        try:
            images.append(read_png(Path(path)))
        except (OSError, ValueError, DeformglError) as exc:
            raise InputError(f"{path}: the {label} image cannot be read as PNG: {exc}") from None
    expected, actual = images
    if expected.shape != actual.shape:
        raise InputError(f"{args.actual}: sizes differ: expected {args.expected} is {_shape(expected.shape)}, "
                         f"actual {args.actual} is {_shape(actual.shape)}")

    tolerances: dict[str, float] = dict(SAME_RENDERER) if getattr(args, "strict", False) else {}
    tolerances.update(channel_tol=args.channel_tolerance, max_fraction=args.max_fraction, pixel_max=args.pixel_max)
    for key, value in (("small_tol", args.small_tolerance), ("max_small_fraction", args.max_small_fraction),
                       ("max_mean", args.max_mean)):
        if value is not None:
            tolerances[key] = value
    result = compare_images(actual, expected, **tolerances)  # type: ignore[arg-type]
    mean = "" if "max_mean" in tolerances else f"; mean difference {result.mean_abs:.4g}/255"
    print(f"{'MATCH' if result.passed else 'DIFFER'}: {result.reason}{mean}")
    if args.diff is not None:
        write_png_atomic(Path(args.diff), diff_image(actual, expected, pixel_max=int(tolerances["pixel_max"])))
        print(f"diff image: {args.diff}")
    return 0 if result.passed else 1


def _shape(shape: tuple[int, ...]) -> str:
    return f"{shape[1]}x{shape[0]} with {shape[2]} channels"


def main(argv: list[str] | None = None) -> int:
    """Standalone entry (``python -m deformgl.testing.diff_cli``), until the CLI wires it in."""
    parser = argparse.ArgumentParser(prog="deformgl")
    add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return run(args)


if __name__ == "__main__":
    raise SystemExit(main())
