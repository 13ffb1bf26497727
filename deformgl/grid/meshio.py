"""Loading triangle meshes from disk, with every vertex kept exactly as the file stores it.

:func:`load_mesh` reads PLY, OBJ, STL, GLB, glTF and OFF files, each optionally gzip-compressed
(``dragon.ply.gz``). Meshes are loaded without trimesh's processing, so the returned vertex array
has the file's vertex count and order (later code maps each file vertex onto the simulation
grid). Because processing is off, the checks it would have done silently (dropping non-finite
vertices and the faces using them, for one) are done here and reported as :class:`InputError`.
"""

from __future__ import annotations

import io
import json
import os
import re
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from deformgl.errors import InputError
from deformgl.inputs import max_coordinate, read_bounded

#: File suffixes :func:`load_mesh` accepts, each also with ``.gz`` appended.
SUPPORTED_SUFFIXES: tuple[str, ...] = (".ply", ".obj", ".stl", ".glb", ".gltf", ".off")

# Loader options per format. OBJ needs ``maintain_order`` (otherwise trimesh drops unreferenced
# vertices and splits vertices per texture coordinate) and one mesh for all materials.
_FORMAT_NAMES = {"ply": "PLY", "obj": "OBJ", "stl": "STL", "glb": "GLB", "gltf": "glTF", "off": "OFF"}

# ValueError texts of numpy or Python internals (trimesh parsing values that are not there).
_NUMPY_ERRORS = re.compile(r"unpack|reshape|could not convert|invalid literal|"
                           r"buffer (is )?smaller|broadcast|dtype")

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
    _check_counts(data, file_type, name)
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
    """Read the file's bytes (gunzipped, at most DEFORMGL_MAX_MESH_BYTES) and reject an empty
    file."""
    data = read_bounded(file_path, name, compressed)
    if not data.strip():
        raise InputError(f"{name}: file is empty")
    return data


def _parse(data: bytes, file_type: str, file_path: Path, name: str) -> trimesh.parent.Geometry:
    """Parse file bytes with trimesh, without processing, wrapping any failure as one line
    naming the format (never trimesh's internals nor a module it lacks)."""
    shown = _FORMAT_NAMES[file_type]
    if file_type in ("obj", "off", "gltf"):
        _check_utf8(data, name, shown)
    if file_type == "gltf":
        try:
            json.loads(data)
        except ValueError as exc:
            raise InputError(f"{name}: not a valid glTF file (not JSON: {_one_line(exc)})") from None
    try:
        return trimesh.load(
            io.BytesIO(data),
            file_type=file_type,
            resolver=trimesh.resolvers.FilePathResolver(str(file_path.parent)),
            process=False,
            **_LOADER_OPTIONS.get(file_type, {}),
        )
    except (ImportError, UnicodeError):
        # trimesh decodes text it cannot read as UTF-8 with charset_normalizer (not installed)
        raise InputError(f"{name}: not a valid {shown} file (neither binary {shown} nor UTF-8 "
                         f"text)") from None
    except (ValueError, IndexError) as exc:  # trimesh on purpose ("Not a ply file!"), or numpy
        text = _one_line(exc)
        if _NUMPY_ERRORS.search(text):  # a parse step that met too few or wrong values
            text = "corrupt or truncated"
        raise InputError(f"{name}: not a valid {shown} file ({text})") from None
    except Exception:  # noqa: BLE001  anything else: trimesh failing inside on malformed data
        raise InputError(f"{name}: not a valid {shown} file (corrupt or truncated)") from None


def _check_utf8(data: bytes, name: str, shown: str) -> None:
    """Refuse a text format whose bytes are not UTF-8, naming the first bad byte."""
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"{name}: not a valid {shown} file (not UTF-8 text: byte "
                         f"0x{data[exc.start]:02x} at offset {exc.start:,})") from None


def _check_counts(data: bytes, file_type: str, name: str) -> None:
    """Refuse a PLY or OFF file holding fewer elements than its header declares (trimesh would
    load the part that is there without a word)."""
    if file_type == "ply" and data[:3] == b"ply":
        _check_ply(data, name)
    elif file_type == "off":
        _check_off(data, name)
    elif file_type == "stl" and len(data) >= 84:
        # binary STL: an 80-byte header, a uint32 triangle count, 50 bytes per triangle; text
        # ("solid ...") is not counted
        declared = int(np.frombuffer(data, "<u4", 1, 80)[0])
        if 84 + 50 * declared > len(data) and not _is_text_stl(data):
            _truncated(name, "triangle", declared, (len(data) - 84) // 50)


def _is_text_stl(data: bytes) -> bool:
    """Whether STL bytes start as ASCII STL does ("solid"; some binary writers do too, and are
    then left to trimesh)."""
    return data.lstrip()[:5].lower() == b"solid"


_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2,
              "uint16": 2, "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4,
              "float32": 4, "double": 8, "float64": 8}
_PLY_END = re.compile(rb"end_header[ \t]*\r?\n")


def _check_ply(data: bytes, name: str) -> None:
    """The PLY header's element counts against the data after it: lines for ASCII, bytes for
    binary (elements with one list property of constant length, as faces of triangles are;
    other list elements are left to trimesh)."""
    end = _PLY_END.search(data, 0, 1 << 20)
    if end is None:
        return  # trimesh reports the missing header
    lines = data[: end.start()].decode("ascii", "replace").splitlines()
    fmt = next((ln.split()[1] for ln in lines if ln.startswith("format") and len(ln.split()) > 1), "")
    elements: list[tuple[str, int, list[list[str]]]] = []
    for words in (ln.split() for ln in lines):
        if len(words) == 3 and words[0] == "element" and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif words and words[0] == "property" and elements:
            elements[-1][2].append(words[1:])
    body = data[end.end():]
    if fmt == "ascii":
        held = _lines(body)
        for element, count, _ in elements:
            if held < count:
                _truncated(name, element, count, held)
            held -= count
        return
    if fmt not in ("binary_little_endian", "binary_big_endian"):
        return
    order = "<" if fmt == "binary_little_endian" else ">"
    offset = 0
    for element, count, props in elements:
        size = _ply_record_size(body, offset, props, order)
        if size is None:
            return
        held = min(count, (len(body) - offset) // size) if size else count
        if held < count:
            _truncated(name, element, count, held)
        offset += count * size


def _ply_record_size(body: bytes, offset: int, props: list[list[str]], order: str) -> int | None:
    """Bytes of one record of a binary PLY element starting at ``offset``, or None when that
    cannot be known without reading every record (lists of varying length, unknown types)."""
    lists = [p for p in props if p[0] == "list"]
    fixed = [p for p in props if p[0] != "list"]
    if len(lists) > 1 or any(p[0] not in _PLY_SIZES for p in fixed):
        return None
    size = sum(_PLY_SIZES[p[0]] for p in fixed)
    if not lists:
        return size
    if len(lists[0]) < 3 or lists[0][1] not in _PLY_SIZES or lists[0][2] not in _PLY_SIZES:
        return None
    before = sum(_PLY_SIZES[p[0]] for p in props[: props.index(lists[0])])
    count_size, item = _PLY_SIZES[lists[0][1]], _PLY_SIZES[lists[0][2]]
    start = offset + before
    if start + count_size > len(body):
        return size + count_size  # not even one record: anything non-zero says "0 held"
    kind = "i" if lists[0][1] in ("char", "int8", "short", "int16", "int", "int32") else "u"
    record = size + count_size + item * int(
        np.frombuffer(body, f"{order}{kind}{count_size}", 1, start)[0])
    held = (len(body) - offset) // record
    lengths = np.ndarray((held,), f"{order}{kind}{count_size}", body, start, (record,))
    return record if held == 0 or bool((lengths == lengths[0]).all()) else None


def _check_off(data: bytes, name: str) -> None:
    """The OFF header's vertex and face counts against the lines after it."""
    text = data[:4096].decode("utf-8", "replace")
    words: list[str] = []
    consumed = 0
    for line in text.splitlines(keepends=True):
        consumed += len(line.encode("utf-8", "replace"))
        words += line.split("#")[0].split()
        if len(words) >= 3 or (words and not words[0].endswith("OFF")):
            break
    if len(words) < 3 or not words[0].endswith("OFF") or not all(w.isdigit() for w in words[1:3]):
        return  # trimesh reports a malformed header
    vertices, faces = int(words[1]), int(words[2])
    body = data[consumed:]
    held = _lines(body)
    if held < vertices:
        _truncated(name, "vertex", vertices, held)
    if held - vertices < faces:
        _truncated(name, "face", faces, held - vertices)


def _lines(body: bytes) -> int:
    """Lines in ``body`` up to its last non-blank byte, counted without copying it."""
    end = len(body)
    while end and body[end - 1] in b" \t\r\n":
        end -= 1
    return body.count(b"\n", 0, end) + 1 if end else 0


def _truncated(name: str, element: str, declared: int, held: int) -> None:
    plural = "vertices" if element == "vertex" else f"{element}s"
    raise InputError(f"{name}: truncated: header declares {declared:,} {plural}, "
                     f"file holds {max(held, 0):,}")


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
    bound = max_coordinate()
    far = np.flatnonzero((np.abs(vertices) >= bound).any(axis=1))
    if far.size:
        vertex = int(far[0])
        coords = ", ".join(f"{c:.6g}" for c in vertices[vertex])
        raise InputError(
            f"{name}: vertex {vertex} has a coordinate beyond ±{bound:.6g} ({coords}); "
            f"{_count(far.size, 'vertex')} out of range (DEFORMGL_MAX_COORDINATE sets the bound)"
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
