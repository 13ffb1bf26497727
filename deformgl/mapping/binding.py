"""Binding a detailed mesh to the node surface, once, on the CPU (Mosegaard & Sørensen 2005, 3.3).

For every vertex ``v`` of the detailed mesh :func:`bind` finds the closest point ``r`` on the
node-grid surface (:func:`deformgl.grid.surface.grid_surface` over the rest node positions), the
triangle of nodes ``(p1, p2, p3)`` it lies on and its barycentric weights (Mosegaard & Sørensen 2005, eq. 4), and the
offset ``o = v - r`` (eq. 5). The offset, the vertex normal and the vertex tangent (3.3.4) are
then expressed (Mosegaard & Sørensen 2005, eq. 7) in the two triangle bases :mod:`deformgl.mapping.bases` rebuilds from the
deformed nodes: the constant basis (Mosegaard & Sørensen 2005, eq. 6) and the curvature-corrected basis (eq. 8), the latter
from the rest node normals exactly as the GPU unpacks them. This is the inverse of
:func:`deformgl.mapping.bases.map_vertices`: at rest every vertex, normal and tangent maps to itself.

Where the curvature basis is unreliable (paper 3.5: nodes without an Mosegaard & Sørensen 2005, eq. 3 normal, such as
one-node-thin sheets) :attr:`Binding.curvature_ok` is False, and an "auto" mapping uses the
constant basis there (paper 3.6). The closest-point search is in :mod:`deformgl.mapping.closest`;
bindings are cached by a hash of their inputs in :mod:`deformgl.mapping.binding_cache`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from deformgl.errors import InputError
from deformgl.mapping.bases import constant_basis, curvature_basis
from deformgl.mapping.closest import clean_weights, row_dot, closest_on_triangles
from deformgl.grid.surface import GridSurface
from deformgl.mapping.tangents import orthonormalize_tangents, procedural_uv, vertex_normals, vertex_tangents

#: Default far threshold, in grid spacings: a vertex farther than this from the node surface is
#: reported (its offset is long, so it swings with every rotation of its triangle).
FAR_SPACINGS = 1.5
#: curvature_ok needs ``|Nc x T| > MIN_SIN_NC_T`` with Nc the normalised weighted node normal
#: and T the triangle tangent (Mosegaard & Sørensen 2005, eq. 8): below it (about 5.7 degrees) ``Bc = Nc x T`` is a
#: difference of nearly parallel vectors and turns erratically as the nodes move.
MIN_SIN_NC_T = 0.1
#: curvature_ok needs Nc within this angle of the constant-basis normal N (Mosegaard & Sørensen 2005, eq. 6). Beyond it the
#: node normals disagree with the triangle (a sheet wound the other way, a groove, a corner
#: node whose normal points along an edge) and the offset would be rotated far off. At rest T is
#: perpendicular to N, so this test alone already keeps Nc at least 15 degrees off T
#: (``|Nc x T| >= 0.26``); MIN_SIN_NC_T is checked first and reported as its own reason.
MAX_NC_ANGLE_DEG = 75.0
#: curvature_ok needs the weighted sum of the three unit node normals to be at least this long:
#: shorter means the normals disagree (opposite faces of a slab two nodes thick), so Nc is the
#: small difference of large vectors and swings wildly as the nodes move (measured on the
#: dragon on 21 nodes: such vertices opened seams 10x wider than the constant basis).
MIN_NC_AGREEMENT = 0.7
#: A node normal shorter than this is "undefined" (unpack_normals gives exactly 0 or unit).
MIN_NODE_NORMAL = 0.5


@dataclass(frozen=True, eq=False)
class BindingReport:
    """What :func:`bind` noticed about a binding.

    Attributes:
        vertex_count: vertices bound.
        triangle_count: triangles of the node surface.
        spacing: grid spacing h.
        far: far threshold in spacings.
        far_vertices: (K,) int64 vertices farther than ``far * spacing`` from the node surface.
        far_distances: (K,) float64 their distances.
        degenerate_triangles: (D,) int64 indices into the surface triangles whose nodes are
            repeated or collinear at rest (the constant basis, Mosegaard & Sørensen 2005, eq. 6, cannot be built).
        degenerate_vertices: (M,) int64 vertices bound to such a triangle (they keep their
            world-space offset while it stays degenerate).
        no_normal: vertices whose triangle has a node without an Mosegaard & Sørensen 2005, eq. 3 normal.
        parallel: vertices whose interpolated normal Nc is near-parallel to T (or zero).
        disagree: vertices whose node normals disagree (weighted sum shorter than MIN_NC_AGREEMENT).
        flipped: vertices whose Nc is more than MAX_NC_ANGLE_DEG from the triangle normal N.
        curvature_fallback: vertices with curvature_ok False. Each is counted under the first
            reason that applies: degenerate triangle (``degenerate_vertices``), no_normal,
            parallel (which includes an Nc that sums to zero), disagree, flipped.
        normal_fallback: vertices without a mesh normal (no face, or faces whose area-weighted
            normals cancel: zero-area or double-sided), given the normal of their node triangle.
    """

    vertex_count: int
    triangle_count: int
    spacing: float
    far: float
    far_vertices: np.ndarray
    far_distances: np.ndarray
    degenerate_triangles: np.ndarray
    degenerate_vertices: np.ndarray
    no_normal: int
    parallel: int
    disagree: int
    flipped: int
    curvature_fallback: int
    normal_fallback: int

    def lines(self) -> list[str]:
        """Human summary, one finding per line."""
        out = [f"bound {self.vertex_count} vertices to {self.triangle_count} node-surface triangles "
               f"(spacing {self.spacing:.4g})"]
        if len(self.far_vertices):
            worst = int(np.argmax(self.far_distances))
            out.append(f"{len(self.far_vertices)} vertices farther than {self.far:g} spacings from the "
                       f"node surface; farthest: vertex {int(self.far_vertices[worst])} at "
                       f"{self.far_distances[worst] / self.spacing:.2f} spacings")
        if len(self.degenerate_triangles):
            out.append(f"{len(self.degenerate_triangles)} degenerate node triangles (repeated or "
                       f"collinear nodes at rest), {len(self.degenerate_vertices)} vertices bound "
                       f"to them keep world-space offsets")
        if self.curvature_fallback:
            out.append(f"curvature basis unreliable for {self.curvature_fallback} vertices (auto mode "
                       f"uses the constant basis there): node without normal {self.no_normal}, "
                       f"normal near-parallel to T {self.parallel}, node normals disagreeing {self.disagree}, "
                       f"flipped against the triangle "
                       f"{self.flipped}")
        if self.normal_fallback:
            out.append(f"{self.normal_fallback} vertices have no mesh normal (used by no face, or "
                       f"their faces' normals cancel: zero-area or double-sided faces); they use "
                       f"their node triangle's normal")
        return out


@dataclass(frozen=True, eq=False)
class Binding:
    """Per-vertex data of a detailed mesh bound to the node surface (all arrays read-only).

    Attributes:
        tri_nodes: (V, 3) int64 node numbers (p1, p2, p3) of each vertex's node triangle (a
            triangle of the GridSurface, its winding kept).
        weights: (V, 3) float64 Mosegaard & Sørensen 2005, eq. 4 weights of the reference point r: sum 1, each in [0, 1].
        offset_world: (V, 3) Mosegaard & Sørensen 2005, eq. 5 offset ``o = v - r`` at rest, world space.
        offset_constant: (V, 3) o in the constant basis (T, N, B) of Mosegaard & Sørensen 2005, eq. 6/7 (x along T, y along
            N, z along B).
        offset_curvature: (V, 3) o in the curvature basis (Tc, Nc, Bc) of Mosegaard & Sørensen 2005, eq. 8 built from the
            rest node normals passed to :func:`bind`. Where that basis cannot be built at rest it
            holds the constant-basis values (finite; the mapping falls back to world space).
        normal_constant, normal_curvature: (V, 3) the vertex normal in each basis (3.3.4).
        tangent_constant, tangent_curvature: (V, 4) xyz the vertex tangent in each basis, w the
            handedness (+1/-1): the bitangent is ``w * (normal x tangent)``.
        normal_world, tangent_world: (V, 3), (V, 4) rest normal and tangent in world space
            (used where a basis is degenerate).
        uv: (V, 2) the texture coordinates the tangents belong to (given, or procedural).
        curvature_ok: (V,) bool, the curvature basis is reliable for this vertex.
        distance: (V,) ``|o|``.
        report: what :func:`bind` noticed.
    """

    tri_nodes: np.ndarray
    weights: np.ndarray
    offset_world: np.ndarray
    offset_constant: np.ndarray
    offset_curvature: np.ndarray
    normal_constant: np.ndarray
    normal_curvature: np.ndarray
    tangent_constant: np.ndarray
    tangent_curvature: np.ndarray
    normal_world: np.ndarray
    tangent_world: np.ndarray
    uv: np.ndarray
    curvature_ok: np.ndarray
    distance: np.ndarray
    report: BindingReport

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, np.ndarray):
                value.setflags(write=False)

    @property
    def vertex_count(self) -> int:
        """Number of bound vertices V."""
        return int(self.tri_nodes.shape[0])


# --------------------------------------------------------------------------------------------
# Input checks


def _array(value: Any, name: str, what: str, cols: int, dtype: type) -> np.ndarray:
    arr = np.asarray(value)
    if arr.ndim != 2 or arr.shape[1] != cols:
        raise InputError(f"{name}: {what} must be an array of shape (n, {cols}), got shape {arr.shape}")
    if dtype is np.int64:
        if arr.size and not np.issubdtype(arr.dtype, np.integer):
            raise InputError(f"{name}: {what} must be integers, got {arr.dtype}")
        return arr.astype(np.int64)
    arr = arr.astype(np.float64)
    bad = np.flatnonzero(~np.isfinite(arr).all(axis=1))
    if len(bad):
        raise InputError(f"{name}: {what} {bad[0]} is not finite ({len(bad)} such rows)")
    return arr


def _check_inputs(name: str, vertices: Any, faces: Any, node_positions: Any, node_normals: Any,
                  surface: GridSurface, spacing: float, far: float) -> tuple[np.ndarray, ...]:
    v = _array(vertices, name, "vertex", 3, np.float64)
    f = _array(faces, name, "face", 3, np.int64)
    if len(v) == 0:
        raise InputError(f"{name}: the mesh has no vertices to bind")
    if len(f):
        bad = np.flatnonzero(((f < 0) | (f >= len(v))).any(axis=1))
        if len(bad):
            raise InputError(f"{name}: face {bad[0]} uses a vertex index out of range "
                             f"({len(v)} vertices)")
    x = _array(node_positions, name, "node position", 3, np.float64)
    n = _array(node_normals, name, "node normal", 3, np.float64)
    if len(n) != len(x):
        raise InputError(f"{name}: {len(n)} node normals for {len(x)} nodes")
    if len(surface.triangles) == 0:
        raise InputError(f"{name}: the node surface has no triangles to bind the mesh to "
                         f"(no full cell and no 2x2 sheet of nodes)")
    if surface.nodes.min() < 0 or surface.nodes.max() >= len(x):
        raise InputError(f"{name}: the node surface uses node {int(surface.nodes.max())}, but only "
                         f"{len(x)} node positions were given")
    if not (math.isfinite(spacing) and spacing > 0):
        raise InputError(f"{name}: grid spacing must be positive and finite, got {spacing!r}")
    if not (math.isfinite(far) and far > 0):
        raise InputError(f"{name}: far threshold must be positive and finite, got {far!r}")
    return v, f, x, n


# --------------------------------------------------------------------------------------------
# Binding


def _in_basis(frame: np.ndarray, vec: np.ndarray) -> np.ndarray:
    """Mosegaard & Sørensen 2005, Eq. 7: components of world vectors (V, 3) along the rows of orthonormal frames (V, 3, 3)."""
    return np.einsum("vkj,vj->vk", frame, vec)


def _tangents(v: np.ndarray, f: np.ndarray, normal: np.ndarray, name: str, tangents: Any, uv: Any,
              periodic_u: bool | None) -> tuple[np.ndarray, np.ndarray]:
    """World tangents (V, 4) and the UVs they belong to (see :func:`bind`)."""
    if uv is not None:
        uv = _array(uv, name, "texture coordinate", 2, np.float64)
        if len(uv) != len(v):
            raise InputError(f"{name}: {len(uv)} texture coordinates for {len(v)} vertices")
    if tangents is not None:
        t = np.asarray(tangents)
        cols = t.shape[1] if t.ndim == 2 else 0
        t = _array(t, name, "tangent", 4 if cols == 4 else 3, np.float64)
        if len(t) != len(v):
            raise InputError(f"{name}: {len(t)} tangents for {len(v)} vertices")
        w = np.where(t[:, 3] < 0, -1.0, 1.0) if t.shape[1] == 4 else np.ones(len(v))
        out = np.concatenate([orthonormalize_tangents(normal, t[:, :3]), w[:, None]], axis=1)
        return out, (procedural_uv(v, normal) if uv is None else uv)
    periodic = (uv is None) if periodic_u is None else periodic_u
    if uv is None:
        uv = procedural_uv(v, normal)
    return vertex_tangents(v, f, normal, uv, periodic_u=periodic), uv


def bind(vertices: np.ndarray, faces: np.ndarray, node_positions: np.ndarray, node_normals: np.ndarray,
         surface: GridSurface, *, spacing: float, tangents: np.ndarray | None = None,
         uv: np.ndarray | None = None, periodic_u: bool | None = None, far: float = FAR_SPACINGS,
         name: str = "mesh") -> Binding:
    """Bind every vertex of a detailed mesh to its closest node-surface triangle (3.3.1-3.3.4).

    Args:
        vertices: (V, 3) rest positions of the detailed mesh (same frame as the nodes).
        faces: (F, 3) its triangles (for vertex normals and tangents).
        node_positions: (N, 3) rest node positions.
        node_normals: (N, 3) rest Mosegaard & Sørensen 2005, eq. 3 node normals as the GPU sees them (unit, or zero where
            undefined): ``unpack_normals(pack_normals(unit sums))``, see :func:`deformgl.sim.normals.rest_normals`.
        surface: the node surface (triangles over ``surface.nodes``).
        spacing: grid spacing h (for the far test).
        tangents: (V, 4) or (V, 3) tangents to use (orthonormalised against the vertex normals;
            w kept as its sign, +1 if absent); they take precedence over ``uv``.
        uv: (V, 2) texture coordinates to derive tangents from (Lengyel); without either,
            :func:`deformgl.mapping.tangents.procedural_uv` coordinates are used.
        periodic_u: u is periodic with period 1 (wrap per-face u differences); default: True
            for the procedural coordinates, False for ``uv`` given.
        far: far threshold in spacings (reported, not an error).
        name: the mesh's name for messages.

    Returns:
        The binding; ``binding.report`` lists far vertices, degenerate triangles and the
        vertices where the curvature basis is unreliable.

    Raises:
        InputError: malformed or non-finite input arrays, an empty node surface.
    """
    v, f, x, node_n = _check_inputs(name, vertices, faces, node_positions, node_normals, surface,
                                    float(spacing), float(far))
    tri_all = surface.nodes[surface.triangles]                       # (T, 3) node numbers
    corners = x[tri_all]
    _, tri_valid = constant_basis(corners[:, 0], corners[:, 1], corners[:, 2])
    tri_id, w = closest_on_triangles(v, corners, ~tri_valid, x[surface.nodes])
    w = clean_weights(w)                                            # Mosegaard & Sørensen 2005, eq. 4
    tri_nodes = tri_all[tri_id]
    p = x[tri_nodes]                                                 # (V, 3, 3)
    r = np.einsum("vi,vij->vj", w, p)                                # Mosegaard & Sørensen 2005, eq. 4, as map_vertices
    o = v - r                                                        # eq. 5

    const, ok_c = constant_basis(p[:, 0], p[:, 1], p[:, 2])          # Mosegaard & Sørensen 2005, eq. 6
    curv, ok_k = curvature_basis(p[:, 0], p[:, 1], p[:, 2], w, node_n[tri_nodes])  # eq. 8

    normal, has_normal = vertex_normals(v, f)
    normal = np.where(has_normal[:, None], normal,
                      np.where(ok_c[:, None], const[:, 1], np.array([0.0, 0.0, 1.0])))
    tangent, uv_used = _tangents(v, f, normal, name, tangents, uv, periodic_u)

    def constant_local(vec: np.ndarray) -> np.ndarray:
        return np.where(ok_c[:, None], _in_basis(const, vec), vec)  # Mosegaard & Sørensen 2005, eq. 7 (world if degenerate)

    def curvature_local(vec: np.ndarray, fallback: np.ndarray) -> np.ndarray:
        return np.where(ok_k[:, None], _in_basis(curv, vec), fallback)

    off_c, nrm_c, tan_c = constant_local(o), constant_local(normal), constant_local(tangent[:, :3])
    hand = tangent[:, 3:4]

    # curvature_ok (paper 3.5/3.6): all three node normals defined, Nc off T, Nc near N.
    defined = np.linalg.norm(node_n, axis=1) > MIN_NODE_NORMAL
    all_defined = defined[tri_nodes].all(axis=1)
    nc_raw = np.einsum("vi,vij->vj", w, node_n[tri_nodes])
    nc_len = np.linalg.norm(nc_raw, axis=1)
    nc = nc_raw / np.where(nc_len > 0, nc_len, 1.0)[:, None]
    sin_t = np.linalg.norm(np.cross(nc, const[:, 0]), axis=1)
    cos_n = row_dot(nc, const[:, 1])
    # Reasons, exclusive, in this order (the first that applies counts).
    no_normal = ok_c & ~all_defined
    parallel = ok_c & all_defined & ~(ok_k & (sin_t > MIN_SIN_NC_T) & (nc_len > 0))
    disagree = ok_c & all_defined & ~parallel & (nc_len < MIN_NC_AGREEMENT)
    flipped = (ok_c & all_defined & ~parallel & ~disagree
               & ~(cos_n > math.cos(math.radians(MAX_NC_ANGLE_DEG))))
    curvature_ok = ok_c & ~(no_normal | parallel | disagree | flipped)

    dist = np.linalg.norm(o, axis=1)
    far_idx = np.flatnonzero(dist > far * spacing)
    degenerate_tris = np.flatnonzero(~tri_valid)
    report = BindingReport(
        vertex_count=len(v), triangle_count=len(corners), spacing=float(spacing), far=float(far),
        far_vertices=far_idx, far_distances=dist[far_idx], degenerate_triangles=degenerate_tris,
        degenerate_vertices=np.flatnonzero(~tri_valid[tri_id]),
        no_normal=int(no_normal.sum()), parallel=int(parallel.sum()), disagree=int(disagree.sum()),
        flipped=int(flipped.sum()),
        curvature_fallback=int((~curvature_ok).sum()),
        normal_fallback=int((~has_normal).sum()))
    return Binding(
        tri_nodes=tri_nodes, weights=w, offset_world=o,
        offset_constant=off_c, offset_curvature=curvature_local(o, off_c),
        normal_constant=nrm_c, normal_curvature=curvature_local(normal, nrm_c),
        tangent_constant=np.concatenate([tan_c, hand], axis=1),
        tangent_curvature=np.concatenate([curvature_local(tangent[:, :3], tan_c), hand], axis=1),
        normal_world=normal, tangent_world=tangent, uv=uv_used, curvature_ok=curvature_ok,
        distance=dist, report=report)
