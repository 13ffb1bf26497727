"""Preparing a detailed mesh for a mapping mode: binding (cached), per-vertex basis choice,
tangents and normal map; and writing the deformed mesh captured from the GPU."""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np
import trimesh

from deformgl.mapping.binding import Binding, bind
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.normals import rest_normals
from deformgl.mapping.binding_cache import BadCacheEntry, binding_key, read_binding, save_binding
from deformgl.errors import DeformglWarning, InputError
from deformgl.files import read_png, write_atomic
from deformgl.render.mapped import MappedVertices
from deformgl.mapping.bases import curvature_basis
from deformgl.mapping.tangents import procedural_normal_map

CACHE_ENV = "DEFORMGL_CACHE_DIR"
BINDING_FORMAT = 1


def cache_dir() -> Path:
    """Where bindings are cached: ``$DEFORMGL_CACHE_DIR``, else ``$XDG_CACHE_HOME/deformgl``
    (an absolute ``XDG_CACHE_HOME`` only, as the XDG spec asks), else ``~/.cache/deformgl``.
    See docs/CACHE.md."""
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV])
    xdg = os.environ.get("XDG_CACHE_HOME", "")
    base = Path(xdg) if xdg and Path(xdg).is_absolute() else Path.home() / ".cache"
    return base / "deformgl"


def mesh_uv(mesh: trimesh.Trimesh) -> np.ndarray | None:
    """The mesh's own per-vertex UVs, if it has them."""
    uv = getattr(getattr(mesh, "visual", None), "uv", None)
    if uv is None or len(uv) != len(mesh.vertices):
        return None
    return np.asarray(uv, dtype=np.float64)


def _warn(message: str) -> None:
    warnings.warn(message, DeformglWarning, stacklevel=3)


def get_binding(mesh: trimesh.Trimesh, grid: NodeGrid, surface, *, use_cache: bool, uv: np.ndarray | None) -> Binding:
    """Bind the mesh to the node surface of ``grid``, reusing a cached binding of the same inputs.

    A cached entry is verified (:func:`deformgl.mapping.binding_cache.read_binding`, against this
    mesh and grid); a bad one is rebuilt and replaced, with a :class:`DeformglWarning`. Something
    in the way of the cache (a directory at the file's path, a folder that cannot be written, a
    file where the folder goes) is a :class:`DeformglWarning` too ("caching off for this run"),
    and the mesh is bound without the cache.
    """
    key = binding_key(mesh.vertices, mesh.faces, grid.rest_positions, surface.triangles, grid.spacing,
                      {"format": BINDING_FORMAT}, uv=uv)

    normals = rest_normals(grid)

    def fresh() -> Binding:
        return bind(mesh.vertices, mesh.faces, grid.rest_positions, normals, surface,
                    spacing=grid.spacing, uv=uv)

    if not use_cache:
        return fresh()
    path = cache_dir() / f"binding-{key[:24]}.npz"
    try:
        cached = read_binding(path, key, vertices=mesh.vertices, node_positions=grid.rest_positions,
                              node_normals=normals)
    except BadCacheEntry as exc:
        _warn(f"{path}: binding cache entry {exc}: rebuilt")
        cached = None
    except OSError as exc:
        _warn(f"{path}: caching off for this run: cannot read the cache file "
              f"({exc.strerror or type(exc).__name__})")
        return fresh()
    if cached is not None:
        return cached
    binding = fresh()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        save_binding(path, binding, key)
    except OSError as exc:
        _warn(f"{path}: caching off for this run: cannot write the cache file "
              f"({exc.strerror or type(exc).__name__})")
    return binding


#: "curvature" mode uses Mosegaard & Sørensen 2005, eq. 8 only where ``|Nc x T|`` exceeds this (a conditioning bound, far
#: below auto's :data:`deformgl.mapping.binding.MIN_SIN_NC_T`).
MIN_SIN_CURVATURE = 1e-2


def mapped_vertices(binding: Binding, mode: str, rest_positions: np.ndarray, rest_normals: np.ndarray) -> MappedVertices:
    """Per-vertex data for ``mode``: which basis each vertex uses and its vectors in that basis.

    "constant": Mosegaard & Sørensen 2005, eq. 6 everywhere. "curvature": eq. 8 wherever the rest curvature basis can be
    built well conditioned (``|Nc x T| > MIN_SIN_CURVATURE``), Mosegaard & Sørensen 2005, eq. 6 where it cannot (nodes
    without normals summing to zero, Nc along T). "auto": eq. 8
    only where the binding judged the node normals well defined (``curvature_ok``, paper 3.6).
    """
    p = rest_positions[binding.tri_nodes]
    frame, buildable = curvature_basis(p[:, 0], p[:, 1], p[:, 2], binding.weights, rest_normals[binding.tri_nodes])
    if mode == "constant":
        use = np.zeros(len(binding.weights), bool)
    elif mode == "curvature":
        # well conditioned only: where Nc is within ~0.6 degrees of T, the rounding of the 15-bit
        # packed normals (~1e-4 rad) turns Bc = Nc x T around and the vertex jumps
        edge = p[:, 1] - p[:, 0]
        t = edge / np.maximum(np.linalg.norm(edge, axis=1, keepdims=True), 1e-300)
        use = buildable & (np.linalg.norm(np.cross(frame[:, 1], t), axis=1) > MIN_SIN_CURVATURE)
    elif mode == "auto":
        use = buildable & binding.curvature_ok
    else:
        raise ValueError(f"mapping mode {mode!r} has no per-vertex data")

    def local(world: np.ndarray, constant: np.ndarray) -> np.ndarray:
        in_curv = np.einsum("vkj,vj->vk", frame, world)
        return np.where(use[:, None], in_curv, constant)

    t_local = local(binding.tangent_world[:, :3], binding.tangent_constant[:, :3])
    tangent = np.hstack([t_local, binding.tangent_constant[:, 3:4]])
    return MappedVertices(
        tri_nodes=binding.tri_nodes, weights=binding.weights,
        offset=local(binding.offset_world, binding.offset_constant), offset_world=binding.offset_world,
        normal=local(binding.normal_world, binding.normal_constant), normal_world=binding.normal_world,
        use_curvature=use, tangent=tangent,
        tangent_world=binding.tangent_world[:, :3])


def normal_map_image(spec, source: Path) -> np.ndarray | None:
    """The normal map of a scene: None, the procedural detail map, or a PNG file."""
    if spec is None:
        return None
    if spec == "procedural":
        return procedural_normal_map()
    try:
        image = read_png(Path(spec))
    except OSError as exc:
        raise InputError(f"{source}: mapping.normal_map: cannot read {spec}: {exc}") from None
    except InputError as exc:  # (too many pixels, corrupt: the message names the image)
        raise InputError(f"{source}: mapping.normal_map: {exc}") from None
    return image[..., :3]


def export_mesh(path: Path, vertices: np.ndarray, normals: np.ndarray, faces: np.ndarray) -> None:
    """Write a deformed mesh (.ply, .obj or .glb) atomically: temporary file, then rename."""
    suffix = path.suffix.lower()
    if suffix not in (".ply", ".obj", ".glb"):
        raise InputError(f"{path}: --export-mesh must end in .ply, .obj or .glb")
    lengths = np.linalg.norm(normals, axis=1, keepdims=True)
    mesh = trimesh.Trimesh(np.asarray(vertices, dtype=np.float64), faces,
                           vertex_normals=normals / np.where(lengths > 0, lengths, 1.0), process=False)
    data = mesh.export(file_type=suffix[1:])
    if isinstance(data, bytes):
        payload = data
    elif isinstance(data, str):
        payload = data.encode()
    else:  # trimesh returns a dict only for its "dict" export types, never for these suffixes
        raise InputError(f"{path}: trimesh exported a {type(data).__name__} for {suffix}, not bytes or text")
    write_atomic(path, lambda stream: stream.write(payload))
