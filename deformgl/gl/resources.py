"""One way to own GL objects: :class:`GLOwner`, the base of every class that holds them.

A subclass registers each GL object (a moderngl texture, buffer, framebuffer, vertex array,
query, program, or another :class:`GLOwner` / :class:`~deformgl.gl.programs.Program`) with
:meth:`GLOwner.own` as it makes it, and builds inside ``with self.building():``; if the
constructor fails half-way, everything made so far is released before the exception leaves.
:meth:`GLOwner.release` releases in reverse order of creation, once: a second call does
nothing. ``with`` releases on exit::

    class Pass(GLOwner):
        def __init__(self, ctx):
            super().__init__(ctx)
            with self.building():
                self.texture = self.own(ctx.texture((4, 4), 4, dtype="f4"))
                self.fbo = self.own(ctx.framebuffer([self.texture]))

    with Pass(ctx) as p:
        ...

:func:`restore_framebuffer` binds back the framebuffer that was bound before a pass, or the
context's default one when that framebuffer has been released meanwhile.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Protocol, TypeVar

import moderngl


class Releasable(Protocol):
    """Anything with a ``release()``: moderngl objects, programs, owners."""

    def release(self) -> None: ...


R = TypeVar("R", bound=Releasable)
O = TypeVar("O", bound="GLOwner")


class GLOwner:
    """Base of every class holding GL objects: a registry of owned objects, roll-back when a
    constructor fails half-way, an idempotent :meth:`release` and context-manager support.

    Args:
        ctx: the GL context the objects belong to (kept as ``self.ctx``).
    """

    def __init__(self, ctx: moderngl.Context) -> None:
        self.ctx = ctx
        self._owned: list[Releasable] = []
        self._released = False

    def own(self, obj: R) -> R:
        """Register ``obj`` to be released with this owner; returns it."""
        if self._released:
            raise RuntimeError(f"{type(self).__name__} is released: it cannot own new GL objects")
        self._owned.append(obj)
        return obj

    def disown(self, obj: Releasable) -> None:
        """Release ``obj`` now and forget it (for objects replaced during the owner's life)."""
        self._owned = [o for o in self._owned if o is not obj]
        obj.release()

    @contextmanager
    def building(self) -> Iterator[None]:
        """Wrap a constructor: on any exception, release what was made, then re-raise."""
        try:
            yield
        except BaseException:
            self.release()
            raise

    @property
    def released(self) -> bool:
        """Whether :meth:`release` has run."""
        return self._released

    @property
    def owned_count(self) -> int:
        """How many GL objects this owner holds (0 after :meth:`release`)."""
        return len(self._owned)

    def release(self) -> None:
        """Release every owned object, newest first; calling it again does nothing."""
        if self._released:
            return
        self._released = True
        owned, self._owned = self._owned, []
        errors: list[BaseException] = []
        for obj in reversed(owned):
            try:
                obj.release()
            except Exception as exc:  # release the rest, then report the first failure
                errors.append(exc)
        if errors:
            raise errors[0]

    def __enter__(self: O) -> O:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def is_released(obj: object) -> bool:
    """Whether a moderngl object has been released (its GL handle is gone)."""
    return type(getattr(obj, "mglo", None)).__name__ == "InvalidObject"


def restore_framebuffer(ctx: moderngl.Context, previous: moderngl.Framebuffer | None) -> None:
    """Bind ``previous`` again, or framebuffer 0 when ``previous`` is None or has been released
    since (a standalone context then has none that draws: bind one before the next draw)."""
    if previous is not None and not is_released(previous):
        previous.use()
    else:
        ctx.detect_framebuffer(0).use()
