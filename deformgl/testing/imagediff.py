"""Image comparison for golden-image regression tests.

Renders are compared with :func:`compare_images`, which tolerates the small per-channel noise
that differs between GPU drivers but fails on broad changes (many pixels slightly off) and on
local breakage (any pixel far off). :func:`check_golden` wraps that for tests: it compares a
render with a golden PNG, and on failure writes the actual, expected and a magnified difference
image side by side so a person can see what changed.

PNG reading and atomic writing live in :mod:`deformgl.files`.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from deformgl.files import read_png, write_png_atomic

__all__ = [
    "DEFAULT_CHANNEL_TOL",
    "DEFAULT_MAX_FRACTION",
    "DEFAULT_MAX_MEAN",
    "DEFAULT_MAX_SMALL_FRACTION",
    "DEFAULT_PIXEL_MAX",
    "DEFAULT_SMALL_TOL",
    "SAME_RENDERER",
    "TOLERANCE_NAMES",
    "ImageDiff",
    "baselines",
    "check_golden",
    "compare_images",
    "diff_image",
]

DEFAULT_CHANNEL_TOL = 4
"""Per-channel difference (out of 255) up to which a pixel counts as unchanged."""

DEFAULT_MAX_FRACTION = 0.005
"""Largest fraction of pixels allowed to differ by more than the channel tolerance."""

DEFAULT_PIXEL_MAX = 64
"""Per-channel difference (out of 255) that no single pixel may exceed."""

DEFAULT_SMALL_TOL = 1
"""Per-channel difference (out of 255) above which a pixel counts towards the small-difference
fraction (see ``max_small_fraction``)."""

DEFAULT_MAX_SMALL_FRACTION = 1.0
"""Largest fraction of pixels allowed to differ by more than ``small_tol``; 1.0 (the default)
turns this test off, :data:`SAME_RENDERER` turns it on."""

DEFAULT_MAX_MEAN: float | None = None
"""Largest mean absolute difference (out of 255, the mean over pixels of each pixel's largest
channel difference); ``None`` (the default) turns this test off."""

SAME_RENDERER: dict[str, float] = {"small_tol": 1, "max_small_fraction": 0.001, "max_mean": 0.05}
"""Tolerances for baselines made by the same renderer (deformgl's goldens, on llvmpipe, which
renders byte-identical images run to run): besides the defaults' big-difference tests, at most
0.1 % of pixels may differ by more than 1/255 and the mean difference may not exceed 0.05/255.
They catch shading changes that move many pixels by 1 to 5 levels (a specular exponent x 1.1, a
specular strength x 1.05, a light tilted by 1 degree) which the defaults let through."""

TOLERANCE_NAMES = ("channel_tol", "max_fraction", "pixel_max", "small_tol", "max_small_fraction",
                   "max_mean")
"""The keyword arguments of :func:`compare_images` that set a tolerance."""

_RED = np.array([255, 0, 0], dtype=np.uint8)


@dataclass(frozen=True)
class ImageDiff:
    """The result of comparing two images.

    Attributes:
        passed: Whether the images match within the tolerances.
        fraction_over: Fraction of pixels (0 to 1) whose difference exceeds the channel
            tolerance in at least one channel; 1.0 when the shapes differ.
        max_abs: Largest absolute difference over all pixels and channels, out of 255;
            255 when the shapes differ.
        worst_pixel: ``(x, y)`` of the pixel with the largest difference (the first such pixel
            in row-major order); ``(0, 0)`` when the images are empty or the shapes differ.
        reason: A sentence for a person saying how the images differ and against what limits.
        mean_abs: Mean over pixels of each pixel's largest channel difference, out of 255;
            255.0 when the shapes differ.
        fraction_small: Fraction of pixels whose difference exceeds the small tolerance
            (``small_tol``); 1.0 when the shapes differ.
    """

    passed: bool
    fraction_over: float
    max_abs: int
    worst_pixel: tuple[int, int]
    reason: str
    mean_abs: float = 0.0
    fraction_small: float = 0.0


def _check_image(name: str, image: np.ndarray) -> None:
    """Raises if ``image`` is not a uint8 array of shape (H, W, 3) or (H, W, 4)."""
    if not isinstance(image, np.ndarray):
        raise TypeError(f"{name} must be a numpy array, got {type(image).__name__}")
    if image.dtype != np.uint8:
        raise TypeError(f"{name} must have dtype uint8, got {image.dtype}")
    if image.ndim != 3 or image.shape[2] not in (3, 4):
        raise ValueError(f"{name} must have shape (H, W, 3) or (H, W, 4), got {image.shape}")


def _check_level(name: str, value: int) -> None:
    """Raises if ``value`` is not an integer difference level from 0 to 255."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an int, got {type(value).__name__}")
    if not 0 <= value <= 255:
        raise ValueError(f"{name} must be between 0 and 255, got {value}")


def _format_percent(fraction: float) -> str:
    """Formats a fraction as a percentage without rounding small non-zero values to zero."""
    percent = fraction * 100.0
    if percent == 0.0:
        return "0"
    if percent < 0.01:
        return f"{percent:.2g}"
    return f"{percent:.2f}"


def _per_pixel_difference(actual: np.ndarray, expected: np.ndarray) -> np.ndarray:
    """Returns the largest absolute channel difference of each pixel, shape (H, W), int16."""
    difference = np.abs(actual.astype(np.int16) - expected.astype(np.int16))
    return difference.max(axis=2)


def compare_images(
    actual: np.ndarray,
    expected: np.ndarray,
    *,
    channel_tol: int = DEFAULT_CHANNEL_TOL,
    max_fraction: float = DEFAULT_MAX_FRACTION,
    pixel_max: int = DEFAULT_PIXEL_MAX,
    small_tol: int = DEFAULT_SMALL_TOL,
    max_small_fraction: float = DEFAULT_MAX_SMALL_FRACTION,
    max_mean: float | None = DEFAULT_MAX_MEAN,
) -> ImageDiff:
    """Compares two images with tolerances for rendering noise.

    A pixel counts as different when any of its channels (alpha included) differs by more than
    ``channel_tol``/255. The comparison fails when more than ``max_fraction`` of the pixels are
    different, or when any channel of any pixel differs by more than ``pixel_max``/255 (the
    big-difference tests), or when more than ``max_small_fraction`` of the pixels differ by more
    than ``small_tol``/255, or when the mean difference exceeds ``max_mean``/255 (the
    small-difference tests, off by default; :data:`SAME_RENDERER` turns them on).
    Differences are computed in int16, so 0 against 255 is a difference of 255.

    Args:
        actual: The image produced, uint8 of shape (H, W, 3) or (H, W, 4).
        expected: The reference image, same dtype and layout.
        channel_tol: Per-channel difference, out of 255, up to which a pixel is unchanged.
        max_fraction: Largest fraction of pixels (0 to 1) allowed to exceed ``channel_tol``.
        pixel_max: Per-channel difference, out of 255, that no pixel may exceed.
        small_tol: Per-channel difference, out of 255, above which a pixel counts as slightly
            different.
        max_small_fraction: Largest fraction of pixels (0 to 1) allowed to exceed ``small_tol``.
        max_mean: Largest mean difference, out of 255 (a float >= 0), or ``None`` for no limit.

    Returns:
        The result. Images of different shapes (including RGB against RGBA) do not raise; they
        give a failing result whose reason names both shapes.

    Raises:
        TypeError: An image is not a uint8 numpy array, or a tolerance has the wrong type.
        ValueError: An image is not (H, W, 3) or (H, W, 4), or a tolerance is out of range.
    """
    _check_image("actual", actual)
    _check_image("expected", expected)
    _check_level("channel_tol", channel_tol)
    _check_level("pixel_max", pixel_max)
    _check_level("small_tol", small_tol)
    for name, fraction in (("max_fraction", max_fraction), ("max_small_fraction", max_small_fraction)):
        if not 0.0 <= fraction <= 1.0:
            raise ValueError(f"{name} must be between 0 and 1, got {fraction}")
    if max_mean is not None and not 0.0 <= max_mean:
        raise ValueError(f"max_mean must be at least 0, got {max_mean}")

    if actual.shape != expected.shape:
        return ImageDiff(
            passed=False,
            fraction_over=1.0,
            max_abs=255,
            worst_pixel=(0, 0),
            reason=f"image shapes differ: actual {actual.shape}, expected {expected.shape}",
            mean_abs=255.0,
            fraction_small=1.0,
        )

    per_pixel = _per_pixel_difference(actual, expected)
    total = per_pixel.size
    count_over = int(np.count_nonzero(per_pixel > channel_tol))
    fraction_over = count_over / total if total else 0.0
    if total:
        y, x = np.unravel_index(int(np.argmax(per_pixel)), per_pixel.shape)
        worst_pixel = (int(x), int(y))
        max_abs = int(per_pixel[y, x])
    else:
        worst_pixel = (0, 0)
        max_abs = 0

    count_small = int(np.count_nonzero(per_pixel > small_tol))
    fraction_small = count_small / total if total else 0.0
    mean_abs = float(per_pixel.mean()) if total else 0.0

    too_many = fraction_over > max_fraction
    too_far = max_abs > pixel_max
    spread = (
        f"{count_over} of {total} pixels ({_format_percent(fraction_over)} %) differ by more "
        f"than {channel_tol}/255 (limit {max_fraction * 100:g} %)"
    )
    largest = (
        f"largest difference {max_abs}/255 at {worst_pixel} (limit {pixel_max}/255)"
    )
    checks = [(spread, too_many), (largest, too_far)]
    # the small-difference tests are reported only when they are on
    if max_small_fraction < 1.0:
        checks.append((
            f"{count_small} pixels ({_format_percent(fraction_small)} %) differ by more than "
            f"{small_tol}/255 (limit {max_small_fraction * 100:g} %)",
            fraction_small > max_small_fraction,
        ))
    if max_mean is not None:
        checks.append((f"mean difference {mean_abs:.4g}/255 (limit {max_mean:g}/255)",
                       mean_abs > max_mean))
    failed = any(bad for _, bad in checks)
    if failed:
        verdict = "images differ: " + " and ".join(text for text, bad in checks if bad)
        reason = verdict + "".join(f"; {text}" for text, bad in checks if not bad)
    else:
        reason = "images match: " + "; ".join(text for text, _ in checks)
    return ImageDiff(
        passed=not failed,
        fraction_over=fraction_over,
        max_abs=max_abs,
        worst_pixel=worst_pixel,
        reason=reason,
        mean_abs=mean_abs,
        fraction_small=fraction_small,
    )


def _as_rgba(image: np.ndarray) -> np.ndarray:
    """Returns ``image`` with four channels, adding an opaque alpha channel to RGB."""
    if image.shape[2] == 4:
        return image
    alpha = np.full(image.shape[:2] + (1,), 255, dtype=np.uint8)
    return np.concatenate([image, alpha], axis=2)


def diff_image(
    actual: np.ndarray,
    expected: np.ndarray,
    *,
    gain: int = 8,
    pixel_max: int = DEFAULT_PIXEL_MAX,
) -> np.ndarray:
    """Makes a picture of where two images differ, for a person to look at.

    Each pixel is grey with brightness ``min(255, gain * d)``, where ``d`` is the largest
    absolute channel difference of that pixel (alpha included); pixels with ``d > pixel_max``
    are pure red instead.

    When the shapes differ the result covers the larger height and the larger width: the
    region both images cover is compared as above (an RGB image is compared with an RGBA one
    as if it were opaque), and the area only one image covers is red.

    Args:
        actual: The image produced, uint8 of shape (H, W, 3) or (H, W, 4).
        expected: The reference image, same dtype and layout.
        gain: Magnification of the difference; at 8 a difference of 4/255 shows as 32/255.
        pixel_max: Per-channel difference, out of 255, above which a pixel is shown red.

    Returns:
        A uint8 RGB image of shape (H, W, 3).

    Raises:
        TypeError: An image is not a uint8 numpy array, or gain or pixel_max is not an int.
        ValueError: An image is not (H, W, 3) or (H, W, 4), or gain or pixel_max is out of
            range.
    """
    _check_image("actual", actual)
    _check_image("expected", expected)
    _check_level("pixel_max", pixel_max)
    if isinstance(gain, bool) or not isinstance(gain, (int, np.integer)):
        raise TypeError(f"gain must be an int, got {type(gain).__name__}")
    if gain < 1:
        raise ValueError(f"gain must be at least 1, got {gain}")

    height = max(actual.shape[0], expected.shape[0])
    width = max(actual.shape[1], expected.shape[1])
    out = np.empty((height, width, 3), dtype=np.uint8)
    out[...] = _RED

    common_h = min(actual.shape[0], expected.shape[0])
    common_w = min(actual.shape[1], expected.shape[1])
    a = actual[:common_h, :common_w]
    b = expected[:common_h, :common_w]
    if a.shape[2] != b.shape[2]:
        a, b = _as_rgba(a), _as_rgba(b)
    per_pixel = _per_pixel_difference(a, b)
    grey = np.minimum(per_pixel.astype(np.int32) * int(gain), 255).astype(np.uint8)
    region = out[:common_h, :common_w]
    region[...] = grey[..., np.newaxis]
    region[per_pixel > pixel_max] = _RED
    return out


def baselines(golden: Path) -> list[Path]:
    """The accepted baselines of a golden: ``golden`` itself and, VTK-style, its siblings
    ``<stem>_1.png``, ``<stem>_2.png``, ... (any number after the last underscore), for renderers
    that legitimately differ; those that exist, ``golden`` first, then by number."""
    golden = Path(golden)
    found = [golden] if golden.is_file() else []
    pattern = re.compile(re.escape(golden.stem) + r"_(\d+)" + re.escape(golden.suffix))
    if golden.parent.is_dir():
        numbered = [(int(m.group(1)), p) for p in golden.parent.iterdir()
                    if (m := pattern.fullmatch(p.name)) and p.is_file()]
        found += [p for _, p in sorted(numbered)]
    return found


def check_golden(
    actual: np.ndarray,
    golden: Path,
    *,
    update: bool,
    out_dir: Path,
    **tolerances: float,
) -> ImageDiff:
    """Compares a render with a golden PNG and its accepted alternatives, for use in tests.

    The render passes when it matches any of :func:`baselines` (``golden`` or a numbered
    sibling ``<stem>_N.png``).

    Args:
        actual: The render, uint8 of shape (H, W, 3) or (H, W, 4).
        golden: The golden PNG.
        update: Write ``actual`` to ``golden`` (creating its directory) instead of comparing;
            when numbered alternatives exist, only if the render matches none of the baselines
            (so that updating on one renderer does not overwrite another's baseline).
        out_dir: Where to write images when the comparison fails; created if needed.
        **tolerances: any of :data:`TOLERANCE_NAMES`, passed to :func:`compare_images`
            (``pixel_max`` also to :func:`diff_image`).

    Returns:
        The comparison result with the matching baseline, which has passed; in update mode, a
        passing result whose reason says the golden was written (or which baseline matched).

    Raises:
        AssertionError: No baseline exists (the message says how to create one), or the
            render matches none; then ``<out_dir>/<stem>-actual.png``, ``<stem>-expected.png``
            (the closest baseline, by mean difference) and ``<stem>-diff.png`` are written and
            the message gives the reasons and their paths.
        TypeError: ``tolerances`` has an unknown name, or an argument has the wrong type.
        ValueError: ``actual`` has an unsupported shape, or a tolerance is out of range.
    """
    golden = Path(golden)
    out_dir = Path(out_dir)
    _check_image("actual", actual)
    unknown = sorted(set(tolerances) - set(TOLERANCE_NAMES))
    if unknown:
        raise TypeError(f"unknown tolerance(s): {', '.join(unknown)}")
    found = baselines(golden)
    results = []
    for path in found:
        expected = read_png(path)
        result = compare_images(actual, expected, **tolerances)  # type: ignore[arg-type]
        if result.passed and not (update and found == [golden]):
            if update:
                result = dataclasses.replace(
                    result, reason=f"render matches baseline {path}; nothing written (update mode)")
            return result
        results.append((path, expected, result))

    if update:
        golden.parent.mkdir(parents=True, exist_ok=True)
        write_png_atomic(golden, actual)
        return ImageDiff(
            passed=True,
            fraction_over=0.0,
            max_abs=0,
            worst_pixel=(0, 0),
            reason=f"golden image {golden} written (update mode)",
        )

    if not found:
        raise AssertionError(
            f"golden image {golden} is missing; run pytest --update-goldens to create it, "
            "then look at it"
        )

    path, expected, result = min(results, key=lambda item: (item[2].mean_abs, item[2].fraction_over))
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = golden.stem
    actual_path = out_dir / f"{stem}-actual.png"
    expected_path = out_dir / f"{stem}-expected.png"
    diff_path = out_dir / f"{stem}-diff.png"
    pixel_max = int(tolerances.get("pixel_max", DEFAULT_PIXEL_MAX))
    write_png_atomic(actual_path, actual)
    write_png_atomic(expected_path, expected)
    write_png_atomic(diff_path, diff_image(actual, expected, pixel_max=pixel_max))
    others = "".join(f"\n  also tried {p}: {r.reason}" for p, _, r in results if p != path)
    raise AssertionError(
        f"render does not match golden image {path}: {result.reason}{others}\n"
        f"  actual:   {actual_path}\n"
        f"  expected: {expected_path}\n"
        f"  diff:     {diff_path}"
    )
