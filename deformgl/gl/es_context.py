"""An OpenGL ES 3 context on EGL, wrapped by moderngl: the ES profile's test bed.

moderngl 5 and glcontext create desktop contexts only (glcontext's EGL backend binds
``EGL_OPENGL_API``, and has no "detect" mode for a context made elsewhere). Here EGL is driven
through ctypes: Mesa's surfaceless platform (``EGL_MESA_platform_surfaceless``), a config with
``EGL_OPENGL_ES3_BIT``, ``eglBindAPI(EGL_OPENGL_ES_API)``, a 3.x context made current without a
surface; then ``moderngl.init_context`` takes it with a loader that resolves every GL function
through ``eglGetProcAddress``. On llvmpipe that is "OpenGL ES 3.2 Mesa ...".

The context becomes the thread's current one: use it in a process of its own (the tests run it
in a subprocess), not next to a desktop moderngl context.
"""

from __future__ import annotations

import ctypes
from typing import Any

import moderngl

from deformgl.errors import GLError

__all__ = ["create_es_context", "is_es"]

_EGL_PLATFORM_SURFACELESS_MESA = 0x31DD
_EGL_RENDERABLE_TYPE, _EGL_OPENGL_ES3_BIT, _EGL_SURFACE_TYPE, _EGL_NONE = 0x3040, 0x0040, 0x3033, 0x3038
_EGL_OPENGL_ES_API = 0x30A0
_EGL_CONTEXT_MAJOR_VERSION, _EGL_CONTEXT_MINOR_VERSION = 0x3098, 0x30FB


def is_es(ctx: moderngl.Context) -> bool:
    """Whether ``ctx`` is an OpenGL ES context (its version string says "OpenGL ES")."""
    return str(ctx.info.get("GL_VERSION", "")).startswith("OpenGL ES")


class _Loader:
    def __init__(self, egl: Any, display: int, context: int) -> None:
        self.egl, self.display, self.context = egl, display, context

    def load_opengl_function(self, name: str) -> int:
        return int(self.egl.eglGetProcAddress(name.encode()) or 0)

    def release(self) -> None:
        if self.context:
            self.egl.eglMakeCurrent(self.display, None, None, None)
            self.egl.eglDestroyContext(self.display, self.context)
            self.context = 0


def create_es_context(minor: int = 0) -> moderngl.Context:
    """An OpenGL ES 3.``minor`` context (3.0 asks for the WebGL2 level; Mesa may give more).

    Raises:
        GLError: libEGL, the surfaceless platform or an ES 3 config is missing.
    """
    try:
        egl = ctypes.CDLL("libEGL.so.1")
    except OSError as exc:
        raise GLError(f"no libEGL.so.1 for an OpenGL ES context: {exc}") from None
    vp, ip = ctypes.c_void_p, ctypes.POINTER(ctypes.c_int)
    egl.eglGetProcAddress.restype, egl.eglGetProcAddress.argtypes = vp, [ctypes.c_char_p]
    egl.eglInitialize.argtypes = [vp, ip, ip]
    egl.eglChooseConfig.argtypes = [vp, ip, ctypes.POINTER(vp), ctypes.c_int, ip]
    egl.eglCreateContext.restype, egl.eglCreateContext.argtypes = vp, [vp, vp, vp, ip]
    egl.eglMakeCurrent.argtypes = [vp, vp, vp, vp]
    egl.eglDestroyContext.argtypes = [vp, vp]
    address = egl.eglGetProcAddress(b"eglGetPlatformDisplayEXT")
    if not address:
        raise GLError("EGL has no eglGetPlatformDisplayEXT: cannot open the surfaceless platform")
    get_display = ctypes.CFUNCTYPE(vp, ctypes.c_int, vp, vp)(address)
    display = get_display(_EGL_PLATFORM_SURFACELESS_MESA, None, None)
    major, minor_out = ctypes.c_int(), ctypes.c_int()
    if not display or not egl.eglInitialize(display, ctypes.byref(major), ctypes.byref(minor_out)):
        raise GLError("could not initialise EGL's surfaceless platform (EGL_MESA_platform_surfaceless)")
    attrs = (ctypes.c_int * 5)(_EGL_RENDERABLE_TYPE, _EGL_OPENGL_ES3_BIT, _EGL_SURFACE_TYPE, 0, _EGL_NONE)
    config, count = ctypes.c_void_p(), ctypes.c_int()
    if not egl.eglChooseConfig(display, attrs, ctypes.byref(config), 1, ctypes.byref(count)) or count.value < 1:
        raise GLError("EGL offers no OpenGL ES 3 config")
    if not egl.eglBindAPI(_EGL_OPENGL_ES_API):
        raise GLError("eglBindAPI(EGL_OPENGL_ES_API) failed")
    cattrs = (ctypes.c_int * 5)(_EGL_CONTEXT_MAJOR_VERSION, 3, _EGL_CONTEXT_MINOR_VERSION, minor, _EGL_NONE)
    context = egl.eglCreateContext(display, config, None, cattrs)
    if not context or not egl.eglMakeCurrent(display, None, None, context):
        raise GLError(f"could not create and make current an OpenGL ES 3.{minor} context")
    moderngl.init_context(_Loader(egl, display, context))
    ctx = moderngl.get_context()
    if not is_es(ctx):
        raise GLError(f"asked for OpenGL ES, got {ctx.info.get('GL_VERSION')}")
    _ = ctx.error  # moderngl's set-up enables a desktop-only switch (GL_INVALID_ENUM): cleared here
    return ctx


_GL_ANY_SAMPLES_PASSED, _GL_QUERY_RESULT = 0x8C2F, 0x8866


class AnySamplesQuery:
    """The ES equivalent of ``ctx.query(samples=True)``: OpenGL ES has no ``GL_SAMPLES_PASSED``,
    only ``GL_ANY_SAMPLES_PASSED`` (moderngl creates one but cannot read it back), so this
    drives the query object through the GL entry points directly. :attr:`samples` is 1 when
    any sample passed, else 0: enough for "no node moved" and "no node went bad"."""

    def __init__(self) -> None:
        egl = ctypes.CDLL("libEGL.so.1")
        egl.eglGetProcAddress.restype, egl.eglGetProcAddress.argtypes = ctypes.c_void_p, [ctypes.c_char_p]
        uint_p = ctypes.POINTER(ctypes.c_uint)

        def fn(name: str, *args: Any) -> Any:
            address = egl.eglGetProcAddress(name.encode())
            if not address:
                raise GLError(f"no {name} in this OpenGL ES context")
            return ctypes.CFUNCTYPE(None, *args)(address)

        self._gen = fn("glGenQueries", ctypes.c_int, uint_p)
        self._delete = fn("glDeleteQueries", ctypes.c_int, uint_p)
        self._begin = fn("glBeginQuery", ctypes.c_uint, ctypes.c_uint)
        self._end = fn("glEndQuery", ctypes.c_uint)
        self._result = fn("glGetQueryObjectuiv", ctypes.c_uint, ctypes.c_uint, uint_p)
        self._id = ctypes.c_uint(0)
        self._gen(1, ctypes.byref(self._id))

    def __enter__(self) -> AnySamplesQuery:
        self._begin(_GL_ANY_SAMPLES_PASSED, self._id.value)
        return self

    def __exit__(self, *exc: object) -> None:
        self._end(_GL_ANY_SAMPLES_PASSED)

    @property
    def samples(self) -> int:
        """1 if any sample passed during the last ``with`` block, else 0 (waits for the GPU)."""
        value = ctypes.c_uint(0)
        self._result(self._id.value, _GL_QUERY_RESULT, ctypes.byref(value))
        return int(value.value != 0)

    def release(self) -> None:
        if self._id.value:
            self._delete(1, ctypes.byref(self._id))
            self._id = ctypes.c_uint(0)


def read_texture(tex: moderngl.Texture) -> bytes:
    """``tex.read()`` (level 0, tightly packed) on any context: OpenGL ES has no
    ``glGetTexImage``, so there the texture is attached to a framebuffer of its own and read
    with ``glReadPixels`` (RGBA; float textures need ``EXT_color_buffer_float``, which ES 3.2
    and WebGL2 with that extension offer). The bound framebuffer is restored."""
    ctx = tex.ctx
    if not is_es(ctx):
        return tex.read()
    previous = ctx.fbo
    fbo = ctx.framebuffer(color_attachments=[tex])
    try:
        data = fbo.read(components=4, dtype=tex.dtype, alignment=1)
    finally:
        fbo.release()
        if previous is not None:
            previous.use()
    if tex.components == 4:
        return data
    import numpy as np

    size = int(tex.dtype[1:])
    pixels = np.frombuffer(data, dtype=np.uint8).reshape(tex.height, tex.width, 4, size)
    return pixels[:, :, :tex.components].tobytes()
