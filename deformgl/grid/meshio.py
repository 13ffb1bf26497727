"""Loading triangle meshes from disk, with every vertex kept exactly as the file stores it.

:func:`load_mesh` reads PLY, OBJ, STL, GLB, glTF and OFF files, each optionally gzip-compressed
(``dragon.ply.gz``). Meshes are loaded without trimesh's processing, so the returned vertex array
has the file's vertex count and order (later code maps each file vertex onto the simulation
grid). Because processing is off, the checks it would have done silently (dropping non-finite
vertices and the faces using them, for one) are done here and reported as :class:`InputError`.
"""

from __future__ import annotations

import gzip
import io
import os
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from deformgl.errors import InputError

#: File suffixes :func:`load_mesh` accepts, each also with ``.gz`` appended.
SUPPORTED_SUFFIXES: tuple[str, ...] = (".ply", ".obj", ".stl", ".glb", ".gltf", ".off")

# Loader options per format. OBJ needs ``maintain_order`` (otherwise trimesh drops unreferenced
# vertices and splits vertices per texture coordinate) and one mesh for all materials.
_LOADER_OPTIONS: dict[str, dict[str, Any]] = {
    "obj": {"maintain_order": True, "group_material": False, "skip_materials": True},
}


def load_mesh(path: str | os.PathLike[str]) -> trimesh.Trimesh:
    """Load a triangle mesh file, keeping its vertices exactly as stored.

    A file holding a scene of several meshes (GLB, glTF, multi-object OBJ) is flattened into one
    mesh: each part is moved by its scene-graph transform and the parts are concatenated in
    scene-graph order.

    Args:
        path: Mesh file; the format comes from the suffix (``.ply``, ``.obj``, ``.stl``,
            ``.glb``, ``.gltf``, ``.off``, or any of these followed by ``.gz``).

    Returns:
        The mesh, built with ``process=False``: float64 vertices in file order (unreferenced
        vertices included), int64 faces.

    Raises:
        InputError: The file is missing, unreadable, empty, of an unsupported format or cannot
            be parsed; or the mesh has no vertices or faces, a face index out of range, a
            non-finite vertex coordinate, or all vertices at one point. The one-line message
            starts with the path as given.
    """
    name = os.fspath(path)
    file_path = Path(name)
    compressed, file_type = _format_of(file_path)
    if not file_path.exists():
        raise InputError(f"{name}: file not found")
    if not file_path.is_file():
        raise InputError(f"{name}: not a regular file")
    if file_type is None:
        shown = (Path(file_path.stem).suffix if compressed else "") + file_path.suffix
        raise InputError(
            f"{name}: unsupported mesh format ({shown or 'no suffix'}); "
            f"supported: {', '.join(SUPPORTED_SUFFIXES)} (each optionally followed by .gz)"
        )
    data = _read(file_path, name, compressed)
    loaded = _parse(data, file_type, file_path, name)
    vertices, faces, uv = _flatten(loaded, name)
    _validate(vertices, faces, name)
    visual = trimesh.visual.TextureVisuals(uv=uv) if uv is not None else None
    return trimesh.Trimesh(vertices=vertices, faces=faces, visual=visual, process=False)


def _format_of(file_path: Path) -> tuple[bool, str | None]:
    """Return (gzip-compressed?, trimesh file type or None when unsupported) for a path."""
    suffix = file_path.suffix.lower()
    compressed = suffix == ".gz"
    if compressed:
        suffix = Path(file_path.stem).suffix.lower()
    if suffix not in SUPPORTED_SUFFIXES:
        return compressed, None
    return compressed, suffix[1:]


def _read(file_path: Path, name: str, compressed: bool) -> bytes:
    """Read the file's bytes, decompressing gzip, and reject an empty file."""
    try:
        data = file_path.read_bytes()
    except OSError as exc:
        raise InputError(f"{name}: cannot read file: {exc.strerror or exc}") from exc
    if compressed:
        try:
            data = gzip.decompress(data)
        except (OSError, EOFError, zlib.error) as exc:
            raise InputError(f"{name}: not a valid gzip file: {_one_line(exc)}") from exc
    if not data.strip():
        raise InputError(f"{name}: file is empty")
    return data


def _parse(data: bytes, file_type: str, file_path: Path, name: str) -> trimesh.parent.Geometry:
    """Parse file bytes with trimesh, without processing, wrapping any failure."""
    try:
        return trimesh.load(
            io.BytesIO(data),
            file_type=file_type,
            resolver=trimesh.resolvers.FilePathResolver(str(file_path.parent)),
            process=False,
            **_LOADER_OPTIONS.get(file_type, {}),
        )
    except Exception as exc:  # trimesh raises many unrelated types on malformed data
        raise InputError(f"{name}: cannot parse as {file_type.upper()}: {_one_line(exc)}") from exc


def _flatten(loaded: object, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Return (vertices, faces, per-vertex UVs or None) of a loaded Trimesh, or of all meshes of
    a Scene concatenated (UVs only when every part has them)."""
    found: list[object]
    if isinstance(loaded, trimesh.Scene):
        # dump() applies each instance's scene-graph transform (and fixes winding on mirrors).
        found = list(loaded.dump())
    else:
        found = [loaded]
    parts = [g for g in found if isinstance(g, trimesh.Trimesh)]
    if not parts:
        if not found:
            raise InputError(f"{name}: empty mesh (no geometry in file; is it truncated?)")
        kinds = ", ".join(sorted({type(g).__name__ for g in found}))
        raise InputError(f"{name}: no triangle mesh in file (found only {kinds})")
    vertices: list[np.ndarray] = []
    faces: list[np.ndarray] = []
    uvs: list[np.ndarray | None] = []
    offset = 0
    for part in parts:
        part_faces = np.asarray(part.faces, dtype=np.int64)
        vertices.append(np.asarray(part.vertices, dtype=np.float64).reshape(-1, 3))
        faces.append(part_faces.reshape(-1, 3) + offset)
        offset += len(vertices[-1])
        uv = getattr(getattr(part, "visual", None), "uv", None)
        ok = uv is not None and np.shape(uv) == (len(vertices[-1]), 2) and np.isfinite(uv).all()
        uvs.append(np.asarray(uv, dtype=np.float64) if ok else None)
    present = [u for u in uvs if u is not None]
    uv_all = np.concatenate(present) if len(present) == len(uvs) else None
    return np.concatenate(vertices), np.concatenate(faces), uv_all


def _validate(vertices: np.ndarray, faces: np.ndarray, name: str) -> None:
    """Raise InputError when the mesh is empty, indexes out of range, non-finite or a point."""
    if len(vertices) == 0 or len(faces) == 0:
        raise InputError(f"{name}: empty mesh ({len(vertices)} vertices, {len(faces)} faces)")
    bad_faces = np.flatnonzero(((faces < 0) | (faces >= len(vertices))).any(axis=1))
    if bad_faces.size:
        face = int(bad_faces[0])
        raise InputError(
            f"{name}: face {face} has a vertex index out of range {faces[face].tolist()} "
            f"(the mesh has {len(vertices)} vertices); {_count(bad_faces.size, 'face')} bad"
        )
    bad_vertices = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
    if bad_vertices.size:
        vertex = int(bad_vertices[0])
        coords = ", ".join(f"{c:.6g}" for c in vertices[vertex])
        raise InputError(
            f"{name}: vertex {vertex} has a non-finite coordinate ({coords}); "
            f"{_count(bad_vertices.size, 'vertex')} bad"
        )
    if not np.ptp(vertices, axis=0).any():
        raise InputError(f"{name}: mesh has zero extent (all {len(vertices)} vertices coincide)")


def _one_line(exc: BaseException) -> str:
    """An exception's text on one line, or its type name when the text is empty."""
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


def _count(count: int, noun: str) -> str:
    """``"1 vertex is"`` / ``"3 vertices are"``: a count with its noun and verb agreeing."""
    if count == 1:
        return f"1 {noun} is"
    plural = "vertices" if noun == "vertex" else f"{noun}s"
    return f"{count} {plural} are"
