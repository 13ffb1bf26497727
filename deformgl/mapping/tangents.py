"""Per-vertex shading frames of a detailed mesh: normals, tangents, procedural UVs, a detail map.

Mosegaard & Sørensen 2005, 3.3.4: normal mapping on the deformed mesh needs, per vertex, a
normal and a tangent expressed in the triangle basis; this module computes them at rest, in
world space (:mod:`deformgl.mapping.binding` then expresses them in the bases of Mosegaard & Sørensen 2005, eq. 6 and eq. 8).

* :func:`vertex_normals`: area-weighted vertex normals.
* :func:`vertex_tangents`: Lengyel's per-vertex tangents from texture coordinates (derivative
  of the position along ``u``), Gram-Schmidt orthogonalised against the normal, with the
  handedness ``w`` so that the bitangent is ``w * (n x t)``.
* :func:`procedural_uv`: a cylindrical parametrisation for meshes without texture
  coordinates, so that :func:`procedural_normal_map` (a tileable detail pattern) can be applied.
"""

from __future__ import annotations

import numpy as np

#: An accumulated tangent shorter than this fraction of the total length of its per-face
#: contributions (after removing the normal component) has no reliable direction.
DEGENERATE_TANGENT = 1e-6
#: Texture coordinates whose parametrisation has a seam are periodic with this period in u.
U_PERIOD = 1.0


def _accumulate(faces: np.ndarray, per_face: np.ndarray, count: int) -> np.ndarray:
    """Sum a per-face value, (F,) or (F, C), into each of the face's three vertices."""
    idx = faces.reshape(-1)
    rep = np.repeat(per_face, 3, axis=0)
    if rep.ndim == 1:
        return np.bincount(idx, weights=rep, minlength=count)
    return np.stack([np.bincount(idx, weights=rep[:, k], minlength=count)
                     for k in range(rep.shape[1])], axis=1)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Area-weighted vertex normals: the normalised sum of the adjacent faces' cross products.

    The cross product ``(v1 - v0) x (v2 - v0)`` of a face is twice its area times its unit
    normal, so summing it weights every face by its area. Faces are wound counter-clockwise seen
    from outside.

    Args:
        vertices: (V, 3) positions.
        faces: (F, 3) vertex indices.

    Returns:
        (V, 3) unit normals (zero where undefined) and a (V,) bool mask of the defined ones: a
        vertex used by no face, or only by faces of zero area, has no normal.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    tri = v[f]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    total = _accumulate(f, cross, len(v))
    length = np.linalg.norm(total, axis=1)
    scale = _accumulate(f, np.linalg.norm(cross, axis=1), len(v))
    ok = (length > 1e-12 * scale) & (length > 0)
    return np.where(ok[:, None], total / np.where(ok, length, 1.0)[:, None], 0.0), ok


def any_orthogonal(normals: np.ndarray) -> np.ndarray:
    """A unit vector orthogonal to each normal (V, 3); +x for a zero normal.

    Crosses the normal with the coordinate axis it is least aligned with, so the result is
    always well conditioned.
    """
    n = np.asarray(normals, dtype=np.float64)
    axis = np.eye(3)[np.argmin(np.abs(n), axis=1)]
    t = np.cross(n, axis)
    length = np.linalg.norm(t, axis=1, keepdims=True)
    return np.where(length > 0, t / np.where(length > 0, length, 1.0), np.array([1.0, 0.0, 0.0]))


def _gram_schmidt(n: np.ndarray, t: np.ndarray, scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit tangents orthogonal to ``n`` and a mask of those that were usable (see below)."""
    ortho = t - n * np.sum(n * t, axis=1, keepdims=True)
    length = np.linalg.norm(ortho, axis=1)
    ok = (length > DEGENERATE_TANGENT * scale) & (length > 0)
    unit = ortho / np.where(ok, length, 1.0)[:, None]
    return np.where(ok[:, None], unit, any_orthogonal(n)), ok


def orthonormalize_tangents(normals: np.ndarray, tangents: np.ndarray) -> np.ndarray:
    """Gram-Schmidt tangents (V, 3) against unit normals (V, 3); returns (V, 3) unit tangents.

    A tangent whose component orthogonal to the normal is shorter than
    :data:`DEGENERATE_TANGENT` times its own length (parallel to the normal, or zero) is replaced
    by :func:`any_orthogonal` of the normal.
    """
    n = np.asarray(normals, dtype=np.float64)
    t = np.asarray(tangents, dtype=np.float64)
    return _gram_schmidt(n, t, np.linalg.norm(t, axis=1))[0]


def vertex_tangents(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray, uv: np.ndarray,
                    *, periodic_u: bool = False) -> np.ndarray:
    """Per-vertex tangents from texture coordinates (Lengyel's method), with handedness.

    For each face with edges ``e1 = p1 - p0``, ``e2 = p2 - p0`` and texture-coordinate edges
    ``(du1, dv1)``, ``(du2, dv2)``, the derivatives of the position along u and v are
    ``dP/du = (dv2 e1 - dv1 e2) / det`` and ``dP/dv = (du1 e2 - du2 e1) / det`` with
    ``det = du1 dv2 - du2 dv1``. They are summed into the face's vertices weighted by the face's
    texture-space area ``|det| / 2`` (so a face with a collapsed texture mapping contributes
    nothing instead of a huge vector). Each vertex tangent is the sum of ``dP/du``, Gram-Schmidt
    orthogonalised against the normal and normalised; ``w = -1`` where ``(n x t) . dP/dv < 0``
    (mirrored texture mapping), else ``+1``, so the bitangent is ``w * (n x t)``. A vertex without
    usable derivatives gets any unit vector orthogonal to its normal, ``w = +1``.

    Args:
        vertices: (V, 3) positions.
        faces: (F, 3) vertex indices.
        normals: (V, 3) unit vertex normals.
        uv: (V, 2) texture coordinates.
        periodic_u: u is periodic with period :data:`U_PERIOD` (a parametrisation with a seam,
            like :func:`procedural_uv`): a face's u differences are wrapped into
            ``[-1/2, 1/2)`` so faces across the seam get the right derivatives.

    Returns:
        (V, 4) float64: xyz the unit tangent, w the handedness (+1 or -1).
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    n = np.asarray(normals, dtype=np.float64)
    t_uv = np.asarray(uv, dtype=np.float64)[f]                 # (F, 3, 2)
    tri = v[f]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    d1, d2 = t_uv[:, 1] - t_uv[:, 0], t_uv[:, 2] - t_uv[:, 0]
    if periodic_u:
        d1[:, 0] -= U_PERIOD * np.floor(d1[:, 0] / U_PERIOD + 0.5)
        d2[:, 0] -= U_PERIOD * np.floor(d2[:, 0] / U_PERIOD + 0.5)
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    sign = np.sign(det)[:, None]
    # dP/du * |det| and dP/dv * |det|: the texture-area weighted derivatives.
    s_dir = (d2[:, 1:2] * e1 - d1[:, 1:2] * e2) * sign
    t_dir = (d1[:, 0:1] * e2 - d2[:, 0:1] * e1) * sign
    s_sum = _accumulate(f, s_dir, len(v))
    t_sum = _accumulate(f, t_dir, len(v))
    scale = _accumulate(f, np.linalg.norm(s_dir, axis=1), len(v))
    tangent, usable = _gram_schmidt(n, s_sum, scale)
    handed = np.sum(np.cross(n, tangent) * t_sum, axis=1)
    w = np.where(usable & (handed < 0.0), -1.0, 1.0)
    return np.concatenate([tangent, w[:, None]], axis=1)


def _principal_axes(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Centre and unit axes (e1, e2, axis) of a point set: axis along the largest spread.

    Signs are fixed (largest-magnitude component positive) so the result does not depend on the
    eigen-solver; ``(e1, e2, axis)`` is right-handed.
    """
    centre = points.mean(axis=0)
    d = points - centre
    _, vecs = np.linalg.eigh(d.T @ d)                          # ascending eigenvalues
    axis, e1 = vecs[:, 2], vecs[:, 1]
    axis = axis * np.sign(axis[np.argmax(np.abs(axis))])
    e1 = e1 * np.sign(e1[np.argmax(np.abs(e1))])
    return centre, e1, np.cross(axis, e1), axis


def procedural_uv(vertices: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Cylindrical texture coordinates around the mesh's longest principal axis.

    The axis is the principal direction of largest spread of the vertices through their mean;
    ``e1`` is the second principal direction and ``e2 = axis x e1``. With ``(x, y, z)`` the
    vertex in the frame ``(e1, e2, axis)`` about the mean:

    * ``u = atan2(y, x) / (2 pi) + 1/2`` in ``[0, 1)``;
    * ``v = (z - z_min) / (2 pi r_mean)``, with ``r_mean`` the mean distance from the axis, so
      one unit of v is one mean circumference: texels are square at the mean radius.

    A vertex on the axis (distance below 1e-9 of the mesh's extent) takes its angle from its
    normal projected onto the ``(e1, e2)`` plane instead (the end caps of an elongated shape).

    Seam: u jumps from 1 to 0 across the half-plane through the axis in the direction ``-e1``
    (angle +-pi). Faces straddling it have u differences near +-1; :func:`vertex_tangents`
    with ``periodic_u=True`` wraps them, and a renderer must wrap them too (or accept a thin
    strip where the whole texture is squeezed into one face; the detail map is tileable, so
    the pattern itself has no seam).

    Args:
        vertices: (V, 3) positions.
        normals: (V, 3) unit vertex normals (zero where undefined).

    Returns:
        (V, 2) float64 texture coordinates.
    """
    v = np.asarray(vertices, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    centre, e1, e2, axis = _principal_axes(v)
    d = v - centre
    x, y, z = d @ e1, d @ e2, d @ axis
    r = np.hypot(x, y)
    extent = float(np.ptp(v, axis=0).max()) if len(v) else 0.0
    on_axis = r <= 1e-9 * extent
    x = np.where(on_axis, n @ e1, x)
    y = np.where(on_axis, n @ e2, y)
    u = np.arctan2(y, x) / (2.0 * np.pi) + 0.5
    u = np.where(u >= 1.0, 0.0, u)
    r_mean = float(r.mean()) if len(v) else 0.0
    length = float(np.ptp(z)) if len(v) else 0.0
    denom = 2.0 * np.pi * r_mean if r_mean > 0 else (length if length > 0 else 1.0)
    return np.stack([u, (z - (z.min() if len(v) else 0.0)) / denom], axis=1)


#: Height components of :func:`procedural_normal_map`: (cycles along u, cycles along v,
#: amplitude, phase). Integer frequencies make the height field periodic over one tile. The
#: first three (magnitudes 8, 8.9, 8.9, at 0/63/117 degrees) add up to a near-hexagonal field of
#: round bumps ("scales"); the next three repeat it three times finer and weaker; the last two
#: are a slow irregular undulation so the repetition is less obvious.
DETAIL_WAVES: tuple[tuple[int, int, float, float], ...] = (
    (8, 0, 1.0, 0.0), (4, 8, 1.0, 0.0), (-4, 8, 1.0, 0.0),
    (24, 0, 0.18, 0.7), (12, 24, 0.18, 0.7), (-12, 24, 0.18, 0.7),
    (3, 2, 0.35, 1.3), (-2, 5, 0.25, 2.1),
)


def procedural_normal_map(size: int = 256, *, strength: float = 0.5) -> np.ndarray:
    """A tileable tangent-space normal map of a bump ("scales") pattern, RGB8.

    The height is ``h(u, v) = sum A cos(2 pi (fu u + fv v) + phase)`` over
    :data:`DETAIL_WAVES`; the normal is ``normalize(-s dh/du, -s dh/dv, 1)`` with
    ``s = strength / (2 pi * 8)``, so ``strength`` is the slope of one unit-amplitude wave of the
    main pattern. Texel ``[j, i]`` is sampled at ``u = (i + 1/2) / size``,
    ``v = (j + 1/2) / size`` (row 0 is the first row uploaded, t near 0), x along the tangent
    (u), y along the bitangent (v), z up; encoded as ``round((n * 0.5 + 0.5) * 255)``.

    Args:
        size: width and height in texels (>= 1).
        strength: bump slope scale (>= 0).

    Returns:
        (size, size, 3) uint8.

    Raises:
        ValueError: size < 1 or strength negative or not finite.
    """
    if int(size) != size or size < 1:
        raise ValueError(f"normal map size must be a positive integer, got {size!r}")
    if not (np.isfinite(strength) and strength >= 0):
        raise ValueError(f"normal map strength must be finite and >= 0, got {strength!r}")
    c = (np.arange(int(size)) + 0.5) / size
    u, v = np.meshgrid(c, c, indexing="xy")                     # u varies along columns
    dh_du = np.zeros_like(u)
    dh_dv = np.zeros_like(u)
    for fu, fv, amp, phase in DETAIL_WAVES:
        s = -amp * 2.0 * np.pi * np.sin(2.0 * np.pi * (fu * u + fv * v) + phase)
        dh_du += fu * s
        dh_dv += fv * s
    k = strength / (2.0 * np.pi * 8.0)
    n = np.stack([-k * dh_du, -k * dh_dv, np.ones_like(u)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return np.rint(np.clip(n * 0.5 + 0.5, 0.0, 1.0) * 255.0).astype(np.uint8)
