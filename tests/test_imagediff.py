"""Tests for deformgl.testing.imagediff: tolerant image comparison, diff images, atomic PNG writing."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from deformgl.files import read_png, write_png_atomic

from deformgl.testing.imagediff import ImageDiff, check_golden, compare_images, diff_image

HEIGHT, WIDTH = 100, 120  # not square, so swapped x and y show up


def gradient(channels: int = 3) -> np.ndarray:
    """A deterministic image whose values stay between 20 and 230, away from clipping."""
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH]
    planes = [20 + (x * 2) % 200, 20 + (y * 2) % 200, 20 + (x + y) % 200, 20 + (x * y) % 200]
    return np.stack(planes[:channels], axis=2).astype(np.uint8)


def with_pixels_changed(image: np.ndarray, count: int, delta: int, seed: int = 0) -> np.ndarray:
    """Returns a copy with ``count`` distinct random pixels raised by ``delta`` in channel 1."""
    rng = np.random.default_rng(seed)
    flat = rng.choice(image.shape[0] * image.shape[1], size=count, replace=False)
    ys, xs = np.unravel_index(flat, image.shape[:2])
    changed = image.copy()
    changed[ys, xs, 1] += np.uint8(delta)
    return changed


# --- compare_images -----------------------------------------------------------------------


def test_identical_images_pass() -> None:
    image = gradient()
    result = compare_images(image, image.copy())
    assert result == ImageDiff(
        passed=True,
        fraction_over=0.0,
        max_abs=0,
        worst_pixel=(0, 0),
        reason=result.reason,
    )
    assert result.reason.startswith("images match")


@pytest.mark.parametrize(("delta", "passed"), [(64, True), (65, False)])
def test_single_pixel_against_pixel_max(delta: int, passed: bool) -> None:
    expected = gradient()
    actual = expected.copy()
    actual[44, 110, 2] += delta  # row 44, column 110
    result = compare_images(actual, expected)
    assert result.passed is passed
    assert result.max_abs == delta
    assert result.worst_pixel == (110, 44)
    assert result.fraction_over == pytest.approx(1 / (HEIGHT * WIDTH))
    if not passed:
        assert f"largest difference {delta}/255 at (110, 44) (limit 64/255)" in result.reason


def test_pixel_max_is_configurable() -> None:
    expected = gradient()
    actual = expected.copy()
    actual[3, 4, 0] += 30
    assert compare_images(actual, expected).passed
    assert not compare_images(actual, expected, pixel_max=29).passed


@pytest.mark.parametrize(("percent", "passed"), [(1.0, False), (0.4, True)])
def test_broad_small_change_against_max_fraction(percent: float, passed: bool) -> None:
    expected = gradient()
    count = round(HEIGHT * WIDTH * percent / 100)
    actual = with_pixels_changed(expected, count, 5)
    result = compare_images(actual, expected)
    assert result.passed is passed
    assert result.fraction_over == pytest.approx(percent / 100)
    assert result.max_abs == 5
    assert f"{count} of {HEIGHT * WIDTH} pixels ({percent:.2f} %)" in result.reason
    assert "more than 4/255 (limit 0.5 %)" in result.reason


@pytest.mark.parametrize(("count", "passed"), [(60, True), (61, False)])
def test_exactly_max_fraction_passes(count: int, passed: bool) -> None:
    expected = gradient()  # 12000 pixels, so 60 of them are exactly 0.5 %
    actual = with_pixels_changed(expected, count, 5)
    assert compare_images(actual, expected).passed is passed


def test_changes_at_channel_tol_are_not_counted() -> None:
    expected = gradient()
    actual = with_pixels_changed(expected, HEIGHT * WIDTH // 10, 4)
    result = compare_images(actual, expected)
    assert result.passed
    assert result.fraction_over == 0.0
    assert not compare_images(actual, expected, channel_tol=3).passed


def test_subthreshold_noise_everywhere_passes() -> None:
    expected = gradient(4)
    rng = np.random.default_rng(7)
    noise = rng.integers(-4, 5, size=expected.shape)
    actual = (expected.astype(np.int16) + noise).astype(np.uint8)
    assert np.abs(actual.astype(np.int16) - expected).max() == 4
    result = compare_images(actual, expected)
    assert result.passed, result.reason
    assert result.max_abs == 4
    # The same noise is far over the limit once the tolerance is one level lower.
    assert not compare_images(actual, expected, channel_tol=3).passed


def test_no_uint8_wraparound() -> None:
    expected = np.zeros((4, 5, 3), dtype=np.uint8)
    actual = expected.copy()
    actual[1, 2] = 255  # 0 - 255 would wrap to 1 in uint8
    result = compare_images(actual, expected)
    assert not result.passed
    assert result.max_abs == 255
    assert result.worst_pixel == (2, 1)
    reverse = compare_images(expected, actual)
    assert not reverse.passed
    assert reverse.max_abs == 255


def test_rgba_alpha_channel_is_compared() -> None:
    expected = gradient(4)
    actual = expected.copy()
    actual[10, 20, 3] += 65
    result = compare_images(actual, expected)
    assert not result.passed
    assert result.max_abs == 65
    assert result.worst_pixel == (20, 10)


def test_shape_mismatch_fails_and_names_both_shapes() -> None:
    actual = np.zeros((10, 12, 3), dtype=np.uint8)
    for expected in (np.zeros((10, 13, 3), dtype=np.uint8), np.zeros((10, 12, 4), np.uint8)):
        result = compare_images(actual, expected)
        assert not result.passed
        assert str(actual.shape) in result.reason
        assert str(expected.shape) in result.reason
        assert result.fraction_over == 1.0


def test_reason_for_failure_reads_as_a_sentence() -> None:
    expected = gradient()
    actual = with_pixels_changed(expected, 83, 37)  # 0.69 % of the 12000 pixels
    result = compare_images(actual, expected)
    assert not result.passed
    x, y = result.worst_pixel
    assert result.reason == (
        "images differ: 83 of 12000 pixels (0.69 %) differ by more than 4/255 (limit 0.5 %); "
        f"largest difference 37/255 at ({x}, {y}) (limit 64/255)"
    )
    assert actual[y, x, 1] - expected[y, x, 1] == 37


@pytest.mark.parametrize(
    ("actual", "expected", "error"),
    [
        (np.zeros((4, 4, 3), np.float32), np.zeros((4, 4, 3), np.uint8), TypeError),
        (np.zeros((4, 4), np.uint8), np.zeros((4, 4), np.uint8), ValueError),
        (np.zeros((4, 4, 2), np.uint8), np.zeros((4, 4, 2), np.uint8), ValueError),
    ],
)
def test_bad_inputs_raise(actual: np.ndarray, expected: np.ndarray, error: type) -> None:
    with pytest.raises(error):
        compare_images(actual, expected)


def test_bad_tolerances_raise() -> None:
    image = gradient()
    with pytest.raises(ValueError, match="pixel_max"):
        compare_images(image, image, pixel_max=256)
    with pytest.raises(ValueError, match="max_fraction"):
        compare_images(image, image, max_fraction=1.5)
    with pytest.raises(TypeError, match="channel_tol"):
        compare_images(image, image, channel_tol=4.5)  # type: ignore[arg-type]


# --- diff_image ---------------------------------------------------------------------------


def test_diff_image_magnifies_and_marks_bad_pixels_red() -> None:
    expected = gradient(4)
    actual = expected.copy()
    actual[5, 7, 0] += 3  # small: shown magnified, grey
    actual[6, 9, 3] -= 40  # alpha only, capped at 255 by the gain
    actual[50, 100, 2] += 65  # over pixel_max: red
    diff = diff_image(actual, expected)
    assert diff.dtype == np.uint8
    assert diff.shape == (HEIGHT, WIDTH, 3)
    assert diff[5, 7].tolist() == [24, 24, 24]
    assert diff[6, 9].tolist() == [255, 255, 255]
    assert diff[50, 100].tolist() == [255, 0, 0]
    untouched = np.ones((HEIGHT, WIDTH), bool)
    untouched[[5, 6, 50], [7, 9, 100]] = False
    assert not diff[untouched].any()
    assert diff_image(actual, expected, gain=2)[5, 7].tolist() == [6, 6, 6]
    assert diff_image(actual, expected, pixel_max=65)[50, 100].tolist() == [255, 255, 255]


def test_diff_image_for_shape_mismatch_covers_the_larger_size() -> None:
    actual = np.zeros((10, 6, 3), dtype=np.uint8)
    expected = np.zeros((8, 9, 4), dtype=np.uint8)
    expected[..., 3] = 255  # opaque, so it matches the RGB image where both exist
    expected[2, 3, 0] = 10
    diff = diff_image(actual, expected)
    assert diff.shape == (10, 9, 3)
    assert diff[2, 3].tolist() == [80, 80, 80]
    overlap = diff[:8, :6].copy()
    overlap[2, 3] = 0
    assert not overlap.any()
    assert (diff[8:, :] == [255, 0, 0]).all()
    assert (diff[:, 6:] == [255, 0, 0]).all()


# --- write_png_atomic and read_png --------------------------------------------------------


@pytest.mark.parametrize("channels", [3, 4])
def test_write_then_read_round_trips(tmp_path: Path, channels: int) -> None:
    image = gradient(channels)
    path = tmp_path / "out.png"
    write_png_atomic(path, image)
    assert os.listdir(tmp_path) == ["out.png"]
    with Image.open(path) as opened:
        assert opened.format == "PNG"
    back = read_png(path)
    assert back.dtype == np.uint8
    np.testing.assert_array_equal(back, image)


def test_write_png_atomic_replaces_existing_file(tmp_path: Path) -> None:
    path = tmp_path / "out.png"
    write_png_atomic(path, np.zeros((2, 3, 3), np.uint8))
    write_png_atomic(str(path), gradient())
    np.testing.assert_array_equal(read_png(path), gradient())
    assert os.listdir(tmp_path) == ["out.png"]


def test_write_png_atomic_uses_normal_permissions(tmp_path: Path) -> None:
    umask = os.umask(0o022)
    try:
        write_png_atomic(tmp_path / "out.png", gradient())
    finally:
        os.umask(umask)
    assert stat.S_IMODE((tmp_path / "out.png").stat().st_mode) == 0o644


def test_failed_write_keeps_old_file_and_leaves_no_temporary(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "out.png"
    write_png_atomic(path, gradient())
    before = path.read_bytes()

    def save_half_then_fail(
        self: Image.Image, fp: object, *args: object, **kwargs: object
    ) -> None:
        fp.write(b"\x89PNG\r\n\x1a\n partial")  # type: ignore[attr-defined]
        raise OSError("disk full")

    monkeypatch.setattr(Image.Image, "save", save_half_then_fail)
    with pytest.raises(OSError, match="disk full"):
        write_png_atomic(path, np.zeros((HEIGHT, WIDTH, 3), np.uint8))
    assert os.listdir(tmp_path) == ["out.png"]
    assert path.read_bytes() == before


def test_failed_write_to_new_path_leaves_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def fail(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(KeyboardInterrupt):
        write_png_atomic(tmp_path / "new.png", gradient())
    assert os.listdir(tmp_path) == []


def test_write_png_atomic_rejects_bad_arrays_and_missing_directory(tmp_path: Path) -> None:
    with pytest.raises(TypeError):
        write_png_atomic(tmp_path / "a.png", np.zeros((2, 2, 3), np.float64))
    with pytest.raises(ValueError):
        write_png_atomic(tmp_path / "a.png", np.zeros((2, 2, 5), np.uint8))
    with pytest.raises(FileNotFoundError, match="does not exist"):
        write_png_atomic(tmp_path / "missing" / "a.png", gradient())
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize(
    ("mode", "shape"),
    [("L", (HEIGHT, WIDTH, 3)), ("P", (HEIGHT, WIDTH, 3)), ("LA", (HEIGHT, WIDTH, 4))],
)
def test_read_png_converts_to_rgb_or_rgba(
    tmp_path: Path, mode: str, shape: tuple[int, int, int]
) -> None:
    path = tmp_path / "in.png"
    Image.fromarray(gradient()).convert(mode).save(path)
    image = read_png(path)
    assert image.dtype == np.uint8
    assert image.shape == shape


# --- check_golden -------------------------------------------------------------------------


def test_check_golden_update_writes_golden(tmp_path: Path) -> None:
    golden = tmp_path / "tests" / "golden" / "scene.png"
    out_dir = tmp_path / "out"
    result = check_golden(gradient(), golden, update=True, out_dir=out_dir)
    assert result.passed
    np.testing.assert_array_equal(read_png(golden), gradient())
    assert not out_dir.exists()


def test_check_golden_missing_golden_says_how_to_create_it(tmp_path: Path) -> None:
    golden = tmp_path / "golden" / "x.png"
    with pytest.raises(AssertionError) as raised:
        check_golden(gradient(), golden, update=False, out_dir=tmp_path / "out")
    message = str(raised.value)
    assert f"golden image {golden} is missing" in message
    assert "pytest --update-goldens" in message
    assert not golden.exists()


def test_check_golden_pass_returns_diff_and_writes_nothing(tmp_path: Path) -> None:
    golden = tmp_path / "x.png"
    write_png_atomic(golden, gradient())
    out_dir = tmp_path / "out"
    actual = gradient()
    actual[1, 2, 0] += 3
    result = check_golden(actual, golden, update=False, out_dir=out_dir)
    assert isinstance(result, ImageDiff)
    assert result.passed
    assert result.max_abs == 3
    assert result.worst_pixel == (2, 1)
    assert not out_dir.exists()


def test_check_golden_failure_writes_three_images_and_names_them(tmp_path: Path) -> None:
    golden = tmp_path / "golden" / "scene.png"
    golden.parent.mkdir()
    write_png_atomic(golden, gradient())
    out_dir = tmp_path / "out"
    actual = gradient()
    actual[44, 110, 1] += 65
    with pytest.raises(AssertionError) as raised:
        check_golden(actual, golden, update=False, out_dir=out_dir)
    message = str(raised.value)
    paths = {kind: out_dir / f"scene-{kind}.png" for kind in ("actual", "expected", "diff")}
    for path in paths.values():
        assert str(path) in message
    assert "largest difference 65/255 at (110, 44)" in message
    assert str(golden) in message
    assert sorted(os.listdir(out_dir)) == sorted(path.name for path in paths.values())
    np.testing.assert_array_equal(read_png(paths["actual"]), actual)
    np.testing.assert_array_equal(read_png(paths["expected"]), gradient())
    diff = read_png(paths["diff"])
    assert diff[44, 110].tolist() == [255, 0, 0]
    assert diff.sum() == 255


def test_check_golden_passes_tolerances_through(tmp_path: Path) -> None:
    golden = tmp_path / "x.png"
    write_png_atomic(golden, gradient())
    actual = gradient()
    actual[44, 110, 1] += 65
    result = check_golden(actual, golden, update=False, out_dir=tmp_path / "out", pixel_max=65)
    assert result.passed
    with pytest.raises(AssertionError):
        check_golden(
            actual, golden, update=False, out_dir=tmp_path / "out", channel_tol=70, pixel_max=64
        )
    with pytest.raises(TypeError, match="pixelmax"):
        check_golden(actual, golden, update=False, out_dir=tmp_path / "out", pixelmax=65)


def test_check_golden_shape_mismatch_fails_with_both_shapes(tmp_path: Path) -> None:
    golden = tmp_path / "x.png"
    write_png_atomic(golden, gradient(4))
    with pytest.raises(AssertionError) as raised:
        check_golden(gradient(3), golden, update=False, out_dir=tmp_path / "out")
    message = str(raised.value)
    assert f"({HEIGHT}, {WIDTH}, 3)" in message
    assert f"({HEIGHT}, {WIDTH}, 4)" in message
    assert (tmp_path / "out" / "x-diff.png").is_file()


# --- small-difference tests and accepted baselines ------------------------------------------


def test_small_differences_pass_by_default_and_fail_the_same_renderer_tolerances() -> None:
    from deformgl.testing.imagediff import SAME_RENDERER

    expected = gradient()
    actual = with_pixels_changed(expected, 240, 3)  # 2 % of pixels 3/255 off: shading, not noise
    loose = compare_images(actual, expected)
    assert loose.passed and "1/255" not in loose.reason and "mean" not in loose.reason
    assert loose.fraction_small == pytest.approx(0.02)
    assert loose.mean_abs == pytest.approx(0.06)
    strict = compare_images(actual, expected, **SAME_RENDERER)
    assert not strict.passed
    assert strict.reason.startswith(
        "images differ: 240 pixels (2.00 %) differ by more than 1/255 (limit 0.1 %) and "
        "mean difference 0.06/255 (limit 0.05/255)")
    # one level of noise everywhere is not counted by the small fraction, only by the mean
    noisy = compare_images(gradient() + np.uint8(1), expected, small_tol=1, max_small_fraction=0.0)
    assert noisy.passed
    assert not compare_images(gradient() + np.uint8(1), expected, max_mean=0.5).passed
    assert compare_images(actual, expected, max_mean=0.07).passed


def test_small_difference_tolerances_are_checked() -> None:
    image = gradient()
    with pytest.raises(ValueError, match="max_small_fraction"):
        compare_images(image, image, max_small_fraction=1.5)
    with pytest.raises(ValueError, match="max_mean"):
        compare_images(image, image, max_mean=-1.0)
    with pytest.raises(ValueError, match="small_tol"):
        compare_images(image, image, small_tol=256)


def test_numbered_baselines_are_accepted_alternatives(tmp_path: Path) -> None:
    from deformgl.testing.imagediff import baselines

    golden = tmp_path / "scene.png"
    other = gradient()
    other[:, :, 0] = 0  # another renderer's picture
    write_png_atomic(golden, gradient())
    write_png_atomic(tmp_path / "scene_2.png", other)
    write_png_atomic(tmp_path / "scene_10.png", gradient())
    write_png_atomic(tmp_path / "scene_x.png", other)  # not a number: not an alternative
    write_png_atomic(tmp_path / "scene_2_1.png", other)  # belongs to scene_2
    assert baselines(golden) == [golden, tmp_path / "scene_2.png", tmp_path / "scene_10.png"]
    assert check_golden(other, golden, update=False, out_dir=tmp_path / "out").passed
    changed = gradient()
    changed[:, :, 2] = 255
    with pytest.raises(AssertionError) as raised:
        check_golden(changed, golden, update=False, out_dir=tmp_path / "out")
    assert str(tmp_path / "scene_2.png") in str(raised.value)  # the others tried are named
    # update with alternatives: a match writes nothing, no match writes the primary
    before = golden.read_bytes()
    assert "nothing written" in check_golden(other, golden, update=True, out_dir=tmp_path / "out").reason
    assert golden.read_bytes() == before
    check_golden(changed, golden, update=True, out_dir=tmp_path / "out")
    np.testing.assert_array_equal(read_png(golden), changed)
    # only alternatives, no primary: they are still the baselines
    golden.unlink()
    assert check_golden(other, golden, update=False, out_dir=tmp_path / "out").passed


def test_check_golden_accepts_the_new_tolerances_and_rejects_unknown_ones(tmp_path: Path) -> None:
    golden = tmp_path / "x.png"
    write_png_atomic(golden, gradient())
    actual = with_pixels_changed(gradient(), 240, 3)
    assert check_golden(actual, golden, update=False, out_dir=tmp_path / "out").passed
    with pytest.raises(AssertionError, match="more than 1/255"):
        check_golden(actual, golden, update=False, out_dir=tmp_path / "out", max_small_fraction=0.01)
    with pytest.raises(TypeError, match="max_means"):
        check_golden(actual, golden, update=False, out_dir=tmp_path / "out", max_means=1.0)
