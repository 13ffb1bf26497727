"""Atomic file output and PNG I/O: every file deformgl writes goes through :func:`write_atomic`.

A file is written to a temporary file in the target directory, flushed to disk, then renamed over
the target, so a reader never sees a partial file and a failed write leaves an existing file as
it was. A run's outputs are committed together (:class:`OutputSet`): while one is active, the
files it holds are written to temporary files and renamed only when all of them are complete;
on any failure none is renamed and every temporary file is removed.

Temporary files are named ``.NAME.deformgl-PID-HEX.tmp``: a run killed with SIGKILL leaves them
behind, recognisably; :func:`remove_stale_temporaries` (called by the next run in that folder)
removes those whose process is gone and that are older than the run that finds them.
"""

from __future__ import annotations

import contextvars
import hashlib
import os
import re
import secrets
import shutil
import threading
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import BinaryIO

import numpy as np
from PIL import Image

from deformgl.errors import InputError

__all__ = ["OutputSet", "STOP", "adopt_file", "check_writable", "committing", "read_png", "remove_stale_temporaries",
           "request_stop", "temporary_path", "write_atomic", "write_png_atomic"]

#: ``.NAME.deformgl-PID-HEX.tmp``; the older ``.NAME.HEX.tmp`` (no process id) is recognised too
_TEMPORARY = re.compile(r"^\..+\.deformgl-(\d+)-[0-9a-f]{12}\.tmp$")
_OLD_TEMPORARY = re.compile(r"^\..+\.[0-9a-f]{12}\.tmp$")
_ACTIVE: contextvars.ContextVar[OutputSet | None] = contextvars.ContextVar("deformgl_output_set", default=None)


#: Set by the CLI's SIGINT / SIGTERM handlers (with the exception to raise): a library that swallows
#: the signal's exception (trimesh catches BaseException around some imports) cannot make a stopped
#: run commit its outputs: :meth:`OutputSet.commit` raises it instead.
STOP: list[BaseException] = []
_STOP_LOCK = threading.Lock()
_COMMITTING = threading.Event()


def committing() -> bool:
    """Whether an :class:`OutputSet` is renaming its files now (a signal then waits for the end)."""
    return _COMMITTING.is_set()


def request_stop(exc: BaseException) -> None:
    """Record that the run was asked to stop (a signal); the next commit raises ``exc``."""
    with _STOP_LOCK:
        if not STOP:
            STOP.append(exc)


def temporary_path(target: Path) -> Path:
    """A fresh temporary name next to ``target``: ``.NAME.deformgl-PID-HEX.tmp`` (a long NAME is
    shortened to a prefix and a hash, so the temporary name fits where the target's does)."""
    name = target.name
    if len(name.encode()) > 150:
        name = name[:100] + "~" + hashlib.sha256(name.encode()).hexdigest()[:12]
    return target.parent / f".{name}.deformgl-{os.getpid()}-{secrets.token_hex(6)}.tmp"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def remove_stale_temporaries(folder: str | os.PathLike[str], before: float) -> list[Path]:
    """Remove the temporary files deformgl left in ``folder`` (a killed run): those named as
    :func:`temporary_path` names them whose process is gone (files, and the scratch folders of
    time series, :mod:`deformgl.scene.interchange`), and older files without a process id, in
    both cases last modified before ``before`` (a time.time(): the finding run's start).
    Returns what was removed; a folder that cannot be listed removes nothing."""
    removed: list[Path] = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for entry in entries:
        m = _TEMPORARY.match(entry.name)
        if m is None and not _OLD_TEMPORARY.match(entry.name):
            continue
        try:
            # a folder: the scratch folder of a time series (deformgl.scene.interchange), named alike
            folder_entry = m is not None and entry.is_dir(follow_symlinks=False)
            if not (entry.is_file(follow_symlinks=False) or folder_entry) \
                    or entry.stat(follow_symlinks=False).st_mtime >= before:
                continue
            if m is not None and (int(m.group(1)) == os.getpid() or _alive(int(m.group(1)))):
                continue
            if folder_entry:
                shutil.rmtree(entry.path)
            else:
                os.unlink(entry.path)
            removed.append(Path(entry.path))
        except OSError:
            continue
    return removed


def check_folder(path: str | os.PathLike[str], what: str = "output") -> None:
    """Whether the folder of ``path`` exists (and is a folder, not a file).

    Raises:
        InputError: one line naming the path and what is wrong.
    """
    target = Path(path)
    directory = target.parent if str(target.parent) else Path(".")
    try:
        if directory.is_dir():
            return
        blocking = next((d for d in (directory, *directory.parents) if d.exists()), None)
        if blocking is not None and not blocking.is_dir():
            raise InputError(f"{target}: {blocking} is a file, not a folder: the {what} cannot be written inside it")
    except OSError as exc:  # (ENAMETOOLONG, ELOOP, EACCES on a parent)
        raise InputError(f"{target}: cannot use this {what} path: {exc.strerror or exc}") from None
    raise InputError(f"{target}: the {what} folder {directory} does not exist")


def check_writable(path: str | os.PathLike[str], what: str = "output") -> None:
    """Whether a file can be written at ``path`` (before any work): its folder exists and takes a
    new file (probed with a temporary file, so read-only mounts and /proc are found), and the path
    is not a folder.

    Raises:
        InputError: one line naming the path and what is wrong.
    """
    target = Path(path)
    directory = target.parent if str(target.parent) else Path(".")
    try:
        if target.is_dir():
            raise InputError(f"{target}: the {what} is a folder, not a file")
        check_folder(target, what)
        if target.exists() and not target.is_file():
            raise InputError(f"{target}: the {what} exists and is not a regular file")
    except OSError as exc:  # (ENAMETOOLONG, ELOOP, EACCES on a parent)
        raise InputError(f"{target}: cannot use this {what} path: {exc.strerror or exc}") from None
    probe = temporary_path(target)
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
    except OSError as exc:
        raise InputError(f"{target}: cannot write the {what} into {directory}: no file can be created there "
                         f"({exc.strerror or exc}); choose a folder you can write to") from None
    os.close(fd)
    os.unlink(probe)


class OutputSet:
    """A run's output files, committed together: all of them or none.

    ``with OutputSet([png, mesh]):`` checks every path first (:func:`check_writable`), then every
    :func:`write_atomic` to one of them inside the block writes a complete temporary file but
    does not rename it. Leaving the block normally renames them all (a file that was there is
    moved aside first and put back if a later rename fails); leaving it by an exception (a
    failed write, a full disk, SIGTERM turned into an exception, Ctrl-C) removes every temporary
    file and leaves the folder as it was.

    Args:
        paths: the outputs (None entries are ignored).
        what: how the messages name them ("output").
    """

    def __init__(self, paths: Iterable[str | os.PathLike[str] | None], what: str = "output") -> None:
        self.paths = [Path(p) for p in paths if p is not None]
        self.what = what
        self._staged: dict[Path, Path] = {}
        self._token: contextvars.Token[OutputSet | None] | None = None
        for path in self.paths:
            check_writable(path, what)

    def holds(self, path: Path) -> bool:
        """Whether ``path`` is one of the set's outputs."""
        key = os.path.abspath(path)
        return any(os.path.abspath(p) == key for p in self.paths)

    def stage(self, target: Path, temporary: Path) -> None:
        """Keep a complete temporary file until :meth:`commit` (``write_atomic`` calls this)."""
        previous = self._staged.pop(target, None)
        if previous is not None:
            _unlink(previous)
        self._staged[target] = temporary

    def commit(self) -> None:
        """Rename every staged file over its target; on a failure undo the renames done.

        A target that exists is first hard-linked to a backup name (it never goes missing, and the
        rename over it stays atomic). A stop requested before (:data:`STOP`) commits nothing; one
        that arrives while the renames run is deferred (:func:`committing` tells the CLI's signal
        handler), so a signal cannot split the set."""
        if STOP:
            self.discard()
            raise STOP[0]
        _COMMITTING.set()
        done: list[tuple[Path, Path | None]] = []
        backup: Path | None = None
        try:
            for target, temporary in list(self._staged.items()):
                backup = None
                if target.exists():
                    backup = temporary_path(target)
                    try:
                        os.link(target, backup)
                    except OSError:  # a file system without hard links: copy the old bytes
                        backup.write_bytes(target.read_bytes())
                os.replace(temporary, target)
                del self._staged[target]
                done.append((target, backup))
                backup = None
        except BaseException:
            if backup is not None:  # the target that failed was not replaced: drop its backup
                _unlink(backup)
            for target, old in reversed(done):  # each undone on its own: one failure stops none
                try:
                    if old is not None:
                        os.replace(old, target)
                    else:
                        _unlink(target)
                except OSError:
                    pass
            self.discard()
            raise
        finally:
            _COMMITTING.clear()
        for _, backup in done:
            if backup is not None:
                _unlink(backup)

    def discard(self) -> None:
        """Remove every staged temporary file (the targets stay as they were)."""
        for temporary in self._staged.values():
            _unlink(temporary)
        self._staged.clear()

    def __enter__(self) -> OutputSet:
        self._token = _ACTIVE.set(self)
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if self._token is not None:
            _ACTIVE.reset(self._token)
            self._token = None
        if exc_type is None:
            self.commit()
        else:
            self.discard()


def _unlink(path: Path) -> None:
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass


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
    disk and renamed over ``path`` (inside an :class:`OutputSet` holding ``path``: when the set
    commits). On any failure the temporary file is removed and an existing ``path`` is left as
    it was. The new file gets the usual permissions for a new file (``0o666`` less the umask).

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
        temporary = temporary_path(target)
        try:
            fd = os.open(temporary, flags, 0o666)
            break
        except FileExistsError:
            continue
    else:
        raise FileExistsError(f"cannot create a temporary file next to {target}")

    def fill() -> None:
        with os.fdopen(fd, "wb") as stream:
            write(stream)
            stream.flush()
            os.fsync(stream.fileno())

    _place(target, temporary, fill)


def _place(target: Path, temporary: Path, complete: Callable[[], object]) -> None:
    """``complete()`` the temporary file, then stage it (inside an :class:`OutputSet` holding
    ``target``) or rename it over ``target``; on any failure remove it."""
    active = _ACTIVE.get()
    try:
        complete()
        if active is not None and active.holds(target):
            active.stage(target, temporary)
            return
        os.replace(temporary, target)
    except BaseException:
        try:
            os.unlink(temporary)
        except FileNotFoundError:
            pass
        raise


def adopt_file(path: str | os.PathLike[str], written: str | os.PathLike[str]) -> None:
    """Make ``written``, a complete file that a library wrote in the folder of ``path`` (or in a
    folder inside it: one file system, so the move is a rename), the output ``path`` as
    :func:`write_atomic` makes its temporary file: flushed to disk, then staged (inside an
    :class:`OutputSet` holding ``path``) or renamed over ``path`` now. On a failure nothing is
    left at ``path``'s temporary name."""
    target = Path(path)
    source = Path(written)
    if os.path.realpath(target.parent) not in (os.path.realpath(source.parent), os.path.realpath(source.parent.parent)):
        raise ValueError(f"adopt_file: {written} is not in (a folder in) the folder of {target}")
    temporary = temporary_path(target)

    def move_and_flush() -> None:
        os.replace(written, temporary)
        fd = os.open(temporary, os.O_RDONLY | getattr(os, "O_BINARY", 0))
        try:
            os.fsync(fd)
        finally:
            os.close(fd)

    _place(target, temporary, move_and_flush)


def read_png(path: str | os.PathLike[str], max_pixels: int | None = None) -> np.ndarray:
    """Reads an image file into a uint8 RGB or RGBA array, refusing a too large one from its
    header, before any pixel is decoded.

    Images with an alpha channel or palette transparency become (H, W, 4); all others,
    greyscale and palette images included, become (H, W, 3). 16-bit images are reduced to
    8 bits by Pillow's conversion.

    Args:
        path: The file to read.
        max_pixels: Most pixels (width x height) accepted; None: the environment variable
            ``DEFORMGL_MAX_IMAGE_PIXELS``, default 8192 x 8192 (the same default as
            :data:`deformgl.inputs.DEFAULT_MAX_IMAGE_PIXELS`; docs/INPUTS.md). Pillow's own
            guard refuses more than 2 x ``PIL.Image.MAX_IMAGE_PIXELS`` whatever this is.

    Returns:
        A uint8 array of shape (H, W, 3) or (H, W, 4).

    Raises:
        FileNotFoundError: ``path`` does not exist.
        PIL.UnidentifiedImageError: ``path`` is not an image Pillow can read.
        InputError: The image has more pixels than the limit, its data is corrupt or truncated,
            or ``DEFORMGL_MAX_IMAGE_PIXELS`` is not a positive integer; the one-line message
            starts with ``path``.
    """
    import warnings
    import zlib

    name = os.fspath(path)
    if max_pixels is None:
        setting = os.environ.get("DEFORMGL_MAX_IMAGE_PIXELS", "").strip().replace("_", "")
        max_pixels = int(setting) if setting.isdigit() else (8192 * 8192 if not setting else 0)
        if max_pixels <= 0:
            raise InputError(f"{name}: environment variable DEFORMGL_MAX_IMAGE_PIXELS must be a "
                          f"positive integer, got {os.environ['DEFORMGL_MAX_IMAGE_PIXELS']!r}")
    refusal = (f"over the limit of {max_pixels:,} pixels "
               f"(set DEFORMGL_MAX_IMAGE_PIXELS to raise it)")
    with warnings.catch_warnings():
        # Pillow warns between its guard and twice it; the limit below is the one that counts.
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)
        try:
            opened = Image.open(path)
        except Image.DecompressionBombError as exc:
            text = " ".join(str(exc).split()).rstrip(".")
            raise InputError(f"{name}: image too large for Pillow's decompression-bomb guard ({text})") from None
    with opened as image:
        width, height = image.size
        if width * height > max_pixels:
            raise InputError(f"{name}: image is {width:,} x {height:,} = {width * height:,} pixels, "
                          f"{refusal}")
        try:
            image.load()
        except (OSError, SyntaxError, ValueError, EOFError, zlib.error) as exc:
            text = " ".join(str(exc).split()) or type(exc).__name__
            raise InputError(f"{name}: corrupt or truncated image data ({text})") from None
        converted: Image.Image
        if image.mode in ("RGB", "RGBA"):
            converted = image
        elif "A" in image.getbands() or "transparency" in image.info:
            converted = image.convert("RGBA")
        else:
            converted = image.convert("RGB")
        return np.array(converted, dtype=np.uint8)
