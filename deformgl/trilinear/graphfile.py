"""Scene-graph files (TOML): :func:`load_graph` reads one into a
:class:`~deformgl.trilinear.graphspec.SceneGraph`, :func:`save_graph` writes one back, so that
load -> save -> load is the identity. The format is docs/SCENEGRAPH.md.

Errors follow the simulation scenes' rules: one :class:`~deformgl.errors.SceneError` line
``"<file>: <key.path>: <what>"``, unknown keys named with the closest known one, before any
geometry is built. A file is a scene graph when it has a ``[graph]`` table (:func:`is_graph_file`).
"""

from __future__ import annotations

import difflib
import math
import re
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
import tomli_w

from deformgl.errors import DeformglError, InputError, SceneError
from deformgl.files import write_atomic
from deformgl.trilinear.graphspec import (
    DEFORMATIONS, SHAPE_INTEGERS, SHAPES, Deformation, GraphBody, GraphMesh, GraphTransform, GraphView, Keyframe, NodeSpec,
    SceneGraph,
)
from deformgl.trilinear.normal_transform import NORMAL_MODES

MAX_GRAPH_BYTES = 1 << 20
_TOP = ("graph", "view", "body", "meshes", "deformations", "nodes")
_NODE_KEYS = ("children", "mesh", "colour", "normals", "matrix", "translate", "rotate", "scale", "cuboid",
              "coefficients", "grid", "array", "attach")


def _fail(file: str, key: str, msg: str) -> NoReturn:
    raise SceneError("".join(c if c.isprintable() else repr(c)[1:-1] for c in f"{file}: {key}: {msg}"))


def _keys(file: str, key: str, v: Any, allowed: tuple[str, ...]) -> dict[str, Any]:
    if not isinstance(v, dict):
        _fail(file, key, f"must be a table, got {type(v).__name__}")
    for k in v:
        if k not in allowed:
            close = difflib.get_close_matches(k[:100], list(allowed), n=1)
            hint = f"did you mean {close[0]!r}?" if close else "expected one of " + ", ".join(map(repr, allowed))
            _fail(file, f"{key}.{k}" if key else k, f"unknown key ({hint})")
    return v


def _num(file: str, key: str, v: Any, *, lo: float | None = None, positive: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
        _fail(file, key, f"must be a finite number, got {v!r}"[:200])
    f = float(v)
    if positive and f <= 0.0:
        _fail(file, key, f"must be > 0, got {v!r}")
    if lo is not None and f < lo:
        _fail(file, key, f"must be >= {lo:g}, got {v!r}")
    return f


def _int(file: str, key: str, v: Any, lo: int = 1, hi: int = 1 << 20) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        _fail(file, key, f"must be an integer in [{lo}, {hi}], got {v!r}"[:200])
    return int(v)


def _str(file: str, key: str, v: Any, choices: tuple[str, ...] | None = None) -> str:
    if not isinstance(v, str) or (choices is not None and v not in choices):
        want = "one of " + ", ".join(map(repr, choices)) if choices else "a string"
        _fail(file, key, f"must be {want}, got {v!r}"[:200])
    return v


def _array(file: str, key: str, v: Any, shape: tuple[int, ...]) -> np.ndarray:
    try:
        a = np.array(v, dtype=object)
    except ValueError:
        a = np.empty(0, dtype=object)
    if a.shape != shape:
        _fail(file, key, f"must be an array of shape {shape}, got {np.shape(a) if a.size else 'a ragged value'}")
    for i, x in enumerate(a.ravel()):
        _num(file, f"{key}[{i}]", x)
    return a.astype(np.float64)


def _vec(file: str, key: str, v: Any, n: int = 3) -> tuple[float, ...]:
    return tuple(float(x) for x in _array(file, key, v, (n,)))


def _ints(file: str, key: str, v: Any, n: int = 3, hi: int = 1 << 16) -> tuple[int, ...]:
    if not isinstance(v, list) or len(v) != n:
        _fail(file, key, f"must be an array of {n} integers, got {v!r}"[:200])
    return tuple(_int(file, f"{key}[{i}]", x, 1, hi) for i, x in enumerate(v))


def _colour(file: str, key: str, v: Any) -> tuple[float, float, float]:
    c = _vec(file, key, v)
    if not all(0.0 <= x <= 1.0 for x in c):
        _fail(file, key, f"colour components must be in [0, 1], got {list(c)}")
    return c  # type: ignore[return-value]


def _box(file: str, key: str, v: Any) -> tuple[tuple[float, float, float], tuple[float, float, float]] | None:
    if v == "content":
        return None
    d = _keys(file, key, v, ("lo", "hi"))
    for k in ("lo", "hi"):
        if k not in d:
            _fail(file, f"{key}.{k}", "required key is missing")
    lo, hi = _vec(file, f"{key}.lo", d["lo"]), _vec(file, f"{key}.hi", d["hi"])
    if not all(h > lo_ for lo_, h in zip(lo, hi)):
        _fail(file, key, f"needs lo < hi on every axis, got lo={list(lo)}, hi={list(hi)}")
    return lo, hi  # type: ignore[return-value]


def _required(file: str, key: str, d: dict[str, Any], name: str) -> Any:
    if name not in d:
        _fail(file, f"{key}.{name}", "required key is missing")
    return d[name]


# ---- reading -------------------------------------------------------------------------------------
def read_toml(path: str | Path) -> dict[str, Any]:
    """The TOML document of ``path``, or one SceneError line (unreadable, too large, invalid)."""
    file = str(path)
    try:
        with open(path, "rb") as fh:
            raw = fh.read(MAX_GRAPH_BYTES + 1)
        if len(raw) > MAX_GRAPH_BYTES:
            raise SceneError(f"{file}: cannot read scene file: larger than {MAX_GRAPH_BYTES // 1024} KiB")
        return tomllib.loads(raw.decode())
    except FileNotFoundError:
        raise SceneError(f"{file}: cannot read scene file: file not found") from None
    except OSError as e:
        raise SceneError(f"{file}: cannot read scene file: {e.strerror or e}") from None
    except UnicodeDecodeError as e:
        raise SceneError(f"{file}: invalid TOML: not UTF-8 ({e.reason} at byte {e.start})") from None
    except (tomllib.TOMLDecodeError, ValueError, RecursionError) as e:
        raise SceneError(" ".join(f"{file}: invalid TOML: {e}".split())) from None


def is_graph_file(path: str | Path) -> bool:
    """Whether the TOML file at ``path`` is a scene graph (has a ``[graph]`` table); False for a
    file that cannot be read (the simulation-scene loader then reports why)."""
    try:
        return isinstance(read_toml(path).get("graph"), dict)
    except DeformglError:
        return False


def _mesh(file: str, key: str, v: Any) -> GraphMesh:
    d = _keys(file, key, v, ("shape", "file", *sorted({k for p in SHAPES.values() for k in p})))
    if ("shape" in d) == ("file" in d):
        _fail(file, key, "needs exactly one of 'shape' and 'file'")
    if "file" in d:
        for k in d:
            if k != "file":
                _fail(file, f"{key}.{k}", "a mesh file takes no shape parameters")
        return GraphMesh(file=_str(file, f"{key}.file", d["file"]))
    shape = _str(file, f"{key}.shape", d["shape"], tuple(SHAPES))
    params: dict[str, float] = {}
    for k, x in d.items():
        if k == "shape":
            continue
        if k not in SHAPES[shape]:
            _fail(file, f"{key}.{k}", f"shape {shape!r} takes only {', '.join(SHAPES[shape])}")
        params[k] = _int(file, f"{key}.{k}", x, 1, 4096) if k in SHAPE_INTEGERS else \
            _num(file, f"{key}.{k}", x, positive=True)
    for k, default in SHAPES[shape].items():
        if default is None and k not in params:
            _fail(file, f"{key}.{k}", f"required key is missing (shape {shape!r})")
    return GraphMesh(shape=shape, params=params)


def _deformation(file: str, key: str, v: Any) -> Deformation:
    d = _keys(file, key, v, ("kind", "keys", *sorted({k for p in DEFORMATIONS.values() for k in p})))
    kind = _str(file, f"{key}.kind", _required(file, key, d, "kind"), tuple(DEFORMATIONS))
    names = DEFORMATIONS[kind]
    params = {}
    for k in names:
        params[k] = _num(file, f"{key}.{k}", _required(file, key, d, k))
    for k in d:
        if k not in (*names, "kind", "keys"):
            _fail(file, f"{key}.{k}", f"a {kind!r} deformation takes only {', '.join(names)}")
    if kind == "bend" and params["length"] <= 0.0:
        _fail(file, f"{key}.length", f"must be > 0, got {params['length']!r}")
    keys: list[Keyframe] = []
    raw_keys = d.get("keys", [])
    if not isinstance(raw_keys, list):
        _fail(file, f"{key}.keys", "must be an array of tables ([[...keys]])")
    for i, k in enumerate(raw_keys):
        where = f"{key}.keys[{i}]"
        kd = _keys(file, where, k, ("t", *names))
        t = _num(file, f"{where}.t", _required(file, where, kd, "t"), lo=0.0)
        if keys and t <= keys[-1].t:
            _fail(file, f"{where}.t", f"keyframe times must increase, got {t!r} after {keys[-1].t!r}")
        values = {n: _num(file, f"{where}.{n}", x) for n, x in kd.items() if n != "t"}
        if not values:
            _fail(file, where, f"a keyframe sets at least one of {', '.join(names)}")
        keys.append(Keyframe(t, values))
    return Deformation(kind, params, keys)


def _transform(file: str, key: str, d: dict[str, Any]) -> GraphTransform | None:
    kinds = [k for k in ("matrix", "cuboid", "coefficients", "grid", "array", "attach") if k in d]
    trs = [k for k in ("translate", "rotate", "scale") if k in d]
    if len(kinds) + bool(trs) > 1:
        both = (kinds + trs)[:2]
        _fail(file, f"{key}.{both[1]}", f"a node has one transform; it already has {both[0]!r}")
    if "mesh" in d and (kinds or trs):
        _fail(file, f"{key}.{(kinds + trs)[0]}", "a mesh node has no transform (put it under a transform node)")
    if trs:
        axis, degrees, scale = (0.0, 0.0, 1.0), 0.0, (1.0, 1.0, 1.0)
        if "rotate" in d:
            r = _keys(file, f"{key}.rotate", d["rotate"], ("axis", "degrees"))
            axis = _vec(file, f"{key}.rotate.axis", _required(file, f"{key}.rotate", r, "axis"))  # type: ignore[assignment]
            if not any(axis):
                _fail(file, f"{key}.rotate.axis", "must not be zero")
            degrees = _num(file, f"{key}.rotate.degrees", _required(file, f"{key}.rotate", r, "degrees"))
        if "scale" in d:
            s = d["scale"]
            scale = (_num(file, f"{key}.scale", s, positive=True),) * 3 if isinstance(s, (int, float)) and \
                not isinstance(s, bool) else _vec(file, f"{key}.scale", s)  # type: ignore[assignment]
            if min(scale) <= 0.0:
                _fail(file, f"{key}.scale", f"must be > 0, got {list(scale)}")
        translate = _vec(file, f"{key}.translate", d["translate"]) if "translate" in d else (0.0, 0.0, 0.0)
        return GraphTransform("trs", translate=translate, axis=axis, degrees=degrees, scale=scale)  # type: ignore[arg-type]
    if not kinds:
        return None
    kind = kinds[0]
    where = f"{key}.{kind}"
    if kind == "matrix":
        m = _array(file, where, d[kind], (4, 4))
        if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], rtol=0.0, atol=1e-12):
            _fail(file, where, f"the last row must be [0, 0, 0, 1] (affine), got {m[3].tolist()}")
        return GraphTransform("matrix", matrix=m)
    v = d[kind]
    if kind == "cuboid":
        t = _keys(file, where, v, ("corners", "box"))
        return GraphTransform("cuboid", corners=_array(file, f"{where}.corners", _required(file, where, t, "corners"), (8, 3)),
                         box=_box(file, f"{where}.box", t.get("box", {"lo": [0, 0, 0], "hi": [1, 1, 1]})))
    if kind == "coefficients":
        t = _keys(file, where, v, ("matrix", "box"))
        return GraphTransform("coefficients",
                         coefficients=_array(file, f"{where}.matrix", _required(file, where, t, "matrix"), (3, 8)),
                         box=_box(file, f"{where}.box", t.get("box", {"lo": [0, 0, 0], "hi": [1, 1, 1]})))
    if kind == "grid":
        t = _keys(file, where, v, ("deformation", "file", "cells", "box"))
        if ("deformation" in t) == ("file" in t):
            _fail(file, where, "needs exactly one of 'deformation' and 'file'")
        box = _box(file, f"{where}.box", t.get("box", "content"))
        if "file" in t:
            if "cells" in t:
                _fail(file, f"{where}.cells", "a lattice file gives its own cells")
            if box is None:
                _fail(file, f"{where}.box", "a lattice file needs an explicit box {lo, hi}")
            return GraphTransform("grid", file=_str(file, f"{where}.file", t["file"]), box=box)
        return GraphTransform("grid", deformation=_str(file, f"{where}.deformation", t["deformation"]), box=box,
                         cells=_ints(file, f"{where}.cells", _required(file, where, t, "cells"), hi=4096))  # type: ignore[arg-type]
    if kind == "array":
        t = _keys(file, where, v, ("count", "step", "offset", "colours", "tangent_of", "tangent_at"))
        count = _ints(file, f"{where}.count", _required(file, where, t, "count"), hi=1 << 16)
        if int(np.prod(count)) > 1 << 20:
            _fail(file, f"{where}.count", f"at most {1 << 20} instances, got {int(np.prod(count))}")
        colours = t.get("colours", [])
        if not isinstance(colours, list):
            _fail(file, f"{where}.colours", "must be an array of RGB colours")
        return GraphTransform("array", count=count,  # type: ignore[arg-type]
                         step=_vec(file, f"{where}.step", t.get("step", [0, 0, 0])),  # type: ignore[arg-type]
                         offset=_vec(file, f"{where}.offset", t.get("offset", [0, 0, 0])),  # type: ignore[arg-type]
                         colours=tuple(_colour(file, f"{where}.colours[{i}]", c) for i, c in enumerate(colours)),
                         tangent_of=_str(file, f"{where}.tangent_of", t["tangent_of"]) if "tangent_of" in t else None,
                         tangent_at=_vec(file, f"{where}.tangent_at", t.get("tangent_at", [0, 0, 0])))  # type: ignore[arg-type]
    t = _keys(file, where, v, ("start", "end", "anchors", "width", "height"))
    frac = [_vec(file, f"{where}.{k}", _required(file, where, t, k)) for k in ("start", "end")]
    for k, p in zip(("start", "end"), frac):
        if not all(-0.5 <= x <= 1.5 for x in p):
            _fail(file, f"{where}.{k}", f"bounding-box fractions must be in [-0.5, 1.5], got {list(p)}")
    return GraphTransform("attach", start=frac[0], end=frac[1],  # type: ignore[arg-type]
                     anchors=_int(file, f"{where}.anchors", t.get("anchors", 8), 2, 4096),
                     width=_num(file, f"{where}.width", t.get("width", 0.02), positive=True),
                     height=_num(file, f"{where}.height", t.get("height", 0.02), positive=True))


def _node(file: str, key: str, v: Any) -> NodeSpec:
    d = _keys(file, key, v, _NODE_KEYS)
    children = d.get("children", [])
    if not isinstance(children, list) or not all(isinstance(c, str) for c in children):
        _fail(file, f"{key}.children", "must be an array of node names")
    if "mesh" in d and children:
        _fail(file, f"{key}.children", "a mesh node has no children")
    return NodeSpec(transform=_transform(file, key, d), children=list(children),
                    mesh=_str(file, f"{key}.mesh", d["mesh"]) if "mesh" in d else None,
                    colour=_colour(file, f"{key}.colour", d["colour"]) if "colour" in d else None,
                    normals=_str(file, f"{key}.normals", d["normals"], NORMAL_MODES) if "normals" in d else None)


def _named(file: str, key: str, v: Any, item: Callable[[str, str, Any], Any]) -> dict[str, Any]:
    if not isinstance(v, dict):
        _fail(file, key, "must be a table of named entries")
    return {name: item(file, f"{key}.{name}", x) for name, x in v.items()}


def parse_graph(file: str, data: dict[str, Any]) -> SceneGraph:
    """A :class:`SceneGraph` from a parsed TOML document (``file`` names it in errors)."""
    _keys(file, "", data, _TOP)
    g = _keys(file, "graph", data.get("graph", {}), ("roots", "description", "output"))
    roots = _required(file, "graph", g, "roots")
    if not isinstance(roots, list) or not 1 <= len(roots) <= 2 or not all(isinstance(r, str) for r in roots):
        _fail(file, "graph.roots", "must be an array of one or two node names")
    output = _str(file, "graph.output", g["output"]) if "output" in g else None
    if output is not None and not output.lower().endswith(".png"):
        _fail(file, "graph.output", f"must be a .png file, got {output!r}")
    vd = _keys(file, "view", data.get("view", {}), ("size", "azimuth", "elevation", "distance", "samples",
                                                     "background"))
    view = GraphView(size=_ints(file, "view.size", vd["size"], 2, hi=8192) if "size" in vd else GraphView.size,  # type: ignore[arg-type]
                azimuth=_num(file, "view.azimuth", vd.get("azimuth", GraphView.azimuth)),
                elevation=_num(file, "view.elevation", vd.get("elevation", GraphView.elevation)),
                distance=_num(file, "view.distance", vd.get("distance", GraphView.distance), positive=True),
                samples=_int(file, "view.samples", vd.get("samples", GraphView.samples), 0, 16),
                background=_colour(file, "view.background", vd.get("background", list(GraphView.background))))
    if min(view.size) < 16:
        _fail(file, "view.size", f"at least 16x16 pixels, got {view.size[0]}x{view.size[1]}")
    body = None
    if "body" in data:
        bd = _keys(file, "body", data["body"], ("scene",))
        body = GraphBody(_str(file, "body.scene", _required(file, "body", bd, "scene")))
    graph = SceneGraph(roots=list(roots), nodes=_named(file, "nodes", data.get("nodes", {}), _node),
                       meshes=_named(file, "meshes", data.get("meshes", {}), _mesh),
                       deformations=_named(file, "deformations", data.get("deformations", {}), _deformation),
                       view=view, output=output, body=body,
                       description=_str(file, "graph.description", g.get("description", "")))
    try:
        return graph.check()
    except InputError as e:
        key, _, what = str(e).partition(": ")
        raise SceneError(f"{file}: {key}: {what}") from None


def load_graph(path: str | Path) -> SceneGraph:
    """Read and check a scene-graph file (named as given in errors); relative paths stay relative
    to the file (:func:`deformgl.trilinear.graphbuild.build_graph` resolves them).

    Raises:
        SceneError: unreadable or invalid TOML, unknown keys, bad values, dangling names, cycles.
    """
    return parse_graph(str(path), read_toml(path))


# ---- writing -------------------------------------------------------------------------------------
def _box_doc(box: Any) -> Any:
    return "content" if box is None else {"lo": list(box[0]), "hi": list(box[1])}


def _transform_doc(t: GraphTransform) -> dict[str, Any]:
    if t.kind == "trs":
        return {"translate": list(t.translate), "rotate": {"axis": list(t.axis), "degrees": t.degrees},
                "scale": list(t.scale)}
    if t.kind == "matrix":
        return {"matrix": np.asarray(t.matrix).tolist()}
    if t.kind == "cuboid":
        return {"cuboid": {"corners": np.asarray(t.corners).tolist(), "box": _box_doc(t.box)}}
    if t.kind == "coefficients":
        return {"coefficients": {"matrix": np.asarray(t.coefficients).tolist(), "box": _box_doc(t.box)}}
    if t.kind == "grid":
        if t.file is not None:
            return {"grid": {"file": t.file, "box": _box_doc(t.box)}}
        return {"grid": {"deformation": t.deformation, "cells": list(t.cells), "box": _box_doc(t.box)}}
    if t.kind == "array":
        a: dict[str, Any] = {"count": list(t.count), "step": list(t.step), "offset": list(t.offset)}
        if t.colours:
            a["colours"] = [list(c) for c in t.colours]
        if t.tangent_of is not None:
            a["tangent_of"], a["tangent_at"] = t.tangent_of, list(t.tangent_at)
        return {"array": a}
    return {"attach": {"start": list(t.start), "end": list(t.end), "anchors": t.anchors, "width": t.width,
                       "height": t.height}}


def graph_document(graph: SceneGraph) -> dict[str, Any]:
    """The TOML document of ``graph`` (what :func:`save_graph` writes)."""
    head: dict[str, Any] = {"roots": list(graph.roots)}
    if graph.description:
        head["description"] = graph.description
    if graph.output is not None:
        head["output"] = graph.output
    v = graph.view
    doc: dict[str, Any] = {"graph": head, "view": {
        "size": list(v.size), "azimuth": v.azimuth, "elevation": v.elevation, "distance": v.distance,
        "samples": v.samples, "background": list(v.background)}}
    if graph.body is not None:
        doc["body"] = {"scene": graph.body.scene}
    doc["meshes"] = {n: ({"file": m.file} if m.file is not None else {"shape": m.shape, **m.params})
                     for n, m in graph.meshes.items()}
    doc["deformations"] = {}
    for n, d in graph.deformations.items():
        entry: dict[str, Any] = {"kind": d.kind, **d.params}
        if d.keys:
            entry["keys"] = [{"t": k.t, **k.values} for k in d.keys]
        doc["deformations"][n] = entry
    nodes = {}
    for n, node in graph.nodes.items():
        e: dict[str, Any] = {}
        if node.mesh is not None:
            e["mesh"] = node.mesh
        if node.children:
            e["children"] = list(node.children)
        if node.colour is not None:
            e["colour"] = list(node.colour)
        if node.normals is not None:
            e["normals"] = node.normals
        if node.transform is not None:
            e.update(_transform_doc(node.transform))
        nodes[n] = e
    doc["nodes"] = nodes
    return doc


_ARRAY = re.compile(r"\[\n((?:[ ]*[^\s\]][^\n]*,\n)+)[ ]*\]")


def compact_arrays(text: str) -> str:
    """``text`` (TOML from tomli_w) with its one-item-a-line arrays written on one line, innermost
    first: ``[1.0, 0.0]`` rather than four lines."""
    while True:
        out = _ARRAY.sub(lambda m: "[" + " ".join(x.strip() for x in m[1].splitlines())[:-1] + "]", text)
        if out == text:
            return out
        text = out


def save_graph(graph: SceneGraph, path: str | Path) -> Path:
    """Write ``graph`` as a scene-graph file, atomically (temporary file, rename); floats are
    written exactly (shortest repr), so loading it gives an equal graph. Returns the path."""
    graph.check()
    text = compact_arrays(tomli_w.dumps(graph_document(graph)))
    out = Path(path)
    write_atomic(out, lambda stream: stream.write(text.encode()))
    return out
