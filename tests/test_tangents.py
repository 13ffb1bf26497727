"""Tests for :mod:`deformgl.mapping.tangents`: vertex normals, UV tangents, procedural UVs and detail map."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from deformgl.mapping.tangents import (
    any_orthogonal,
    orthonormalize_tangents,
    procedural_normal_map,
    procedural_uv,
    vertex_normals,
    vertex_tangents,
)


def plane(n: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """A unit square in the z = 0 plane, n x n vertices, faces wound counter-clockwise (+z)."""
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n), indexing="xy")
    vertices = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1)
    i = np.arange(n - 1)
    a = (i[None, :] + n * i[:, None]).ravel()
    faces = np.concatenate([np.stack([a, a + 1, a + n + 1], 1), np.stack([a, a + n + 1, a + n], 1)])
    return vertices, faces


def rotation(seed: int) -> np.ndarray:
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def cylinder(axis_rotation: np.ndarray, sections: int = 48, rings: int = 9) -> trimesh.Trimesh:
    """An open tube (radius 1, length 8, no caps) along the rotated z axis, centred at (1, 2, 3),
    faces wound outwards."""
    angle = 2 * np.pi * np.arange(sections) / sections + 0.1
    z = np.linspace(-4.0, 4.0, rings)
    local = np.stack([np.tile(np.cos(angle), rings), np.tile(np.sin(angle), rings),
                      np.repeat(z, sections)], axis=1)
    j, k = np.meshgrid(np.arange(sections), np.arange(rings - 1), indexing="xy")
    a = (k * sections + j).ravel()
    b = (k * sections + (j + 1) % sections).ravel()
    faces = np.concatenate([np.stack([a, b, b + sections], 1), np.stack([a, b + sections, a + sections], 1)])
    return trimesh.Trimesh(local @ axis_rotation.T + [1.0, 2.0, 3.0], faces, process=False)


def test_plane_normals_point_up_and_are_unit():
    v, f = plane()
    n, ok = vertex_normals(v, f)
    assert ok.all()
    np.testing.assert_allclose(n, np.tile([0.0, 0.0, 1.0], (len(v), 1)), atol=1e-15)


def test_vertex_normals_are_area_weighted():
    # Vertex 0 is shared by a big face in the z=0 plane (area 2) and a small one in x=0 (area 0.5).
    v = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [0, 0, 1], [0, 1, 0.0]])
    f = np.array([[0, 1, 2], [0, 3, 4]])
    n, ok = vertex_normals(v, f)
    expected = np.array([0.0, 0.0, 2.0]) * 2 + np.array([-0.5, 0.0, 0.0]) * 2  # cross = 2 * area * n
    np.testing.assert_allclose(n[0], expected / np.linalg.norm(expected), atol=1e-15)
    assert ok[:5].all()


def test_vertex_normals_undefined_for_unused_and_cancelling_vertices():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5.0]])
    f = np.array([[0, 1, 2], [0, 2, 1]])  # a double-sided triangle: the normals cancel
    n, ok = vertex_normals(v, f)
    assert not ok.any()
    assert (n == 0).all()


@pytest.mark.parametrize("matrix", [np.eye(2), np.array([[2.0, 0.5], [-0.3, 1.5]]),
                                    np.array([[0.0, 1.0], [1.0, 0.0]]), np.array([[-1.0, 0.0], [0.0, 1.0]]),
                                    np.array([[0.7, -1.1], [0.4, 0.9]])])
def test_affine_uv_gives_dp_du_and_handedness(matrix):
    v, f = plane()
    uv = v[:, :2] @ matrix.T + [0.25, -3.0]
    t = vertex_tangents(v, f, np.tile([0.0, 0.0, 1.0], (len(v), 1)), uv)
    inverse = np.linalg.inv(matrix)        # columns: dP/du and dP/dv in the plane
    dp_du = np.array([*inverse[:, 0], 0.0])
    np.testing.assert_allclose(t[:, :3], np.tile(dp_du / np.linalg.norm(dp_du), (len(v), 1)), atol=1e-12)
    np.testing.assert_array_equal(t[:, 3], np.sign(np.linalg.det(matrix)))


def test_mirrored_uv_flips_handedness():
    v, f = plane()
    n = np.tile([0.0, 0.0, 1.0], (len(v), 1))
    straight = vertex_tangents(v, f, n, v[:, :2])
    mirrored = vertex_tangents(v, f, n, v[:, :2] * [-1.0, 1.0])
    np.testing.assert_allclose(straight[:, :3], [[1.0, 0.0, 0.0]] * len(v), atol=1e-12)
    assert (straight[:, 3] == 1.0).all()
    np.testing.assert_allclose(mirrored[:, :3], [[-1.0, 0.0, 0.0]] * len(v), atol=1e-12)
    assert (mirrored[:, 3] == -1.0).all()
    # The bitangent w (n x t) follows +v in both cases.
    for t in (straight, mirrored):
        b = t[:, 3:4] * np.cross(n, t[:, :3])
        np.testing.assert_allclose(b, [[0.0, 1.0, 0.0]] * len(v), atol=1e-12)


def test_tangents_orthogonal_to_normals_and_unit():
    mesh = trimesh.creation.icosphere(subdivisions=3)
    n, ok = vertex_normals(mesh.vertices, mesh.faces)
    assert ok.all()
    uv = procedural_uv(mesh.vertices, n)
    t = vertex_tangents(mesh.vertices, mesh.faces, n, uv, periodic_u=True)
    assert np.abs(np.einsum("ij,ij->i", t[:, :3], n)).max() < 1e-12
    np.testing.assert_allclose(np.linalg.norm(t[:, :3], axis=1), 1.0, atol=1e-12)
    assert set(np.unique(t[:, 3])) <= {-1.0, 1.0}


def test_degenerate_uv_gives_unit_orthogonal_tangent_and_plus_one():
    v, f = plane()
    n = np.tile([0.0, 0.0, 1.0], (len(v), 1))
    t = vertex_tangents(v, f, n, np.zeros((len(v), 2)))
    np.testing.assert_allclose(np.linalg.norm(t[:, :3], axis=1), 1.0)
    assert np.abs(t[:, 2]).max() < 1e-15
    assert (t[:, 3] == 1.0).all()


def test_any_orthogonal_and_orthonormalize():
    n = np.array([[0, 0, 1.0], [1, 0, 0], [0.6, 0.8, 0], [0, 0, 0]])
    o = any_orthogonal(n)
    np.testing.assert_allclose(np.linalg.norm(o, axis=1), 1.0)
    assert np.abs(np.einsum("ij,ij->i", o, n)).max() < 1e-15
    t = orthonormalize_tangents(n[:3], np.array([[1.0, 0, 1], [2.0, 0, 0], [0, 0, 3.0]]))
    np.testing.assert_allclose(t[0], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(np.einsum("ij,ij->i", t, n[:3]), 0.0, atol=1e-15)  # parallel -> fallback
    np.testing.assert_allclose(t[2], [0.0, 0.0, 1.0])


@pytest.mark.parametrize("seed", [0, 1])
def test_procedural_uv_is_cylindrical_about_the_longest_axis(seed):
    rot = rotation(seed)
    mesh = cylinder(rot)
    n, _ = vertex_normals(mesh.vertices, mesh.faces)
    uv = procedural_uv(mesh.vertices, n)
    assert (uv[:, 0] >= 0).all() and (uv[:, 0] < 1).all()
    height = (mesh.vertices - [1.0, 2.0, 3.0]) @ rot[:, 2]
    # v runs along the tube's axis (either direction), one unit per circumference 2 pi.
    slope = np.polyfit(height, uv[:, 1], 1)[0]
    assert abs(abs(slope) - 1 / (2 * np.pi)) < 1e-9
    assert uv[:, 1].min() == pytest.approx(0.0, abs=1e-12)
    # u is the angle: one ring of vertices covers [0, 1) evenly.
    ring = np.abs(height - height.max()) < 1e-9
    steps = np.diff(np.sort(uv[ring, 0]))
    np.testing.assert_allclose(steps, 1 / 48, atol=1e-9)


def test_periodic_u_fixes_the_seam_tangents():
    rot = rotation(3)
    mesh = cylinder(rot)
    n, _ = vertex_normals(mesh.vertices, mesh.faces)
    uv = procedural_uv(mesh.vertices, n)
    d = mesh.vertices - [1.0, 2.0, 3.0]
    radial = d - np.outer(d @ rot[:, 2], rot[:, 2])
    around = np.cross(rot[:, 2], radial)
    around /= np.linalg.norm(around, axis=1, keepdims=True)
    wrapped = vertex_tangents(mesh.vertices, mesh.faces, n, uv, periodic_u=True)
    align = np.abs(np.einsum("ij,ij->i", wrapped[:, :3], around))
    assert align.min() > 0.99
    # Without wrapping, the faces across the seam spoil the tangents of the seam vertices.
    plain = vertex_tangents(mesh.vertices, mesh.faces, n, uv)
    assert np.abs(np.einsum("ij,ij->i", plain[:, :3], around)).min() < 0.9


def decode(image: np.ndarray) -> np.ndarray:
    return image.astype(np.float64) / 255.0 * 2.0 - 1.0


@pytest.mark.parametrize("size", [128, 256])
def test_normal_map_is_tileable(size):
    """Across the tile edge (last row/column to first) the map changes like between neighbours."""
    img = procedural_normal_map(size).astype(np.int64)
    assert img.shape == (size, size, 3)
    for axis in (0, 1):
        inner = np.abs(np.diff(img, axis=axis))
        wrap = np.abs(img.take(0, axis=axis) - img.take(-1, axis=axis))
        assert wrap.max() <= inner.max() + 2                 # +2: rounding to 8 bits
        assert wrap.mean() <= 1.25 * inner.mean() + 0.5
        assert inner.mean() > 2  # not flat: the continuity check means something


def test_normal_map_decodes_to_unit_vectors_pointing_up():
    img = procedural_normal_map()
    assert img.dtype == np.uint8 and img.shape == (256, 256, 3)
    n = decode(img)
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=0.02)
    assert (n[..., 2] > 0.3).all()
    assert n[..., 0].std() > 0.05 and n[..., 1].std() > 0.05
    assert abs(n[..., 0].mean()) < 0.02 and abs(n[..., 1].mean()) < 0.02  # bumps, no overall tilt


def test_normal_map_strength_zero_is_flat_and_bad_arguments_raise():
    flat = procedural_normal_map(8, strength=0.0)
    assert (flat == [128, 128, 255]).all()
    with pytest.raises(ValueError, match="size"):
        procedural_normal_map(0)
    with pytest.raises(ValueError, match="strength"):
        procedural_normal_map(8, strength=-1.0)
