"""The cache of bindings: :func:`binding_key` hashes everything a
:class:`~deformgl.mapping.binding.Binding` depends on, :func:`save_binding` writes one atomically
(.npz), :func:`load_binding` reads it back or gives None for any bad file."""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import zipfile
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np

from deformgl.mapping.binding import Binding, BindingReport

#: Bumped whenever the binding's meaning or file layout changes: invalidates cached bindings.
BINDING_VERSION = 2


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


def save_binding(path: str | os.PathLike[str], binding: Binding, key: str) -> None:
    """Write a binding and its key to ``path`` (.npz, compressed), atomically.

    The data goes to a temporary file in the same directory, which then replaces ``path``
    (``os.replace``), so a reader never sees a half-written file; the temporary file is removed
    if writing fails.

    Raises:
        OSError: the directory does not exist or is not writable, or the disk is full.
    """
    path = Path(path)
    data: dict[str, np.ndarray] = {name: getattr(binding, name) for name in _ARRAY_FIELDS}
    report = binding.report
    data.update({f"report_{name}": getattr(report, name) for name in _REPORT_ARRAYS})
    data.update({f"report_{name}": np.asarray(getattr(report, name)) for name in _REPORT_SCALARS})
    data["key"] = np.asarray(key)
    data["version"] = np.asarray(BINDING_VERSION)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            # allow_pickle=True is numpy's default, named so that mypy knows ``data`` cannot hold it
            np.savez_compressed(fh, allow_pickle=True, **data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


_SHAPES = {"tri_nodes": 3, "weights": 3, "offset_world": 3, "offset_constant": 3,
           "offset_curvature": 3, "normal_constant": 3, "normal_curvature": 3,
           "tangent_constant": 4, "tangent_curvature": 4, "normal_world": 3, "tangent_world": 4,
           "uv": 2, "curvature_ok": 0, "distance": 0}


def load_binding(path: str | os.PathLike[str], key: str) -> Binding | None:
    """The binding cached at ``path`` if it was saved with ``key``, else None.

    Never raises for a bad cache file: missing, unreadable, corrupt, written by another
    version, for other inputs (key mismatch) or with inconsistent arrays all give None, and the
    caller binds again.
    """
    try:
        with np.load(Path(path), allow_pickle=False) as npz:
            if str(npz["key"]) != key or int(npz["version"]) != BINDING_VERSION:
                return None
            arrays = {name: np.array(npz[name]) for name in _ARRAY_FIELDS}
            # Any: what the file holds; BindingReport(...) below raises TypeError on a mismatch
            rep_arrays: dict[str, Any] = {name: np.array(npz[f"report_{name}"]) for name in _REPORT_ARRAYS}
            rep_scalars = {name: npz[f"report_{name}"].item() for name in _REPORT_SCALARS}
    except (OSError, ValueError, KeyError, EOFError, TypeError, zipfile.BadZipFile):
        return None
    count = len(arrays["tri_nodes"])
    for name, cols in _SHAPES.items():
        a = arrays[name]
        if a.shape != ((count,) if cols == 0 else (count, cols)):
            return None
        if a.dtype.kind == "f" and not np.isfinite(a).all():
            return None
    if arrays["tri_nodes"].dtype != np.int64 or arrays["curvature_ok"].dtype != bool:
        return None
    try:
        report = BindingReport(**rep_arrays, **rep_scalars)
        return Binding(**arrays, report=report)
    except TypeError:
        return None
