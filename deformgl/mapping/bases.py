"""Triangle-basis mappings of a detailed mesh onto deforming nodes, float64 NumPy
(Mosegaard & Sørensen 2005, 3.3): the reference of the vertex shader
``shaders/render/mapped_mesh.vert``.

A vertex is bound to a triangle of nodes (p1, p2, p3) with weights w (Mosegaard & Sørensen 2005, eq. 4): its reference
point is ``r = sum w_i p_i`` and its offset ``o = v - r`` (eq. 5) is stored in a basis of the
triangle (Mosegaard & Sørensen 2005, eq. 7):

* constant basis (eq. 6): ``T = normalize(p2 - p1)``, ``Bt = normalize(p3 - p1)``,
  ``N = normalize(T x Bt)``, ``B = N x T``;
* curvature-corrected basis (Mosegaard & Sørensen 2005, eq. 8): ``Nc = normalize(sum w_i Na(i))`` from the nodes' eq. 3
  normals, ``Bc = normalize(Nc x T)``, ``Tc = Bc x Nc``.

Deformed (Mosegaard & Sørensen 2005, eq. 9): ``v' = r' + o_t.x T' + o_t.y N' + o_t.z B'`` in the basis of the deformed
nodes. A basis that cannot be built (collapsed triangle, normals summing to zero or parallel
to T) is *degenerate*: the vertex then keeps its offset in world space, ``v' = r' + o_world``
(a defined result instead of NaN). ``N`` is normalised, unlike the paper's Mosegaard & Sørensen 2005, eq. 6 where
``|T x Bt|`` is the sine of the corner angle, so that offsets keep their length.
"""

from __future__ import annotations

import numpy as np

#: A basis vector shorter than this (before normalising) makes the basis degenerate.
DEGENERATE = 1e-6

def _normalize(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors and a bool mask of those that were long enough to normalise."""
    length = np.linalg.norm(v, axis=-1, keepdims=True)
    ok = length[..., 0] > DEGENERATE
    return v / np.where(length > DEGENERATE, length, 1.0), ok


def constant_basis(p1: np.ndarray, p2: np.ndarray, p3: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mosegaard & Sørensen 2005, Eq. 6: rows (T, N, B) per triangle, shape (V, 3, 3), and a validity mask (V,)."""
    t, ok_t = _normalize(p2 - p1)
    bt, ok_b = _normalize(p3 - p1)
    n, ok_n = _normalize(np.cross(t, bt))
    b = np.cross(n, t)
    return np.stack([t, n, b], axis=1), ok_t & ok_b & ok_n


def curvature_basis(p1: np.ndarray, p2: np.ndarray, p3: np.ndarray, weights: np.ndarray,
                    normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mosegaard & Sørensen 2005, Eq. 8: rows (Tc, Nc, Bc), shape (V, 3, 3), from the weighted node normals (V, 3, 3)
    (zero vectors where a node has no normal), and a validity mask (V,)."""
    t, ok_t = _normalize(p2 - p1)
    nc, ok_n = _normalize(np.einsum("vi,vij->vj", weights, normals))
    bc, ok_b = _normalize(np.cross(nc, t))
    tc = np.cross(bc, nc)
    return np.stack([tc, nc, bc], axis=1), ok_t & ok_n & ok_b


def map_vertices(positions: np.ndarray, normals: np.ndarray, tri_nodes: np.ndarray, weights: np.ndarray,
                 local_offset: np.ndarray, world_offset: np.ndarray, use_curvature: np.ndarray,
                 vectors: tuple[tuple[np.ndarray, np.ndarray], ...] = ()) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
    """Mosegaard & Sørensen 2005, Eq. 9: deformed vertex positions (and vectors such as normals) from node positions.

    Args:
        positions: (N, 3) node positions now.
        normals: (N, 3) node Mosegaard & Sørensen 2005, eq. 3 unit normals now (zero where undefined).
        tri_nodes: (V, 3) node numbers of each vertex's triangle.
        weights: (V, 3) Mosegaard & Sørensen 2005, eq. 4 weights.
        local_offset: (V, 3) offset in the vertex's basis (eq. 7).
        world_offset: (V, 3) rest offset in world space, used where the basis is degenerate.
        use_curvature: (V,) bool, curvature-corrected basis (Mosegaard & Sørensen 2005, eq. 8) instead of constant (eq. 6).
        vectors: more vectors to carry along (normal, tangent), each as a pair
            ((V, 3) in the basis, (V, 3) in world space at rest, used where degenerate).

    Returns:
        (V, 3) positions and the carried vectors in world space.
    """
    p = positions[tri_nodes]                                   # (V, 3, 3)
    r = np.einsum("vi,vij->vj", weights, p)                    # Mosegaard & Sørensen 2005, eq. 4
    const, ok_c = constant_basis(p[:, 0], p[:, 1], p[:, 2])
    curv, ok_k = curvature_basis(p[:, 0], p[:, 1], p[:, 2], weights, normals[tri_nodes])
    frame = np.where(use_curvature[:, None, None], curv, const)
    ok = np.where(use_curvature, ok_k, ok_c)
    world = np.einsum("vk,vkj->vj", local_offset, frame)
    out = r + np.where(ok[:, None], world, world_offset)
    carried = tuple(np.where(ok[:, None], np.einsum("vk,vkj->vj", local, frame), rest)
                    for local, rest in vectors)
    return out, carried
