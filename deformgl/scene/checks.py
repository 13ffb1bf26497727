"""Checkers for scene-file values: each takes (file, key path, raw TOML value) and returns the
checked value or raises one :class:`~deformgl.errors.SceneError` line
``"<scene file>: <key.path>: <what>"``. :func:`_table` checks a table against a schema mapping key
to (checker, default) and hands the checked values to a builder that makes the dataclass.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn

from deformgl.errors import SceneError

# --- checkers: (file, key path, raw TOML value) -> checked value, or SceneError -------------------

Check = Callable[[str, str, Any], Any]
Build = Callable[[str, str, dict[str, Any]], Any]
REQUIRED: Any = object()  # schema default: the key must be given
# Schema defaults are raw TOML values run through the key's checker; None stays None (absent).


def _fail(file: str, key: str, msg: str) -> NoReturn:
    raise SceneError(_one_line(f"{file}: {key}: {msg}"), key=key, reason=_one_line(msg))


def _one_line(text: str) -> str:
    """``text`` with its control characters escaped, so that a message stays one line."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def _short(v: str) -> str:
    text = repr(v)
    return text if len(text) <= 60 else text[:50] + "..."


def _join(key: str, sub: str) -> str:
    return f"{key}.{sub}" if key else sub


def _describe(v: object) -> str:
    if isinstance(v, bool):
        return f"boolean {str(v).lower()}"
    for types, name in ((int, "integer"), (float, "float")):
        if isinstance(v, types):
            return f"{name} {_show(v)}"
    if isinstance(v, str):
        return f"string {_short(v)}"
    if isinstance(v, (list, tuple)):
        return f"array of {len(v)} elements"
    return "table" if isinstance(v, dict) else f"{type(v).__name__} {v}"


def _show(v: int | float) -> str:
    """``repr`` of a number, shortened for an integer too long to print whole."""
    text = repr(v)
    return text if len(text) <= 24 else f"{text[:6]}...({len(text)} digits)"


def _num(*, integer: bool = False, lo: float | None = None, hi: float | None = None, lo_open: bool = False,
         hi_open: bool = False, allow_inf: bool = False, choices: tuple[int, ...] | None = None,
         sane: tuple[float, float] | None = None, unit: str = "") -> Check:
    """A checker for a number (ints accepted, bools not), or an int with ``integer``, within bounds.

    ``lo``/``hi`` are the hard bounds of the quantity (e.g. > 0); ``sane`` is the closed range a scene
    may use (``docs/SCENE_LIMITS.md``), checked after them, its message naming ``unit``.
    """
    def check(file: str, key: str, v: Any) -> Any:
        if isinstance(v, bool) or not isinstance(v, int if integer else (int, float)):
            _fail(file, key, f"must be {'an integer' if integer else 'a number'}, got {_describe(v)}")
        try:
            f = float(v)
        except OverflowError:  # an integer beyond float range
            _fail(file, key, f"is far out of range, got {_show(v)}")
        if math.isnan(f) or (math.isinf(f) and not (allow_inf and isinstance(v, float))):
            _fail(file, key, f"must be finite, got {_show(v)}")
        if choices is not None and v not in choices:
            _fail(file, key, f"must be one of {', '.join(map(repr, choices))}, got {_show(v)}")
        if not ((lo is None or (f > lo if lo_open else f >= lo)) and (hi is None or (f < hi if hi_open else f <= hi))):
            if lo is not None and hi is not None:
                want = f"in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
            else:
                want = f"{'>' if lo_open else '>='} {lo:g}" if lo is not None else f"{'<' if hi_open else '<='} {hi:g}"
            _fail(file, key, f"must be {want}, got {_show(v)}")
        if sane is not None and not (sane[0] <= f <= sane[1]) and not (allow_inf and f == math.inf):
            left = "(" if lo_open and lo == sane[0] else "["
            _fail(file, key, f"must be in {left}{sane[0]:g}, {sane[1]:g}]{' ' + unit if unit else ''}, got {_show(v)}")
        return v if integer else f
    return check


def _of(kind: type, what: str, choices: tuple[str, ...] | None = None) -> Check:
    """A checker for a value of type ``kind`` (described as ``what``), optionally one of ``choices``."""
    def check(file: str, key: str, v: Any) -> Any:
        if not isinstance(v, kind):
            _fail(file, key, f"must be {what}, got {_describe(v)}")
        if choices is not None and v not in choices:
            _fail(file, key, f"must be one of {', '.join(map(repr, choices))}, got {_short(str(v))}")
        return v
    return check


def _int(**bounds: Any) -> Check:
    return _num(integer=True, **bounds)


def _str(choices: tuple[str, ...] | None = None) -> Check:
    return _of(str, "a string", choices)


def _vec(n: int, item: Check | None = None) -> Check:
    def check(file: str, key: str, v: Any) -> tuple[Any, ...]:
        if not isinstance(v, (list, tuple)):
            _fail(file, key, f"must be an array of {n} values, got {_describe(v)}")
        if len(v) != n:
            _fail(file, key, f"must have {n} elements, got {len(v)}")
        return tuple((item or _num())(file, f"{key}[{i}]", x) for i, x in enumerate(v))
    return check


def _array(item: Check, most: int | None = None) -> Check:
    def check(file: str, key: str, v: Any) -> tuple[Any, ...]:
        if not isinstance(v, list):
            _fail(file, key, f"must be an array of tables ([[{key}]]), got {_describe(v)}")
        if most is not None and len(v) > most:
            _fail(file, key, f"at most {most} entries are allowed, got {len(v)}")
        return tuple(item(file, f"{key}[{i}]", x) for i, x in enumerate(v))
    return check


def _table(schema: dict[str, tuple[Check, Any]], build: Build) -> Check:
    """A checker for a table: unknown keys first, then each key in schema order, then ``build``."""
    def check(file: str, key: str, v: Any) -> Any:
        if not isinstance(v, dict):
            _fail(file, key, f"must be a table, got {_describe(v)}")
        for k in v:
            if k not in schema:
                close = difflib.get_close_matches(k[:100], list(schema), n=1)
                k = k if len(k) <= 60 and k.isprintable() else _short(k)
                hint = f"did you mean {close[0]!r}?" if close else "expected one of " + ", ".join(map(repr, schema))
                _fail(file, _join(key, k), f"unknown key ({hint})")
        values = {}
        for k, (sub, default) in schema.items():
            if k not in v and default is REQUIRED:
                _fail(file, _join(key, k), "required key is missing")
            raw = v.get(k, default)
            values[k] = None if raw is None else sub(file, _join(key, k), raw)
        return build(file, key, values)
    return check


def _plain(cls: Callable[..., Any]) -> Build:
    return lambda file, key, d: cls(**d)


def _existing(file: str, key: str, path: Path, suffixes: tuple[str, ...] | None = None) -> Path:
    """``path`` if it is an existing file (with one of ``suffixes``, lower-cased, when given)."""
    try:
        exists, is_file = path.exists(), path.is_file()
    except (OSError, ValueError) as e:  # a name too long, a NUL byte
        _fail(file, key, f"cannot use path: {getattr(e, 'strerror', None) or e}")
    if exists and not is_file:
        _fail(file, key, f"not a file: {path}")
    if suffixes is not None and path.suffix.lower() not in suffixes:
        _fail(file, key, f"must be a {' or '.join(suffixes)} file, got {_short(path.name)}")
    if not is_file:
        _fail(file, key, f"file not found: {path}")
    return path


def _resolve(file: str, key: str, base: Path, rel: str) -> Path:
    """``base / rel`` made absolute, or a SceneError for a path the system cannot take."""
    try:
        return (base / rel).resolve()
    except (OSError, ValueError) as e:  # a NUL byte, a name too long, a loop of links
        _fail(file, key, f"cannot use path {_short(rel)}: {getattr(e, 'strerror', None) or e}")
