"""GLSL source preprocessing: ``#include``, injected ``#define`` variants and correct line numbers.

Shader files live in the ``shaders/`` folder, which ships inside the wheel as the package
``deformgl.shaders`` and is read through :mod:`importlib.resources`, in an editable install and an
installed wheel alike (and from the checkout's folder where the checkout itself is imported:
:func:`deformgl.data.package_folder`).

Rules, as in moderngl-window's ``ShaderSource`` and three.js' chunks:

* ``#version`` must be the first line of the top-level file. Defines are injected right after it,
  followed by ``#line 2 0`` so that compiler messages point at the real line.
* ``#include "path/relative/to/shaders.glsl"`` is resolved recursively (depth cap
  :data:`MAX_INCLUDE_DEPTH`); each file is included once per program (include guard built in).
  Every included file gets its own GLSL source-string number; :func:`explain_log` maps compiler
  messages back to file names.
* A missing include is a :class:`~deformgl.errors.ShaderError` naming both files and the line.

Two profiles (:data:`PROFILES`) of the same files: ``core`` keeps their ``#version 330 core``;
``es`` emits ``#version 300 es`` (WebGL2, OpenGL ES 3.0) with explicit ``highp`` precision for
every type that needs one (:data:`ES_PRECISION`), before the defines. The sources are written in
the common subset (no implicit int-to-float conversions, ``flat`` integer varyings, explicit
locations), so nothing else changes; ``#line N S`` with source-string numbers is valid in both.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from deformgl.data import package_folder
from deformgl.errors import ShaderError

MAX_INCLUDE_DEPTH = 16
_INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"\s*$')
_VERSION = re.compile(r"^\s*#\s*version\s+\d+")

#: The shader-language profiles :func:`preprocess` emits.
PROFILES = ("core", "es")
#: The ES profile's precision statements (right after ``#version``; all of them ``highp``).
ES_PRECISION = tuple(f"precision highp {t};" for t in (
    "float", "int", "sampler2D", "sampler3D", "sampler2DArray", "isampler2D", "isampler2DArray",
    "usampler2D"))


def read_shader_file(name: str) -> str:
    """Return the text of ``shaders/<name>`` from the installed package.

    Args:
        name: path relative to the shaders folder, with forward slashes (``"sim/verlet.frag"``).

    Raises:
        ShaderError: the file does not exist in the package.
    """
    node = package_folder("shaders")
    for part in name.split("/"):
        node = node.joinpath(part)
    if not node.is_file():
        raise ShaderError(f"shaders/{name}: no such shader file in the deformgl package")
    return node.read_text(encoding="utf-8")


@dataclass
class Source:
    """A preprocessed shader: the GLSL text and the file behind each source-string number."""

    text: str
    files: list[str] = field(default_factory=list)

    def explain_log(self, log: str) -> str:
        """Rewrite ``N:LINE(COL)`` / ``N(LINE)`` prefixes of a compiler log into ``shaders/file:LINE``."""

        def repl(m: re.Match[str]) -> str:
            num = int(m.group(1))
            name = self.files[num] if 0 <= num < len(self.files) else f"<source {num}>"
            return f"shaders/{name}:{m.group(2)}"

        return re.sub(r"\b(\d+):(\d+)\(\d+\)", repl, log)


def format_defines(defines: dict[str, object]) -> list[str]:
    """Turn ``{"NAME": value}`` into ``#define`` lines; ``True`` gives a bare define, ``False``/``None`` none."""
    lines = []
    for key, value in sorted(defines.items()):
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", key):
            raise ShaderError(f"invalid #define name {key!r}")
        if value is False or value is None:
            continue
        lines.append(f"#define {key}" if value is True else f"#define {key} {value}")
    return lines


def preprocess(name: str, defines: dict[str, object] | None = None, profile: str = "core",
               chunks: dict[str, str] | None = None) -> Source:
    """Load ``shaders/<name>``, inject defines and resolve includes.

    Args:
        name: top-level shader file, relative to the shaders folder.
        defines: variant switches injected after ``#version``.
        profile: ``"core"`` (GLSL 3.30 core, as written) or ``"es"`` (GLSL ES 3.00, see the
            module docstring).
        chunks: shader files given as text, by name: ``name`` itself or an ``#include`` of one of
            these names takes its text instead of the package's file (the physics terms' chunks,
            :mod:`deformgl.sim.terms`, and the term list a pass composes of them; a study's own
            shader).

    Returns:
        The complete source and the file list for :meth:`Source.explain_log`.
    """
    text = chunks[name] if chunks and name in chunks else read_shader_file(name)
    lines = text.splitlines()
    if not lines or not _VERSION.match(lines[0]):
        raise ShaderError(f"shaders/{name}:1: #version must be the first line")
    if profile not in PROFILES:
        raise ShaderError(f"unknown shader profile {profile!r}; expected one of {', '.join(PROFILES)}")
    src = Source(text="", files=[name])
    head = [lines[0]] if profile == "core" else ["#version 300 es", *ES_PRECISION]
    out = [*head, *format_defines(defines or {}), "#line 2 0"]
    seen: set[str] = {name}
    _expand(lines[1:], name, 0, first_line=2, out=out, src=src, seen=seen, depth=0, chunks=chunks or {})
    src.text = "\n".join(out) + "\n"
    return src


def _expand(lines: list[str], name: str, number: int, *, first_line: int, out: list[str],
            src: Source, seen: set[str], depth: int, chunks: dict[str, str]) -> None:
    for offset, line in enumerate(lines):
        m = _INCLUDE.match(line)
        if not m:
            out.append(line)
            continue
        lineno = first_line + offset
        target = m.group(1)
        if depth >= MAX_INCLUDE_DEPTH:
            raise ShaderError(f"shaders/{name}:{lineno}: #include nesting deeper than {MAX_INCLUDE_DEPTH}")
        if target in seen:
            out.append(f"// {target} already included")
            continue
        try:
            child = chunks[target] if target in chunks else read_shader_file(target)
        except ShaderError:
            raise ShaderError(
                f'shaders/{name}:{lineno}: cannot resolve #include "{target}" '
                f"(no file shaders/{target})") from None
        seen.add(target)
        src.files.append(target)
        child_number = len(src.files) - 1
        out.append(f"#line 1 {child_number}")
        _expand(child.splitlines(), target, child_number, first_line=1, out=out, src=src,
                seen=seen, depth=depth + 1, chunks=chunks)
        out.append(f"#line {lineno + 1} {number}")
