"""The cache of bindings: :func:`binding_key` hashes everything a
:class:`~deformgl.mapping.binding.Binding` depends on, :func:`save_binding` writes one atomically
(.npz, with a SHA-256 checksum of its arrays), :func:`read_binding` reads it back and verifies it
(format version, key, checksum, every array's dtype and shape, index ranges, finiteness, weights)
or says why it cannot be used (:class:`BadCacheEntry`); :func:`load_binding` gives None instead.

The checksum catches damage (a flipped bit, a half-copied file, an edit); the value checks catch an
entry that is self-consistent but wrong (written by a buggy version, or edited with its checksum
recomputed). Neither makes the cache a security boundary: whoever can write the cache folder can
still choose what a verified entry holds. See docs/CACHE.md.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np

from deformgl.files import write_atomic
from deformgl.mapping.bases import constant_basis, curvature_basis
from deformgl.mapping.binding import Binding, BindingReport

#: Bumped whenever the binding's meaning or file layout changes: invalidates cached bindings.
#: 3: entries carry a checksum of their arrays.
BINDING_VERSION = 3


class BadCacheEntry(Exception):
    """A cache file that exists but cannot be used; ``str(exc)`` says why, on one line, as a
    phrase that follows "binding cache entry" (e.g. "fails its checksum")."""


def binding_key(vertices: np.ndarray, faces: np.ndarray, node_positions: np.ndarray,
                surface_triangles: np.ndarray, spacing: float, options: dict[str, Any], *,
                surface_nodes: np.ndarray | None = None, node_normals: np.ndarray | None = None,
                uv: np.ndarray | None = None, tangents: np.ndarray | None = None) -> str:
    """sha256 hex digest of everything a binding depends on, and :data:`BINDING_VERSION`.

    Arrays are hashed as float64 / int64 C-order bytes with their shapes, so equal values give
    equal keys whatever dtype they came in. ``options`` (e.g. far, periodic_u, a format number)
    must be JSON-serialisable; keys are sorted. The keyword arrays are optional extra inputs
    (``surface.nodes``, rest node normals, uv, tangents) for callers whose binding depends on
    more than the rest grid.
    """
    h = hashlib.sha256(f"deformgl-binding-{BINDING_VERSION}".encode())
    arrays = {"vertices": (vertices, np.float64), "faces": (faces, np.int64),
              "node_positions": (node_positions, np.float64),
              "surface_triangles": (surface_triangles, np.int64), "surface_nodes": (surface_nodes, np.int64),
              "node_normals": (node_normals, np.float64), "uv": (uv, np.float64),
              "tangents": (tangents, np.float64)}
    for label, (arr, dtype) in arrays.items():
        if arr is None:
            h.update(f"|{label}:none".encode())
            continue
        a = np.ascontiguousarray(np.asarray(arr, dtype=dtype))
        h.update(f"|{label}:{a.shape}".encode())
        h.update(a.tobytes())
    h.update(f"|spacing:{float(spacing)!r}".encode())
    h.update(("|options:" + json.dumps(options, sort_keys=True, default=repr)).encode())
    return h.hexdigest()


_ARRAY_FIELDS = tuple(f.name for f in fields(Binding) if f.name != "report")
_REPORT_ARRAYS = ("far_vertices", "far_distances", "degenerate_triangles", "degenerate_vertices")
_REPORT_SCALARS = tuple(f.name for f in fields(BindingReport) if f.name not in _REPORT_ARRAYS)

#: The field specs of :class:`Binding` (see its docstring): dtype and columns, 0 for a (V,) array.
#: Node numbers are int32 or int64 (the grid's index dtype); every other field has one dtype.
INDEX_DTYPES = (np.dtype(np.int32), np.dtype(np.int64))
FIELD_SPECS: dict[str, tuple[np.dtype[Any], int]] = {
    "tri_nodes": (np.dtype(np.int64), 3), "weights": (np.dtype(np.float64), 3),
    "offset_world": (np.dtype(np.float64), 3), "offset_constant": (np.dtype(np.float64), 3),
    "offset_curvature": (np.dtype(np.float64), 3), "normal_constant": (np.dtype(np.float64), 3),
    "normal_curvature": (np.dtype(np.float64), 3), "tangent_constant": (np.dtype(np.float64), 4),
    "tangent_curvature": (np.dtype(np.float64), 4), "normal_world": (np.dtype(np.float64), 3),
    "tangent_world": (np.dtype(np.float64), 4), "uv": (np.dtype(np.float64), 2),
    "curvature_ok": (np.dtype(np.bool_), 0), "distance": (np.dtype(np.float64), 0)}
#: The report's arrays: dtype; each is 1-D, far_distances as long as far_vertices.
REPORT_SPECS: dict[str, np.dtype[Any]] = {
    "far_vertices": np.dtype(np.int64), "far_distances": np.dtype(np.float64),
    "degenerate_triangles": np.dtype(np.int64), "degenerate_vertices": np.dtype(np.int64)}
_FLOAT_SCALARS = ("spacing", "far")
#: |sum of weights - 1| allowed (bind renormalises them, so they sum to 1 within rounding).
WEIGHT_SUM_TOL = 1e-9
#: |w . p + offset_world - vertex| allowed, relative to the scale of the vertices (rounding only).
RECONSTRUCTION_TOL = 1e-9

_MEMBERS = frozenset((*_ARRAY_FIELDS, *(f"report_{n}" for n in (*_REPORT_ARRAYS, *_REPORT_SCALARS)),
                      "key", "version", "checksum"))


def checksum(arrays: dict[str, np.ndarray]) -> str:
    """SHA-256 hex digest over every array of an entry but ``checksum``, in name order: each
    array's name, dtype, shape and C-order bytes."""
    h = hashlib.sha256(b"deformgl-binding-entry")
    for name in sorted(arrays):
        if name == "checksum":
            continue
        a = np.ascontiguousarray(arrays[name])
        h.update(f"|{name}:{a.dtype.str}:{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def save_binding(path: str | os.PathLike[str], binding: Binding, key: str) -> None:
    """Write a binding, its key and the checksum of its arrays to ``path`` (.npz, compressed),
    atomically (:func:`deformgl.files.write_atomic`: a reader never sees a half-written file).

    Raises:
        OSError: the directory does not exist or is not writable, a directory is at ``path``,
            or the disk is full.
    """
    data: dict[str, np.ndarray] = {name: np.asarray(getattr(binding, name)) for name in _ARRAY_FIELDS}
    report = binding.report
    data.update({f"report_{name}": np.asarray(getattr(report, name)) for name in _REPORT_ARRAYS})
    data.update({f"report_{name}": np.asarray(getattr(report, name)) for name in _REPORT_SCALARS})
    data["key"] = np.asarray(key)
    data["version"] = np.asarray(BINDING_VERSION)
    data["checksum"] = np.asarray(checksum(data))
    # allow_pickle=True is numpy's default, named so that mypy knows ``data`` cannot hold it
    write_atomic(path, lambda stream: np.savez_compressed(stream, allow_pickle=True, **data))


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or "no message"
    return f"{type(exc).__name__}: {text[:200]}"


def _parse(data: bytes) -> dict[str, np.ndarray]:
    """The arrays of an .npz file's bytes, never unpickling anything."""
    if not data.startswith(b"PK\x03\x04"):
        raise BadCacheEntry(f"is not an .npz file ({'empty' if not data else 'no zip header'})")
    try:
        npz = np.load(io.BytesIO(data), allow_pickle=False)
        if not isinstance(npz, np.lib.npyio.NpzFile):
            raise BadCacheEntry("is not an .npz archive")
        with npz:
            return {name: np.array(npz[name]) for name in npz.files}
    except BadCacheEntry:
        raise
    except Exception as exc:  # the file is untrusted input: whatever numpy or zipfile raise
        raise BadCacheEntry(f"is not a readable .npz file ({_one_line(exc)})") from None


def _scalar(arrays: dict[str, np.ndarray], name: str, kinds: str) -> Any:
    a = arrays[name]
    if a.shape != () or a.dtype.kind not in kinds:
        raise BadCacheEntry(f"has {name} of dtype {a.dtype} and shape {a.shape}, not a scalar")
    return a.item()


def _check_arrays(arrays: dict[str, np.ndarray], node_count: int | None) -> None:
    count = len(arrays["tri_nodes"]) if arrays["tri_nodes"].ndim else 0
    for name, (dtype, cols) in FIELD_SPECS.items():
        a, shape = arrays[name], (count,) if cols == 0 else (count, cols)
        allowed = INDEX_DTYPES if dtype in INDEX_DTYPES else (dtype,)
        if a.dtype not in allowed:
            raise BadCacheEntry(f"has {name} of dtype {a.dtype}, not {' or '.join(map(str, allowed))}")
        if a.shape != shape:
            raise BadCacheEntry(f"has {name} of shape {a.shape}, not {shape}")
        if a.dtype.kind == "f" and not np.isfinite(a).all():
            raise BadCacheEntry(f"has non-finite values in {name}")
    tri = arrays["tri_nodes"]
    if tri.size:
        low, high = int(tri.min()), int(tri.max())
        limit = "" if node_count is None else f"..{node_count - 1}"
        if low < 0 or (node_count is not None and high >= node_count):
            raise BadCacheEntry(f"has node index {low if low < 0 else high} in tri_nodes, outside 0{limit}")
    w = arrays["weights"]
    if ((w < 0) | (w > 1)).any():
        raise BadCacheEntry("has weights outside [0, 1]")
    if count and np.abs(w.sum(axis=1) - 1).max() > WEIGHT_SUM_TOL:
        raise BadCacheEntry("has weights that do not sum to 1")
    for name in ("tangent_constant", "tangent_curvature", "tangent_world"):
        if not np.isin(arrays[name][:, 3], (-1.0, 1.0)).all():
            raise BadCacheEntry(f"has a handedness in {name} that is not +1 or -1")
    offset = arrays["offset_world"]
    if np.abs(np.linalg.norm(offset, axis=1) - arrays["distance"]).max(initial=0.0) > \
            1e-12 * (1.0 + float(np.abs(offset).max(initial=0.0))):
        raise BadCacheEntry("has distances that are not the lengths of offset_world")


def _check_report(arrays: dict[str, np.ndarray], count: int) -> BindingReport:
    rep: dict[str, Any] = {}
    for name, dtype in REPORT_SPECS.items():
        a = arrays[f"report_{name}"]
        if a.dtype not in (INDEX_DTYPES if dtype in INDEX_DTYPES else (dtype,)) or a.ndim != 1:
            raise BadCacheEntry(f"has report_{name} of dtype {a.dtype} and shape {a.shape}, "
                                f"not a 1-D {dtype} array")
        rep[name] = a
    for name in _REPORT_SCALARS:
        rep[name] = _scalar(arrays, f"report_{name}", "f" if name in _FLOAT_SCALARS else "iu")
    if rep["vertex_count"] != count:
        raise BadCacheEntry(f"has report_vertex_count {rep['vertex_count']} for {count} vertices")
    if len(rep["far_distances"]) != len(rep["far_vertices"]) or not np.isfinite(rep["far_distances"]).all():
        raise BadCacheEntry("has report_far_distances that do not match report_far_vertices")
    for name, limit in (("far_vertices", count), ("degenerate_vertices", count),
                        ("degenerate_triangles", rep["triangle_count"])):
        a = rep[name]
        if a.size and (a.min() < 0 or a.max() >= limit):
            raise BadCacheEntry(f"has an index in report_{name} outside 0..{limit - 1}")
    return BindingReport(**rep)


def _check_reconstruction(arrays: dict[str, np.ndarray], vertices: np.ndarray,
                          node_positions: np.ndarray) -> None:
    """Mosegaard & Sørensen 2005, eq. 4/5 at rest: ``w . p + o`` must give back every vertex."""
    v = np.asarray(vertices, dtype=np.float64)
    x = np.asarray(node_positions, dtype=np.float64)
    if v.shape != arrays["offset_world"].shape:
        raise BadCacheEntry(f"binds {len(arrays['offset_world'])} vertices, the mesh has {len(v)}")
    r = np.einsum("vi,vij->vj", arrays["weights"], x[arrays["tri_nodes"]])
    scale = 1.0 + max(float(np.abs(v).max(initial=0.0)), float(np.abs(x).max(initial=0.0)))
    if np.abs(r + arrays["offset_world"] - v).max(initial=0.0) > RECONSTRUCTION_TOL * scale:
        raise BadCacheEntry("does not reproduce the mesh at rest (weights, nodes and offsets disagree)")


def _check_bases(arrays: dict[str, np.ndarray], node_positions: np.ndarray,
                 node_normals: np.ndarray | None) -> None:
    """The offsets, normals and tangents in the constant basis (Mosegaard & Sørensen 2005, eq. 6/7)
    and, with the rest node normals, the curvature basis (eq. 8) must be their world vectors
    expressed in those bases, as :func:`deformgl.mapping.binding.bind` wrote them."""
    x = np.asarray(node_positions, dtype=np.float64)
    tri, w = arrays["tri_nodes"], arrays["weights"]
    p = x[tri]
    const, ok_c = constant_basis(p[:, 0], p[:, 1], p[:, 2])
    curv, ok_k = (None, None) if node_normals is None else \
        curvature_basis(p[:, 0], p[:, 1], p[:, 2], w, np.asarray(node_normals, dtype=np.float64)[tri])
    world = {"offset": arrays["offset_world"], "normal": arrays["normal_world"],
             "tangent": arrays["tangent_world"][:, :3]}
    for label, vec in world.items():
        scale = RECONSTRUCTION_TOL * (1.0 + float(np.abs(vec).max(initial=0.0)))
        expect_c = np.where(ok_c[:, None], np.einsum("vkj,vj->vk", const, vec), vec)
        if np.abs(arrays[f"{label}_constant"][:, :3] - expect_c).max(initial=0.0) > scale:
            raise BadCacheEntry(f"has {label}_constant that is not {label}_world in the constant basis")
        if curv is not None and ok_k is not None:
            expect_k = np.where(ok_k[:, None], np.einsum("vkj,vj->vk", curv, vec), expect_c)
            if np.abs(arrays[f"{label}_curvature"][:, :3] - expect_k).max(initial=0.0) > scale:
                raise BadCacheEntry(f"has {label}_curvature that is not {label}_world in the curvature basis")
    hand = arrays["tangent_world"][:, 3]
    if not (np.array_equal(arrays["tangent_constant"][:, 3], hand)
            and np.array_equal(arrays["tangent_curvature"][:, 3], hand)):
        raise BadCacheEntry("has tangent handedness that differs between bases")


def read_binding(path: str | os.PathLike[str], key: str, *, node_count: int | None = None,
                 vertices: np.ndarray | None = None,
                 node_positions: np.ndarray | None = None,
                 node_normals: np.ndarray | None = None) -> Binding | None:
    """The binding cached at ``path``, verified; None if there is no file at ``path``.

    Checks, in order: the file is an .npz (read without unpickling), it holds exactly the
    expected arrays, its format version is :data:`BINDING_VERSION`, its key is ``key``, its
    checksum (:func:`checksum`) matches, every array has the dtype and shape of
    :data:`FIELD_SPECS` / :data:`REPORT_SPECS`, floats are finite, node indices are in
    ``0..node_count-1`` (just non-negative without ``node_count``), weights are in [0, 1] and sum
    to 1, handedness is +-1, distances are the offsets' lengths, the report's indices are in
    range; with ``vertices`` and ``node_positions`` (the rest mesh and nodes the key was made
    for; node_count defaults to their count) the weights, nodes and offsets must give back every
    vertex (Mosegaard & Sørensen 2005, eq. 4/5), and the offsets, normals and tangents in the
    constant basis (Mosegaard & Sørensen 2005, eq. 6/7) must be the world ones in that basis;
    with ``node_normals`` (the rest node normals :func:`~deformgl.mapping.binding.bind` was
    given) those in the curvature basis too (Mosegaard & Sørensen 2005, eq. 8). Only
    ``curvature_ok`` and ``uv`` are not checked against the inputs.

    Raises:
        BadCacheEntry: the file is there but fails a check (its message says which).
        OSError: the file cannot be read (a directory at ``path``, no permission, a file where
            a folder of ``path`` should be), other than not existing.
    """
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        return None
    arrays = _parse(data)
    missing = sorted(_MEMBERS - set(arrays))
    extra = sorted(set(arrays) - _MEMBERS)
    if "version" in missing:
        raise BadCacheEntry("has no format version")
    version = _scalar(arrays, "version", "iu")
    if version != BINDING_VERSION:
        raise BadCacheEntry(f"has format version {version}, not {BINDING_VERSION}")
    if missing or extra:
        raise BadCacheEntry(f"lacks array {missing[0]!r}" if missing else f"has an unexpected array {extra[0]!r}")
    if arrays["key"].shape != () or arrays["key"].dtype.kind != "U" or str(arrays["key"]) != key:
        raise BadCacheEntry("has another key (made for other inputs)")
    if arrays["checksum"].shape != () or arrays["checksum"].dtype.kind != "U" \
            or str(arrays["checksum"]) != checksum(arrays):
        raise BadCacheEntry("fails its checksum (the file is damaged)")
    if node_count is None and node_positions is not None:
        node_count = len(node_positions)
    _check_arrays(arrays, node_count)
    report = _check_report(arrays, len(arrays["tri_nodes"]))
    if vertices is not None and node_positions is not None:
        _check_reconstruction(arrays, vertices, node_positions)
    if node_positions is not None:
        _check_bases(arrays, node_positions, node_normals)
    return Binding(**{name: arrays[name] for name in _ARRAY_FIELDS}, report=report)


def load_binding(path: str | os.PathLike[str], key: str, *, node_count: int | None = None) -> Binding | None:
    """The binding cached at ``path`` if it was saved with ``key`` and passes
    :func:`read_binding`'s checks, else None: never raises for a bad or unreadable cache file
    (for the reason, call :func:`read_binding`)."""
    try:
        return read_binding(path, key, node_count=node_count)
    except (BadCacheEntry, OSError):
        return None
