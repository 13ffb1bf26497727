"""Reading a scene file's TOML (size, encoding, nesting, syntax) with nothing but the standard
library, so that the CLI reports a syntax error before it imports NumPy, moderngl or trimesh
(:func:`deformgl.cli.main`), with the message :func:`deformgl.scene.schema.load_scene` gives.
"""

from __future__ import annotations

import os
import re
import tomllib
from typing import Any

from deformgl.errors import SceneError
from deformgl.scene.checks import _fail, _one_line

__all__ = ["MAX_DEPTH", "MAX_SCENE_BYTES", "check_depth", "read_toml"]

#: How deep a scene file's tables and arrays may nest, and how large the file may be.
MAX_DEPTH = 32
MAX_SCENE_BYTES = 1 << 20
_TOKENS = re.compile(r'"""(?:\\.|[^\\])*?"""|\'\'\'.*?\'\'\'|"(?:\\.|[^"\\\n])*"|\'[^\'\n]*\'|#[^\n]*|[\[\]{}\n]', re.S)


def _check_text_depth(file: str, text: str) -> None:
    """Refuses brackets and braces nested beyond :data:`MAX_DEPTH` outside strings and comments,
    before the (recursive) TOML parser sees them."""
    depth, line = 0, 1
    for m in _TOKENS.finditer(text):
        tok = m[0]
        if tok in "[{":
            depth += 1
            if depth > MAX_DEPTH:
                raise SceneError(f"{file}: line {line}: nested more than {MAX_DEPTH} levels deep (arrays and tables)")
        elif tok in "]}":
            depth = max(0, depth - 1)
        line += tok.count("\n")


def check_depth(file: str, data: dict[str, Any]) -> None:
    """Refuses parsed tables and arrays nested beyond :data:`MAX_DEPTH` (dotted keys and table
    headers nest without brackets), walking iteratively."""
    stack: list[tuple[Any, int, tuple[str, ...]]] = [(data, 0, ())]
    while stack:
        value, depth, where = stack.pop()
        if depth > MAX_DEPTH:
            shown = "".join(k if k.startswith("[") or not i else "." + k for i, k in enumerate(where[:4]))
            shown += "..." if len(where) > 4 else ""
            _fail(file, shown, f"nested more than {MAX_DEPTH} levels deep (arrays and tables)")
        items: Any = iter(())
        if isinstance(value, dict):
            items = iter(value.items())
        elif isinstance(value, list):
            items = ((f"[{i}]", x) for i, x in enumerate(value))
        for k, x in items:
            if isinstance(x, (dict, list)):
                stack.append((x, depth + 1, where + (k if len(k) <= 40 else k[:40] + "...",)))


def read_toml(path: str | os.PathLike[str], file: str | None = None) -> dict[str, Any]:
    """The parsed TOML of a scene file, its nesting checked; errors name ``file`` (default: the
    path as given).

    Raises:
        SceneError: an unreadable or too large file, not UTF-8, invalid TOML, nested too deeply.
    """
    file = _one_line(os.fspath(path) if file is None else file)  # (a name may hold a line break)
    try:
        try:
            with open(path, "rb") as fh:
                raw = fh.read(MAX_SCENE_BYTES + 1)
        except ValueError as e:  # a NUL byte in the name
            raise SceneError(_one_line(f"{file}: cannot read scene file: {e}")) from None
        if len(raw) > MAX_SCENE_BYTES:
            raise SceneError(f"{file}: cannot read scene file: larger than {MAX_SCENE_BYTES // 1024} KiB")
        text = raw.decode()
        _check_text_depth(file, text)
        data = tomllib.loads(text)
    except FileNotFoundError:
        raise SceneError(f"{file}: cannot read scene file: file not found") from None
    except OSError as e:
        raise SceneError(f"{file}: cannot read scene file: {e.strerror or e}") from None
    except UnicodeDecodeError as e:
        raise SceneError(f"{file}: invalid TOML: not UTF-8 ({e.reason} at byte {e.start})") from None
    except tomllib.TOMLDecodeError as e:
        m = re.fullmatch(r"(.*) \(at (line (\d+), column (\d+)|end of document)\)", str(e))
        where = f"{m[2]}: invalid TOML: {m[1]}" if m else f"invalid TOML: {e}"
        raise SceneError(_one_line(f"{file}: {where}")) from None
    except ValueError as e:  # e.g. an integer of more than 4300 digits
        raise SceneError(_one_line(f"{file}: invalid TOML: {str(e).split(';')[0]}")) from None
    except RecursionError:
        raise SceneError(f"{file}: invalid TOML: nested too deeply to parse "
                         f"(more than {MAX_DEPTH} levels are refused)") from None
    check_depth(file, data)
    return data
