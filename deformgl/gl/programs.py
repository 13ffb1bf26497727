"""Compiled GL programs that fail loudly: compile errors name files, unknown uniforms are errors."""

from __future__ import annotations

from typing import Any

import moderngl

from deformgl.errors import ShaderError
from deformgl.gl.preprocessor import Source, preprocess

#: The fragment stage an OpenGL ES program without one gets (ES links no program without a
#: fragment shader; transform-feedback passes discard the rasterizer anyway).
ES_EMPTY_FRAGMENT = "lib/empty.frag"


def profile_of(ctx: moderngl.Context) -> str:
    """The shader profile of a context: "es" for OpenGL ES, else "core"."""
    return "es" if str(ctx.info.get("GL_VERSION", "")).startswith("OpenGL ES") else "core"


class Program:
    """A moderngl program built from shader files, owning its GL object.

    Setting a uniform the program does not have (misspelt, or optimised away because unused) is a
    :class:`ShaderError` naming the program and the uniform: no silent ``except: pass``.

    Args:
        ctx: the GL context.
        vertex: vertex shader file, relative to ``shaders/``.
        fragment: fragment shader file, or ``None`` (transform feedback).
        defines: variant switches for both stages.
        varyings: transform-feedback outputs, in buffer order.
        chunks: include files given as text (:func:`~deformgl.gl.preprocessor.preprocess`).

    On an OpenGL ES context the sources are preprocessed in the ``es`` profile, and a program
    without a fragment shader gets :data:`ES_EMPTY_FRAGMENT`.
    """

    def __init__(self, ctx: moderngl.Context, vertex: str, fragment: str | None = None, *,
                 defines: dict[str, object] | None = None, varyings: tuple[str, ...] = (),
                 chunks: dict[str, str] | None = None) -> None:
        self.name = f"{vertex}+{fragment}" if fragment else vertex
        self.defines = dict(defines or {})
        self.profile = profile_of(ctx)
        if fragment is None and self.profile == "es":
            fragment = ES_EMPTY_FRAGMENT
        self.vertex_source = preprocess(vertex, self.defines, self.profile, chunks)
        self.fragment_source = preprocess(fragment, self.defines, self.profile, chunks) if fragment else None
        try:
            self.gl = ctx.program(
                vertex_shader=self.vertex_source.text,
                fragment_shader=self.fragment_source.text if self.fragment_source else None,
                varyings=tuple(varyings))
        except moderngl.Error as exc:
            raise ShaderError(f"program {self.name} failed to build:\n{self._explain(str(exc))}") from None

    def _explain(self, log: str) -> str:
        if "fragment_shader" in log and self.fragment_source is not None:
            return self.fragment_source.explain_log(log)
        return self.vertex_source.explain_log(log)

    @property
    def members(self) -> frozenset[str]:
        """Names of the program's active uniforms, uniform blocks and attributes."""
        return frozenset(self.gl)

    def set(self, **uniforms: Any) -> None:
        """Set uniforms by name; an unknown name raises :class:`ShaderError`."""
        for key, value in uniforms.items():
            try:
                member = self.gl[key]
            except KeyError:
                raise ShaderError(f"program {self.name} has no active uniform {key!r}") from None
            if not isinstance(member, (moderngl.Uniform, moderngl.UniformBlock, moderngl.StorageBlock)):
                raise ShaderError(f"program {self.name}: {key!r} is a {type(member).__name__}, not a uniform")
            member.value = value

    def release(self) -> None:
        """Release the GL program."""
        self.gl.release()
