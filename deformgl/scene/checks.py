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
    raise SceneError(f"{file}: {key}: {msg}")


def _join(key: str, sub: str) -> str:
    return f"{key}.{sub}" if key else sub


def _describe(v: object) -> str:
    if isinstance(v, bool):
        return f"boolean {str(v).lower()}"
    for types, name in ((int, "integer"), (float, "float"), (str, "string")):
        if isinstance(v, types):
            return f"{name} {v!r}"
    if isinstance(v, (list, tuple)):
        return f"array of {len(v)} elements"
    return "table" if isinstance(v, dict) else f"{type(v).__name__} {v}"


def _num(*, integer: bool = False, lo: float | None = None, hi: float | None = None, lo_open: bool = False,
         hi_open: bool = False, allow_inf: bool = False, choices: tuple[int, ...] | None = None) -> Check:
    """A checker for a number (ints accepted, bools not), or an int with ``integer``, within bounds."""
    def check(file: str, key: str, v: Any) -> Any:
        if isinstance(v, bool) or not isinstance(v, int if integer else (int, float)):
            _fail(file, key, f"must be {'an integer' if integer else 'a number'}, got {_describe(v)}")
        if math.isnan(v) or (math.isinf(v) and not allow_inf):
            _fail(file, key, f"must be finite, got {v!r}")
        if choices is not None and v not in choices:
            _fail(file, key, f"must be one of {', '.join(map(repr, choices))}, got {v!r}")
        if (lo is None or (v > lo if lo_open else v >= lo)) and (hi is None or (v < hi if hi_open else v <= hi)):
            return v if integer else float(v)
        if lo is not None and hi is not None:
            want = f"in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
        else:
            want = f"{'>' if lo_open else '>='} {lo:g}" if lo is not None else f"{'<' if hi_open else '<='} {hi:g}"
        _fail(file, key, f"must be {want}, got {v!r}")
    return check


def _of(kind: type, what: str, choices: tuple[str, ...] | None = None) -> Check:
    """A checker for a value of type ``kind`` (described as ``what``), optionally one of ``choices``."""
    def check(file: str, key: str, v: Any) -> Any:
        if not isinstance(v, kind):
            _fail(file, key, f"must be {what}, got {_describe(v)}")
        if choices is not None and v not in choices:
            _fail(file, key, f"must be one of {', '.join(map(repr, choices))}, got {v!r}")
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
                close = difflib.get_close_matches(k, list(schema), n=1)
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


def _existing(file: str, key: str, path: Path) -> Path:
    if not path.is_file():
        _fail(file, key, f"{'not a file' if path.exists() else 'file not found'}: {path}")
    return path
