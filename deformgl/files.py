"""Atomic file output and PNG I/O: every file deformgl writes goes through :func:`write_atomic`.

A file is written to a temporary file in the target directory, flushed to disk, then renamed over
the target, so a reader never sees a partial file and a failed write leaves an existing file as
it was.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

import numpy as np
from PIL import Image

__all__ = ["read_png", "write_atomic", "write_png_atomic"]


def write_png_atomic(path: str | os.PathLike[str], array: np.ndarray) -> None:
    """Writes an image as a PNG so that ``path`` never holds a partial file.

    The PNG is written to a temporary file in the same directory, flushed to disk, and then
    renamed over ``path`` with :func:`os.replace`. If anything fails the temporary file is
    removed and an existing file at ``path`` is left as it was. The new file gets the usual
    permissions for a new file (``0o666`` less the umask).

    Args:
        path: Where to write the PNG. Its directory must exist.
        array: uint8 image of shape (H, W) (grey), (H, W, 3) (RGB) or (H, W, 4) (RGBA).

    Raises:
        TypeError: ``array`` is not a uint8 numpy array.
        ValueError: ``array`` has an unsupported shape.
        FileNotFoundError: The directory of ``path`` does not exist.
        OSError: The file could not be written or renamed.
    """
    if not isinstance(array, np.ndarray):
        raise TypeError(f"array must be a numpy array, got {type(array).__name__}")
    if array.dtype != np.uint8:
        raise TypeError(f"array must have dtype uint8, got {array.dtype}")
    if not (array.ndim == 2 or (array.ndim == 3 and array.shape[2] in (3, 4))):
        raise ValueError(
            f"array must have shape (H, W), (H, W, 3) or (H, W, 4), got {array.shape}"
        )
    image = Image.fromarray(np.ascontiguousarray(array))
    write_atomic(path, lambda stream: image.save(stream, format="PNG"))


def write_atomic(path: str | os.PathLike[str], write: Callable[[BinaryIO], object]) -> None:
    """Write a file so that ``path`` never holds a partial one: ``write(stream)`` fills a
    temporary file in the same directory (its return value is ignored), which is flushed to
    disk and renamed over ``path``.
    On any failure the temporary file is removed and an existing ``path`` is left as it was. The
    new file gets the usual permissions for a new file (``0o666`` less the umask).

    Raises:
        FileNotFoundError: The directory of ``path`` does not exist.
        OSError: The file could not be written or renamed.
    """
    target = Path(path)
    directory = target.parent
    if not directory.is_dir():
        raise FileNotFoundError(f"cannot write {target}: directory {directory} does not exist")

    # os.open with O_EXCL and mode 0o666 (rather than tempfile.mkstemp, which uses 0o600) so
    # that the renamed file gets the same permissions as any other new file.
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)
    for _ in range(100):
        temporary = directory / f".{target.name}.{secrets.token_hex(6)}.tmp"
        try:
            fd = os.open(temporary, flags, 0o666)
            break
        except FileExistsError:
            continue
    else:
        raise FileExistsError(f"cannot create a temporary file next to {target}")

    try:
        with os.fdopen(fd, "wb") as stream:
            write(stream)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, target)
    except BaseException:
        try:
            os.unlink(temporary)
        except FileNotFoundError:
            pass
        raise


def read_png(path: str | os.PathLike[str]) -> np.ndarray:
    """Reads an image file into a uint8 RGB or RGBA array.

    Images with an alpha channel or palette transparency become (H, W, 4); all others,
    greyscale and palette images included, become (H, W, 3). 16-bit images are reduced to
    8 bits by Pillow's conversion.

    Args:
        path: The file to read.

    Returns:
        A uint8 array of shape (H, W, 3) or (H, W, 4).

    Raises:
        FileNotFoundError: ``path`` does not exist.
        PIL.UnidentifiedImageError: ``path`` is not an image Pillow can read.
    """
    with Image.open(path) as image:
        image.load()
        converted: Image.Image
        if image.mode in ("RGB", "RGBA"):
            converted = image
        elif "A" in image.getbands() or "transparency" in image.info:
            converted = image.convert("RGBA")
        else:
            converted = image.convert("RGB")
        return np.array(converted, dtype=np.uint8)
