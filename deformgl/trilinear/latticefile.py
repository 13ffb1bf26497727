"""Lattice files of scene graphs (``grid = { file = "lattice.npy", box = {...} }``, docs/SCENEGRAPH.md):
a ``.npy`` array of shape (nx + 1, ny + 1, nz + 1, 3), read and checked before any GL work.

The header (magic, dtype, shape, byte count) is checked before any data is read; then every value
must be finite and every lattice point within :data:`MAX_LATTICE_EXTENT` box sizes of the box's
centre. Why that bound: the lattice is evaluated and projected in float32 on the GPU (24-bit
significand, a relative rounding of 6e-8), and the camera frames the whole image of the grid. A
point 1e6 box sizes away rounds every coordinate by about 0.06 of the box, and shrinks the box's
content to a millionth of the frame: beyond it the deformation no longer has a meaningful image
(at 1e39, past float32's 3.4e38, it is infinite and nothing is drawn). Values beyond float32
are named as such.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from deformgl.errors import InputError
from deformgl.trilinear.cuboid import Box
from deformgl.trilinear.graphspec import MAX_LATTICE_POINTS

#: The farthest a lattice point may be from its box's centre, in box sizes (the largest edge),
#: along any axis (see the module docstring).
MAX_LATTICE_EXTENT = 1e6
#: The largest finite float32 (a value beyond it is infinite on the GPU).
FLOAT32_MAX = float(np.finfo(np.float32).max)


def _header(stream, shown: str) -> tuple[tuple[int, ...], np.dtype, int]:
    magic = stream.read(6)
    if magic != b"\x93NUMPY":
        if not magic:
            kind = "an empty file"
        elif magic[:4] == b"PK\x03\x04":
            kind = "a .npz archive (save one array with numpy.save)"
        else:
            kind = "something else (no .npy magic bytes)"
        raise InputError(f"{shown}: a lattice must be a .npy array, got {kind}")
    stream.seek(0)
    try:
        version = np.lib.format.read_magic(stream)
        reader = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape, _, dtype = reader(stream)
    except (ValueError, EOFError, SyntaxError, TypeError) as exc:
        raise InputError(f"{shown}: not a valid .npy file: {' '.join(str(exc).split())[:200]}") from None
    return tuple(int(n) for n in shape), np.dtype(dtype), stream.tell()


def _check_header(shown: str, shape: tuple[int, ...], dtype: np.dtype) -> None:
    if dtype.kind not in "iuf" or dtype.fields is not None:
        raise InputError(f"{shown}: a lattice must hold real numbers (float or integer), got dtype {dtype}")
    if len(shape) != 4 or shape[3] != 3 or min(shape[:3]) < 2:
        raise InputError(f"{shown}: a lattice must have shape (nx+1, ny+1, nz+1, 3) with at least 2 points "
                         f"on each axis, got {shape}")
    points = shape[0] * shape[1] * shape[2]
    if points > MAX_LATTICE_POINTS:
        raise InputError(f"{shown}: {points} lattice points, at most {MAX_LATTICE_POINTS}")


def check_lattice(shown: str, points: np.ndarray, box: Box) -> np.ndarray:
    """``points`` (nx+1, ny+1, nz+1, 3) as float64, checked: finite, within float32 and within
    :data:`MAX_LATTICE_EXTENT` box sizes of ``box``'s centre; errors name the lattice point."""
    raw = np.asarray(points)
    p = raw.astype(np.float64)
    bad = ~np.isfinite(p)
    if bad.any():
        i, j, k, c = (int(v) for v in np.argwhere(bad)[0])
        raise InputError(f"{shown}: lattice point [{i}, {j}, {k}] has a non-finite {'xyz'[c]} ({float(p[i, j, k, c])!r}); "
                         f"{int(bad.any(-1).sum())} points are bad")
    big = np.abs(p) > FLOAT32_MAX
    if big.any():
        i, j, k, c = (int(v) for v in np.argwhere(big)[0])
        raise InputError(f"{shown}: lattice point [{i}, {j}, {k}] has {'xyz'[c]} = {p[i, j, k, c]:.6g}, beyond "
                         f"float32 (|v| <= {FLOAT32_MAX:.6g})")
    reach = MAX_LATTICE_EXTENT * float(np.max(box.size))
    centre = (box.lo + box.hi) / 2
    far = np.abs(p - centre) > reach
    if far.any():
        i, j, k, c = (int(v) for v in np.argwhere(far)[0])
        raise InputError(f"{shown}: lattice point [{i}, {j}, {k}] has {'xyz'[c]} = {p[i, j, k, c]:.6g}, more than "
                         f"{MAX_LATTICE_EXTENT:g} box sizes ({reach:.6g}) from the box's centre: too far to render "
                         f"in float32")
    return p


def read_lattice(path: str | os.PathLike, box: Box, shown: str | None = None) -> np.ndarray:
    """The lattice of a ``.npy`` file over ``box``: (nx+1, ny+1, nz+1, 3) float64.

    Args:
        path: the file.
        box: the grid's box (the extent bound is relative to it).
        shown: how errors name the file (default: ``path``).

    Raises:
        InputError: one line naming ``shown``: a missing or unreadable file, a directory,
            not a ``.npy`` array (an ``.npz`` archive, text, empty), a truncated file or one with
            bytes after its array, a dtype that is not real numbers (complex, bool, object,
            strings, records), a wrong shape, too many points, a non-finite value, a value beyond
            float32 or farther than :data:`MAX_LATTICE_EXTENT` box sizes.
    """
    shown = os.fspath(path) if shown is None else shown
    file = Path(path)
    if file.is_dir():
        raise InputError(f"cannot read {shown}: a directory, not a .npy file")
    try:
        with open(file, "rb") as stream:
            shape, dtype, start = _header(stream, shown)
            _check_header(shown, shape, dtype)
            size = int(np.prod(shape)) * dtype.itemsize
            held = os.fstat(stream.fileno()).st_size - start
            if held < size:
                raise InputError(f"{shown}: truncated: its header declares {shape} {dtype} ({size:,} bytes), "
                                 f"the file holds {held:,}")
            if held > size:
                raise InputError(f"{shown}: {held - size:,} bytes after its {shape} {dtype} array (not one .npy array)")
            stream.seek(0)
            data = np.load(stream, allow_pickle=False)
    except InputError:
        raise
    except FileNotFoundError:
        raise InputError(f"cannot read {shown}: file not found") from None
    except (OSError, ValueError, EOFError) as exc:
        text = getattr(exc, "strerror", None) or " ".join(str(exc).split()) or type(exc).__name__
        raise InputError(f"cannot read {shown}: {text}") from None
    return check_lattice(shown, data, box)
