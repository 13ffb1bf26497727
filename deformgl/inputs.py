"""Bounded readers of user input files: every size limit deformgl puts on what it reads.

A user file can be far larger in memory than on disk (a 20 MB ``.ply.gz`` can inflate to
20 GiB, a 17 KB PNG can decode to 12000 x 12000 pixels), so each reader checks its limit before
or while it reads, never after:

* :func:`read_bounded` reads a file, gunzipping it in chunks, and stops as soon as the bytes read
  pass :func:`max_mesh_bytes` (``DEFORMGL_MAX_MESH_BYTES``, default 2 GiB);
* :func:`read_image` reads an image whose header gives at most :func:`max_image_pixels`
  pixels (``DEFORMGL_MAX_IMAGE_PIXELS``, default 8192 x 8192, checked by
  :func:`deformgl.files.read_png` from the header before any pixel is decoded);
* :func:`max_coordinate` is the bound on mesh coordinates (``DEFORMGL_MAX_COORDINATE``,
  default 1e15), checked by :func:`deformgl.grid.meshio.load_mesh`.

Each limit is read from its environment variable when it is used, so a caller may set it at any
time; docs/INPUTS.md lists them. Every refusal is one :class:`InputError` line naming the file.
"""

from __future__ import annotations

import gzip
import io
import math
import os
import zlib
from pathlib import Path

import numpy as np

from deformgl.errors import InputError
from deformgl.files import read_png

__all__ = [
    "DEFAULT_MAX_COORDINATE", "DEFAULT_MAX_IMAGE_PIXELS", "DEFAULT_MAX_MESH_BYTES",
    "max_coordinate", "max_image_pixels", "max_mesh_bytes", "read_bounded", "read_image",
]

#: Default of ``DEFORMGL_MAX_MESH_BYTES``: 2 GiB of (decompressed) mesh file. Parsing takes a few
#: times the file size (a 2 GiB binary PLY is about 80 million triangles), so this keeps a run
#: within the memory of a workstation while admitting every published scan (Stanford's Lucy, 28
#: million triangles, is 0.5 GB).
DEFAULT_MAX_MESH_BYTES = 2 * 1024**3

#: Default of ``DEFORMGL_MAX_IMAGE_PIXELS``: an 8192 x 8192 ("8K") texture, 256 MiB as RGBA.
#: Pillow's own guard refuses anything over 178,956,970 pixels whatever this is set to.
DEFAULT_MAX_IMAGE_PIXELS = 8192 * 8192

#: Default of ``DEFORMGL_MAX_COORDINATE``: no real model is 1e15 units across, and squares and
#: sums of coordinates this size stay far from float64 overflow (about 1e154 squared).
DEFAULT_MAX_COORDINATE = 1e15

_CHUNK = 1 << 20  # gzip is inflated 1 MiB at a time


def _env_limit(name: str, default: float, integer: bool) -> float:
    """The positive number in environment variable ``name``, or ``default`` when unset/empty."""
    text = os.environ.get(name, "").strip().replace("_", "")
    if not text:
        return default
    try:
        value = int(text) if integer else float(text)
    except ValueError:
        value = -1
    if not (value > 0 and math.isfinite(value)):
        kind = "a positive integer" if integer else "a positive number"
        raise InputError(f"environment variable {name}: must be {kind}, got {os.environ[name]!r}")
    return value


def max_mesh_bytes() -> int:
    """Bytes a mesh or node file may hold once decompressed (``DEFORMGL_MAX_MESH_BYTES``)."""
    return int(_env_limit("DEFORMGL_MAX_MESH_BYTES", DEFAULT_MAX_MESH_BYTES, integer=True))


def max_image_pixels() -> int:
    """Pixels (width x height) an input image may have (``DEFORMGL_MAX_IMAGE_PIXELS``)."""
    return int(_env_limit("DEFORMGL_MAX_IMAGE_PIXELS", DEFAULT_MAX_IMAGE_PIXELS, integer=True))


def max_coordinate() -> float:
    """Largest absolute mesh coordinate accepted (``DEFORMGL_MAX_COORDINATE``)."""
    return _env_limit("DEFORMGL_MAX_COORDINATE", DEFAULT_MAX_COORDINATE, integer=False)


def _too_big(name: str, limit: int, what: str) -> InputError:
    return InputError(f"{name}: {what} more than {limit:,} bytes, the limit "
                      f"(set DEFORMGL_MAX_MESH_BYTES to raise it)")


def read_bounded(path: Path, name: str, compressed: bool) -> bytes:
    """Read a file's bytes, gunzipping when ``compressed``, refusing more than
    :func:`max_mesh_bytes`; a gzip file is inflated chunk by chunk and abandoned at the limit, so
    a decompression bomb costs at most the limit in memory and the time to inflate it.

    Args:
        path: the file.
        name: the file as the user gave it, for messages.
        compressed: whether the file is gzip-compressed.

    Raises:
        InputError: unreadable, too large, or (``compressed``) not a valid gzip file.
    """
    limit = max_mesh_bytes()
    try:
        if path.stat().st_size > limit:
            raise _too_big(name, limit, "file holds")
        if not compressed:
            return path.read_bytes()
        out = io.BytesIO()
        with gzip.open(path, "rb") as stream:
            while chunk := stream.read(_CHUNK):
                if out.write(chunk) and out.tell() > limit:
                    raise _too_big(name, limit, "decompresses to")
        return out.getvalue()
    except (EOFError, zlib.error, gzip.BadGzipFile) as exc:
        raise InputError(f"{name}: not a valid gzip file: {_one_line(exc)}") from None
    except OSError as exc:
        raise InputError(f"{name}: cannot read file: {exc.strerror or _one_line(exc)}") from None


def read_image(path: str | os.PathLike[str]) -> np.ndarray:
    """:func:`deformgl.files.read_png` (which checks the pixel count in the header against
    :func:`max_image_pixels` before decoding, and refuses corrupt data as InputError) with a
    missing or unidentifiable file also one InputError line."""
    name = os.fspath(path)
    try:
        return read_png(path, max_pixels=max_image_pixels())
    except OSError as exc:
        text = _one_line(exc) if not exc.strerror else exc.strerror
        raise InputError(text if text.startswith(name) else f"{name}: cannot read image: {text}") from None


def _one_line(exc: BaseException) -> str:
    """An exception's text on one line, or its type name when the text is empty."""
    return " ".join(str(exc).split()) or type(exc).__name__
