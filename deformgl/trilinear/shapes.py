"""Meshes the trilinear scenes are built from (trimesh): a UV sphere, a tube along x and the
grooved hall tile of Knuth, Kohlhammer & Kuijper, figure 9, each as a scene-graph
:class:`~deformgl.trilinear.graph_nodes.Geometry`.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import trimesh

from deformgl.trilinear.graph_nodes import Geometry


def uv_sphere(radius: float, segments: int, rings: int, name: str = "sphere") -> Geometry:
    """A UV sphere at the origin with ``2 * segments * (rings - 1)`` triangles."""
    theta = np.linspace(0.0, np.pi, rings + 1)[1:-1]
    phi = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    unit = np.concatenate([[[0.0, 0.0, 1.0]], ring, [[0.0, 0.0, -1.0]]])
    s = segments
    tris = [[0, 1 + (j + 1) % s, 1 + j] for j in range(s)]
    for i in range(rings - 2):
        for j in range(s):
            a, b = 1 + i * s + j, 1 + i * s + (j + 1) % s
            tris += [[a, b, a + s], [b, b + s, a + s]]
    last = len(unit) - 1
    base = 1 + (rings - 2) * s
    tris += [[last, base + j, base + (j + 1) % s] for j in range(s)]
    faces = np.array(tris)[:, [0, 2, 1]]  # counter-clockwise seen from outside
    return Geometry(unit * radius, unit, faces, name)


def tube(length: float, radius: float, *, sections: int = 12, rings: int = 16, name: str = "tube") -> Geometry:
    """A capped tube along x from 0 to ``length``, centred on y = z = 0, with ``rings`` vertex
    rings along its length so that a deformation bends it smoothly."""
    x = np.linspace(0.0, length, rings)
    a = np.linspace(0.0, 2.0 * np.pi, sections, endpoint=False)
    xx, aa = np.meshgrid(x, a, indexing="ij")
    side_n = np.stack([np.zeros_like(aa), np.cos(aa), np.sin(aa)], -1).reshape(-1, 3)
    side_v = np.stack([xx, radius * np.cos(aa), radius * np.sin(aa)], -1).reshape(-1, 3)
    tris = []
    for i in range(rings - 1):
        for j in range(sections):
            p, q = i * sections + j, i * sections + (j + 1) % sections
            tris += [[p, q, p + sections], [q, q + sections, p + sections]]
    verts: list[npt.ArrayLike] = [side_v]
    norms = [side_n]
    start = len(side_v)
    for end, sign in ((0.0, -1.0), (length, 1.0)):
        ring = np.stack([np.full(sections, end), radius * np.cos(a), radius * np.sin(a)], -1)
        verts += [[[end, 0.0, 0.0]], ring]
        norms += [np.tile([sign, 0.0, 0.0], (sections + 1, 1))]
        for j in range(sections):
            p, q = start + 1 + j, start + 1 + (j + 1) % sections
            tris.append([start, q, p] if sign < 0 else [start, p, q])
        start += sections + 1
    return Geometry(np.concatenate(verts), np.concatenate(norms), np.array(tris), name)


def hall_tile(*, resolution: int = 40, name: str = "tile") -> Geometry:
    """The figure 9 tile over [0, 1]^2 (z up), made with trimesh: a floor with a groove along its
    border and a raised ring, and a revolved column with base and capital at its centre."""
    n = resolution
    s = np.linspace(0.0, 1.0, n + 1)
    x, y = np.meshgrid(s, s, indexing="ij")
    edge = np.minimum(np.minimum(x, 1 - x), np.minimum(y, 1 - y))
    r = np.hypot(x - 0.5, y - 0.5)
    z = 0.05 - 0.03 * (edge < 0.05) + 0.025 * np.exp(-((r - 0.3) / 0.035) ** 2)
    verts = np.stack([x, y, z], -1).reshape(-1, 3)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    floor = trimesh.Trimesh(verts, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]), process=False)
    profile = [[0.0, 0.0], [0.12, 0.0], [0.12, 0.04], [0.08, 0.06], [0.07, 0.12], [0.065, 0.2], [0.062, 0.28],
               [0.065, 0.33], [0.1, 0.36], [0.11, 0.4], [0.0, 0.4]]
    column = trimesh.creation.revolve(profile, sections=20)
    column.apply_translation([0.5, 0.5, 0.05])
    mesh = trimesh.util.concatenate([floor, column])
    return Geometry.from_trimesh(mesh, name)
