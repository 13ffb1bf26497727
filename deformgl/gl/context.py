"""The headless OpenGL context: moderngl standalone on EGL, GL 3.3 core or newer.

The EGL device is chosen with ``device`` (CLI ``--device``) or the environment variable
``DEFORMGL_DEVICE``; without either, EGL's default display is used (Mesa llvmpipe when there is
no GPU).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import moderngl
import numpy as np

from deformgl.errors import GLError

DEVICE_ENV = "DEFORMGL_DEVICE"
REQUIRED_VERSION = 330
INSTALL_HINT = (
    "deformgl needs OpenGL 3.3 through EGL: install Mesa's EGL and its llvmpipe software renderer "
    "(Debian/Ubuntu: apt-get install libegl1 libgl1-mesa-dri; Fedora: dnf install mesa-libEGL "
    "mesa-dri-drivers; conda: conda install -c conda-forge mesalib) or a GPU driver with EGL")


def device_from_env(device: int | None = None) -> int | None:
    """Resolve the EGL device index from the argument or ``DEFORMGL_DEVICE``."""
    if device is not None:
        return device
    raw = os.environ.get(DEVICE_ENV, "").strip()
    if not raw:
        return None
    try:
        value = int(raw)
    except ValueError:
        raise GLError(f"{DEVICE_ENV}={raw!r}: must be a non-negative integer device index") from None
    if value < 0:
        raise GLError(f"{DEVICE_ENV}={raw!r}: must be a non-negative integer device index")
    return value


def create_context(device: int | None = None) -> moderngl.Context:
    """Create a standalone EGL context and check it is GL >= 3.3 core.

    Raises:
        GLError: EGL could not start, the device does not exist, or the GL version is too old;
            the message says what failed and what to install.
    """
    index = device_from_env(device)
    kwargs: dict[str, object] = {"backend": "egl", "require": REQUIRED_VERSION}
    if index is not None:
        kwargs["device_index"] = index
    try:
        # moderngl's stub annotates **settings as Dict[str, Any] per keyword, not the values' types
        ctx = moderngl.create_standalone_context(**kwargs)  # type: ignore[arg-type]
    except Exception as exc:  # glcontext raises plain Exception subclasses with its own text
        where = f"EGL device {index}" if index is not None else "the default EGL device"
        detail = " ".join(str(exc).split()) or type(exc).__name__
        raise GLError(f"could not create an OpenGL {REQUIRED_VERSION // 100}.{REQUIRED_VERSION % 100 // 10}"
                      f" context on {where}: {detail}. {INSTALL_HINT}") from None
    if ctx.version_code < REQUIRED_VERSION:
        version = ctx.info.get("GL_VERSION", "?")
        ctx.release()
        raise GLError(f"OpenGL {version} is older than 3.3 core. {INSTALL_HINT}")
    return ctx


@dataclass(frozen=True)
class ContextInfo:
    """What ``deformgl info`` prints."""

    renderer: str
    vendor: str
    version: str
    max_texture_size: int
    max_vertex_texture_units: int
    rgba32f_render_target: bool

    def lines(self) -> list[str]:
        """Human-readable ``key: value`` lines."""
        return [
            f"renderer: {self.renderer}",
            f"vendor: {self.vendor}",
            f"GL version: {self.version}",
            f"max texture size: {self.max_texture_size}",
            f"vertex texture units: {self.max_vertex_texture_units}",
            f"RGBA32F render targets: {'yes' if self.rgba32f_render_target else 'NO'}",
        ]


def rgba32f_renders(ctx: moderngl.Context) -> bool:
    """Whether an RGBA32F texture works as a render target and keeps full float32 values."""
    probe = np.array([1.0e-7, 3.14159274, -1.0e30, 16777215.0], dtype="f4")
    tex = ctx.texture((2, 2), 4, dtype="f4")
    fbo = ctx.framebuffer(color_attachments=[tex])
    try:
        fbo.use()
        fbo.clear(*probe.tolist())
        got = np.frombuffer(fbo.read(components=4, dtype="f4"), dtype="f4").reshape(-1, 4)
        return bool(np.array_equal(got, np.tile(probe, (4, 1))))
    except moderngl.Error:
        return False
    finally:
        fbo.release()
        tex.release()


def context_info(ctx: moderngl.Context) -> ContextInfo:
    """Query renderer, limits and capabilities of a context."""
    info = ctx.info
    return ContextInfo(
        renderer=str(info.get("GL_RENDERER", "?")),
        vendor=str(info.get("GL_VENDOR", "?")),
        version=str(info.get("GL_VERSION", "?")),
        max_texture_size=int(info.get("GL_MAX_TEXTURE_SIZE", 0)),
        max_vertex_texture_units=int(info.get("GL_MAX_VERTEX_TEXTURE_IMAGE_UNITS", 0)),
        rgba32f_render_target=rgba32f_renders(ctx),
    )
