"""Animation files: MP4 (imageio-ffmpeg, the ``video`` extra), GIF and WebP (Pillow), PNG frame
sequences (``frames/%04d.png``), each written atomically.

``with AnimationWriter("out.gif", fps=24) as w: w.write_frame(image)`` (the calls of PyVista's
``open_gif`` / ``write_frame``): frames are uint8 (H, W, 3) arrays of one size. Nothing appears at
the output path until :meth:`AnimationWriter.close` has the whole file; an exception inside the
``with`` block (or :meth:`AnimationWriter.abort`) leaves no file. MP4 frames stream to a temporary
file next to the output as they come (H.264, yuv420p: an odd width or height is padded by one
pixel of the last column or row); GIF, WebP and PNG frames are kept in memory until the close.
Inside an active :class:`~deformgl.files.OutputSet` holding the path, the file is renamed when
the set commits.
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from deformgl.errors import DeformglError, InputError
from deformgl.files import temporary_path, write_atomic, write_png_atomic

__all__ = ["ANIMATION_FORMATS", "AnimationWriter", "animation_kind", "frame_paths"]

#: What an animation output can be: a file suffix, or ``"frames"`` for a %d pattern of PNGs.
ANIMATION_FORMATS = (".mp4", ".gif", ".webp", "frames")
_PATTERN = re.compile(r"%0?\d*d")


def animation_kind(path: str | os.PathLike[str]) -> str | None:
    """``".mp4"``, ``".gif"``, ``".webp"``, ``"frames"`` (a .png name with one ``%d``/``%04d``
    pattern) or None (a plain still image or anything else)."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix == ".png":
        found = _PATTERN.findall(p.name)
        if len(found) == 1 and "%" not in str(p.parent):
            return "frames"
        return None
    return suffix if suffix in (".mp4", ".gif", ".webp") else None


def frame_paths(pattern: str | os.PathLike[str], count: int) -> list[Path]:
    """The ``count`` file names of a frame pattern, ``frames/%04d.png`` -> frames/0000.png ..."""
    p = Path(pattern)
    return [p.parent / (p.name % k) for k in range(count)]


def check_encoder(path: str | os.PathLike[str]) -> None:
    """An MP4 needs imageio-ffmpeg (the ``video`` extra): a one-line InputError without it, before
    any work."""
    if animation_kind(path) == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            raise InputError(f"{path}: writing MP4 needs imageio-ffmpeg (the 'video' extra: "
                             f"pip install 'deformgl[video]'); .gif, .webp and frames/%04d.png need "
                             f"nothing more") from None


class AnimationWriter:
    """Write an animation frame by frame, atomically (see the module docstring).

    Args:
        path: ``.mp4``, ``.gif``, ``.webp`` or a frame pattern ``DIR/%04d.png``.
        fps: frames per second (> 0).
        quality: MP4 quality 0..10 (imageio-ffmpeg's scale); WebP 0..100 is ``quality * 10``.
    """

    def __init__(self, path: str | os.PathLike[str], fps: float = 24.0, *, quality: float = 7.0) -> None:
        self.path = Path(path)
        kind = animation_kind(self.path)
        if kind is None:
            raise InputError(f"{self.path}: an animation must end in .mp4, .gif or .webp, or be a frame "
                             f"pattern such as frames/%04d.png")
        if not fps > 0:
            raise InputError(f"{self.path}: fps must be > 0, got {fps}")
        check_encoder(self.path)
        self.kind, self.fps, self.quality = kind, float(fps), quality
        self.frames: list[np.ndarray] = []
        self.count = 0
        self.size: tuple[int, int] | None = None  # (width, height)
        self._encoder: Any = None
        self._temporary: Path | None = None
        self._closed = False

    def write_frame(self, image: np.ndarray) -> None:
        """Append one uint8 (H, W, 3) frame (all frames the same size)."""
        image = np.asarray(image)
        if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
            raise ValueError(f"a frame must be a uint8 (H, W, 3) array, got {image.dtype} {image.shape}")
        size = (image.shape[1], image.shape[0])
        if self.size is None:
            self.size = size
        elif size != self.size:
            raise ValueError(f"frame {self.count} is {size[0]}x{size[1]}, the first was {self.size[0]}x{self.size[1]}")
        if self._closed:
            raise ValueError("the animation writer is closed")
        if self.kind == ".mp4":
            self._mp4_frame(image)
        else:
            self.frames.append(image)
        self.count += 1

    def _mp4_frame(self, image: np.ndarray) -> None:
        h, w = image.shape[:2]
        if w % 2 or h % 2:  # yuv420p needs even sides
            image = np.pad(image, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
        if self._encoder is None:
            import imageio_ffmpeg

            self._temporary = temporary_path(self.path)
            self._encoder = imageio_ffmpeg.write_frames(
                str(self._temporary), (image.shape[1], image.shape[0]), fps=self.fps, codec="libx264",
                pix_fmt_out="yuv420p", quality=self.quality, macro_block_size=1, output_params=["-f", "mp4"],
                ffmpeg_log_level="error")
            self._encoder.send(None)
        self._encoder.send(np.ascontiguousarray(image))

    def close(self) -> None:
        """Finish the file and put it at the path (or stage it in the active output set)."""
        if self._closed:
            return
        if self.count == 0:
            self.abort()
            raise DeformglError(f"{self.path}: no frames were written")
        try:
            if self.kind == ".mp4":
                assert self._encoder is not None and self._temporary is not None
                self._encoder.close()
                self._encoder = None
                temporary = self._temporary
                with open(temporary, "rb") as source:
                    write_atomic(self.path, lambda stream: shutil.copyfileobj(source, stream))
            elif self.kind == "frames":
                for path, image in zip(frame_paths(self.path, self.count), self.frames):
                    write_png_atomic(path, image)
            else:
                from PIL import Image

                images = [Image.fromarray(f) for f in self.frames]
                duration = 1000.0 / self.fps
                save: dict[str, Any]
                if self.kind == ".gif":
                    # one palette per frame (Pillow's adaptive quantiser); loop forever
                    save = dict(format="GIF", save_all=True, append_images=images[1:], duration=round(duration),
                                loop=0, optimize=False, disposal=1)
                else:
                    save = dict(format="WEBP", save_all=True, append_images=images[1:], duration=round(duration),
                                loop=0, quality=int(self.quality * 10), method=4)
                write_atomic(self.path, lambda stream: images[0].save(stream, **save))
        except BaseException:
            self.abort()
            raise
        self._discard()
        self._closed = True

    def abort(self) -> None:
        """Drop everything written; no file appears at the path."""
        if self._encoder is not None:
            try:
                self._encoder.close()
            except Exception:
                pass
            self._encoder = None
        self._discard()
        self._closed = True

    def _discard(self) -> None:
        self.frames = []
        if self._temporary is not None:
            try:
                os.unlink(self._temporary)
            except FileNotFoundError:
                pass
            self._temporary = None

    def __enter__(self) -> AnimationWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
