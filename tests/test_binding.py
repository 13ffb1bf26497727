"""Tests for :mod:`deformgl.mapping.binding`: binding a detailed mesh to the node surface (no GL).

Rest reproduction and rigid motion are checked through :func:`deformgl.mapping.map_vertices`,
the float64 forward mapping the binding inverts; closest points against trimesh's per-triangle
closest point (brute force over every triangle).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import pytest
import trimesh
from trimesh.triangles import closest_point as triangle_closest_point

from studies import binding_speed as bench_bd
from deformgl.mapping import binding as bd
from deformgl.mapping import binding_cache as cache
from deformgl.mapping import closest
from deformgl.mapping.binding import Binding, bind
from deformgl.sim.normals import rest_normals
from deformgl.mapping.binding_cache import binding_key, load_binding, save_binding
from deformgl.mapping.closest import closest_on_triangles
from deformgl.errors import InputError
from deformgl.grid.nodes import NodeGrid
from deformgl.mapping.bases import map_vertices
from deformgl.grid.meshio import load_mesh
from deformgl.grid.surface import GridSurface, grid_surface
from deformgl.mapping.tangents import procedural_uv, vertex_tangents
from deformgl.grid.voxelize import voxelize

ASSETS = Path(__file__).resolve().parents[1] / "scenes" / "assets"
DRAGON = ASSETS / "dragon_vrip_res4.ply.gz"
TOL = 1e-9  # of the bounding-box diagonal, float64


@dataclass
class Case:
    mesh: trimesh.Trimesh
    grid: NodeGrid
    surface: GridSurface
    normals: np.ndarray
    binding: Binding

    @property
    def diag(self) -> float:
        return float(np.linalg.norm(np.ptp(self.mesh.vertices, axis=0)))

    @property
    def positions(self) -> np.ndarray:
        return self.grid.rest_positions


def make_case(mesh: trimesh.Trimesh, nodes_along_longest: int) -> Case:
    vox = voxelize(mesh, nodes_along_longest=nodes_along_longest)
    grid = NodeGrid(np.asarray(vox.origin), float(vox.spacing), np.asarray(vox.occupied))
    surface = grid_surface(grid)
    normals = rest_normals(grid)
    b = bind(mesh.vertices, mesh.faces, grid.rest_positions, normals, surface, spacing=grid.spacing)
    return Case(mesh, grid, surface, normals, b)


@pytest.fixture(scope="module")
def sphere() -> Case:
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    mesh = trimesh.Trimesh(mesh.vertices + [0.3, -0.2, 0.1], mesh.faces, process=False)
    return make_case(mesh, 7)


@pytest.fixture(scope="module")
def dragon() -> Case:
    """The paper's test: the dragon (about 10,000 faces) on a handful of nodes."""
    return make_case(load_mesh(DRAGON), 4)


@pytest.fixture(scope="module")
def dragon_fine() -> Case:
    return make_case(load_mesh(DRAGON), 24)


CASES = ["sphere", "dragon"]


def mapped(b: Binding, positions: np.ndarray, normals: np.ndarray, use: np.ndarray):
    """map_vertices with the binding's per-basis data selected by ``use`` (curvature where True)."""
    pick = lambda curv, const: np.where(use[:, None], curv, const)  # noqa: E731
    vectors = ((pick(b.normal_curvature, b.normal_constant), b.normal_world),
               (pick(b.tangent_curvature, b.tangent_constant)[:, :3], b.tangent_world[:, :3]))
    out, (n, t) = map_vertices(positions, normals, b.tri_nodes, b.weights,
                               pick(b.offset_curvature, b.offset_constant), b.offset_world, use, vectors)
    return out, n, t


def modes(b: Binding) -> dict[str, np.ndarray]:
    v = b.vertex_count
    return {"constant": np.zeros(v, bool), "curvature": np.ones(v, bool), "auto": b.curvature_ok}


def brute_force_distance(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Distance from each point to the nearest of all triangles, via trimesh's per-triangle test."""
    out = np.empty(len(points))
    for i, p in enumerate(points):
        q = triangle_closest_point(corners, np.repeat(p[None], len(corners), axis=0))
        out[i] = np.linalg.norm(q - p, axis=1).min()
    return out


def random_rotation(seed: int) -> np.ndarray:
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


# --- Fixtures are what the task describes -------------------------------------------------------


def test_dragon_is_on_a_very_coarse_grid(dragon):
    assert 18 <= dragon.grid.count <= 30
    assert len(dragon.mesh.faces) > 10_000


# --- Rest reproduction ------------------------------------------------------------------------------


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("mode", ["constant", "curvature", "auto"])
def test_rest_reproduces_vertices_normals_tangents(case, mode, request):
    c: Case = request.getfixturevalue(case)
    b = c.binding
    out, n, t = mapped(b, c.positions, c.normals, modes(b)[mode])
    assert np.abs(out - c.mesh.vertices).max() <= TOL * c.diag
    assert np.abs(n - b.normal_world).max() <= TOL
    assert np.abs(t - b.tangent_world[:, :3]).max() <= TOL


@pytest.mark.parametrize("case", CASES)
def test_world_normals_and_tangents_are_unit_and_orthogonal(case, request):
    b = request.getfixturevalue(case).binding
    np.testing.assert_allclose(np.linalg.norm(b.normal_world, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(b.tangent_world[:, :3], axis=1), 1.0, atol=1e-12)
    assert np.abs(np.einsum("ij,ij->i", b.normal_world, b.tangent_world[:, :3])).max() < 1e-12
    assert set(np.unique(b.tangent_world[:, 3])) <= {-1.0, 1.0}
    np.testing.assert_array_equal(b.tangent_constant[:, 3], b.tangent_world[:, 3])
    np.testing.assert_array_equal(b.tangent_curvature[:, 3], b.tangent_world[:, 3])


def test_world_normals_are_area_weighted_mesh_normals(sphere):
    c = sphere
    cross = np.cross(*(c.mesh.triangles[:, k] - c.mesh.triangles[:, 0] for k in (1, 2)))
    total = np.zeros_like(c.mesh.vertices)
    for k in range(3):
        np.add.at(total, c.mesh.faces[:, k], cross)
    expected = total / np.linalg.norm(total, axis=1, keepdims=True)
    np.testing.assert_allclose(c.binding.normal_world, expected, atol=1e-14)
    radial = c.mesh.vertices - [0.3, -0.2, 0.1]
    assert (np.einsum("ij,ij->i", expected, radial) > 0.99).all()
    assert c.binding.report.normal_fallback == 0


def test_vertex_without_faces_gets_its_triangle_normal(sphere):
    c = sphere
    verts = np.concatenate([c.mesh.vertices, [[0.35, -0.15, 1.3]]])  # used by no face
    b = bind(verts, c.mesh.faces, c.positions, c.normals, c.surface, spacing=c.grid.spacing)
    assert b.report.normal_fallback == 1
    p = c.positions[b.tri_nodes[-1]]
    n = np.cross(p[1] - p[0], p[2] - p[0])
    np.testing.assert_allclose(b.normal_world[-1], n / np.linalg.norm(n), atol=1e-15)
    np.testing.assert_allclose(b.normal_constant[-1], [0.0, 1.0, 0.0], atol=1e-15)
    assert any("1 vertices have no mesh normal" in line for line in b.report.lines())


def test_constant_offsets_are_components_along_t_n_b(sphere):
    b, x = sphere.binding, sphere.positions
    p = x[b.tri_nodes]
    t = p[:, 1] - p[:, 0]
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    n = np.cross(t, p[:, 2] - p[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    np.testing.assert_allclose(b.offset_constant[:, 0], np.einsum("ij,ij->i", b.offset_world, t), atol=1e-14)
    np.testing.assert_allclose(b.offset_constant[:, 1], np.einsum("ij,ij->i", b.offset_world, n), atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(b.offset_constant, axis=1), b.distance, atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(b.offset_curvature, axis=1), b.distance, atol=1e-14)


# --- Weights, reference points, distances ---------------------------------------------------------------


@pytest.mark.parametrize("case", CASES)
def test_weights_sum_to_one_and_lie_in_unit_interval(case, request):
    w = request.getfixturevalue(case).binding.weights
    assert w.min() >= 0.0 and w.max() <= 1.0
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-15)


@pytest.mark.parametrize("case", CASES)
def test_reference_points_lie_on_their_surface_triangles(case, request):
    c: Case = request.getfixturevalue(case)
    b = c.binding
    surface_tris = {tuple(t) for t in c.surface.nodes[c.surface.triangles]}
    assert {tuple(t) for t in b.tri_nodes} <= surface_tris  # winding kept
    corners = c.positions[b.tri_nodes]
    r = c.mesh.vertices - b.offset_world
    on = triangle_closest_point(corners, r)
    assert np.abs(on - r).max() <= 1e-12 * c.diag
    np.testing.assert_allclose(r, np.einsum("vi,vij->vj", b.weights, corners), atol=1e-15 * c.diag)


@pytest.mark.parametrize("case", CASES + ["dragon_fine"])
def test_offsets_are_distances_to_the_closest_triangle(case, request):
    c: Case = request.getfixturevalue(case)
    b = c.binding
    corners = c.positions[c.surface.nodes[c.surface.triangles]]
    pick = np.random.default_rng(5).choice(len(c.mesh.vertices), size=min(400, len(c.mesh.vertices)),
                                           replace=False)
    exact = brute_force_distance(c.mesh.vertices[pick], corners)
    np.testing.assert_allclose(b.distance[pick], exact, rtol=0, atol=1e-12 * c.diag)
    np.testing.assert_allclose(b.distance, np.linalg.norm(b.offset_world, axis=1), rtol=0, atol=0)


def test_offsets_agree_with_trimesh_proximity(dragon_fine):
    """trimesh.proximity.closest_point, over all vertices. It treats squared distances within
    tol.merge (1e-8) of each other as ties, so at the dragon's scale it sometimes picks a slightly
    farther triangle: ours is never farther, and equal within that tolerance."""
    c = dragon_fine
    node_mesh = trimesh.Trimesh(c.positions[c.surface.nodes], c.surface.triangles, process=False)
    _, dist, _ = trimesh.proximity.closest_point(node_mesh, c.mesh.vertices)
    ours = c.binding.distance
    assert (ours <= dist + 1e-12).all()
    assert (dist**2 - ours**2).max() <= 1e-8


def random_triangles_and_points(seed: int = 7):
    """Varied triangles (every third a sliver), each with 3000 points around it."""
    rng = np.random.default_rng(seed)
    for shape in range(12):
        corners = rng.normal(size=(1, 3, 3))
        if shape % 3 == 1:
            corners[0, 2] = corners[0, 0] + 0.5 * (corners[0, 1] - corners[0, 0]) + 0.02
        yield corners, corners[0].mean(axis=0) + rng.normal(size=(3000, 3)) * 2


@pytest.mark.parametrize("scale", [1.0, 1e3])
def test_closest_point_on_one_triangle_matches_trimesh(scale):
    """Every Voronoi region (corners, edges, interior) of varied triangles, against trimesh
    (whose absolute tolerances on products of lengths make it unreliable at small scales)."""
    for corners, points in random_triangles_and_points():
        corners, points = corners * scale, points * scale
        tri, w = closest_on_triangles(points, corners, np.zeros(1, bool), corners[0])
        assert (tri == 0).all() and (w >= 0).all()
        np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-15)
        expected = triangle_closest_point(np.repeat(corners, len(points), axis=0), points)
        np.testing.assert_allclose(w @ corners[0], expected, rtol=0, atol=1e-12 * scale)


@pytest.mark.parametrize("scale", [1e-3, 1e-6])
def test_closest_point_is_scale_invariant(scale):
    for corners, points in random_triangles_and_points():
        _, w = closest_on_triangles(points, corners, np.zeros(1, bool), corners[0])
        _, ws = closest_on_triangles(points * scale, corners * scale, np.zeros(1, bool), corners[0] * scale)
        np.testing.assert_allclose(ws, w, rtol=0, atol=1e-9)


def test_blocks_of_candidate_pairs_give_the_same_binding(sphere, monkeypatch):
    monkeypatch.setattr(closest, "PAIR_BLOCK", 100)
    assert len(closest._block_bounds(np.full(50, 30), 100)) == 17  # 3 points (90 pairs) per block
    assert closest._block_bounds(np.array([500, 1, 1]), 100) == [(0, 1), (1, 3)]
    c = sphere
    b = bind(c.mesh.vertices, c.mesh.faces, c.positions, c.normals, c.surface, spacing=c.grid.spacing)
    assert_bindings_equal(b, c.binding)


def test_closest_on_triangles_handles_ties_and_degenerate_triangles():
    # Two triangles sharing the edge (0,0,0)-(1,0,0); a point above the edge is equidistant.
    corners = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[1, 0, 0], [0, 0, 0], [0, -1, 0]],
                        [[5, 5, 5], [5, 5, 5], [6, 5, 5]]], dtype=np.float64)
    points = np.array([[0.5, 0.0, 1.0], [5.5, 5.0, 6.0], [0.2, 0.3, -2.0]])
    degenerate = np.array([False, False, True])
    tri, w = closest_on_triangles(points, corners, degenerate, corners.reshape(-1, 3))
    np.testing.assert_array_equal(tri, [0, 2, 0])  # tie: the lower index
    np.testing.assert_allclose(np.einsum("vi,vij->vj", w, corners[tri]),
                               [[0.5, 0, 0], [5.5, 5, 5], [0.2, 0.3, 0]], atol=1e-15)
    assert np.isfinite(w).all() and (w >= 0).all()


# --- Rigid motion ------------------------------------------------------------------------------------


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("mode", ["constant", "curvature", "auto"])
def test_rigid_motion_of_the_nodes_moves_the_mesh_rigidly(case, mode, request):
    c: Case = request.getfixturevalue(case)
    b = c.binding
    rot, shift = random_rotation(11), np.array([0.7, -1.3, 2.1])
    out, n, t = mapped(b, c.positions @ rot.T + shift, c.normals @ rot.T, modes(b)[mode])
    assert np.abs(out - (c.mesh.vertices @ rot.T + shift)).max() <= TOL * c.diag
    assert np.abs(n - b.normal_world @ rot.T).max() <= TOL
    assert np.abs(t - b.tangent_world[:, :3] @ rot.T).max() <= TOL


def test_curvature_basis_differs_from_constant_when_bent(dragon):
    """The two bases are not the same thing: bending the nodes moves vertices differently."""
    b, x = dragon.binding, dragon.positions.copy()
    bend = x.copy()
    span = np.ptp(x[:, 0])
    bend[:, 1] += 0.3 * ((x[:, 0] - x[:, 0].min()) / span) ** 2 * span
    const, _, _ = mapped(b, bend, dragon.normals, modes(b)["constant"])
    curv, _, _ = mapped(b, bend, dragon.normals, modes(b)["curvature"])
    assert np.abs(const - curv).max() > 1e-3 * dragon.diag


# --- Report ---------------------------------------------------------------------------------------


def cube_grid() -> tuple[NodeGrid, GridSurface]:
    grid = NodeGrid(np.zeros(3), 1.0, np.ones((2, 2, 2), bool))
    return grid, grid_surface(grid)


def assert_finite_and_rest(b: Binding, x: np.ndarray, normals: np.ndarray, verts: np.ndarray) -> None:
    for f in fields(Binding):
        value = getattr(b, f.name)
        if isinstance(value, np.ndarray) and value.dtype.kind == "f":
            assert np.isfinite(value).all(), f.name
    for use in (np.zeros(len(verts), bool), np.ones(len(verts), bool)):
        out, n, _ = mapped(b, x, normals, use)
        assert np.abs(out - verts).max() < 1e-12
        assert np.abs(n - b.normal_world).max() < 1e-12


@pytest.mark.parametrize("move", ["repeated", "collinear"])
def test_degenerate_triangles_of_a_grid_surface_are_reported(move):
    grid, surface = cube_grid()
    x = grid.rest_positions.copy()
    node_tris = surface.nodes[surface.triangles]
    i, j, k = node_tris[0]
    if move == "repeated":
        x[j] = x[i]
        expected = np.flatnonzero(np.isin(node_tris, [i]).any(1) & np.isin(node_tris, [j]).any(1))
    else:
        x[j] = (x[i] + x[k]) / 2
        c = x[node_tris]
        area = np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1)
        expected = np.flatnonzero(area < 1e-12)
    assert 0 in expected
    verts = np.random.default_rng(2).uniform(-0.3, 1.3, size=(400, 3))
    normals = np.zeros((grid.count, 3))
    b = bind(verts, np.array([[0, 1, 2]]), x, normals, surface, spacing=1.0)
    np.testing.assert_array_equal(b.report.degenerate_triangles, expected)
    tri_index = {tuple(t): n for n, t in enumerate(node_tris)}
    bound_to = np.array([tri_index[tuple(t)] for t in b.tri_nodes])
    np.testing.assert_array_equal(b.report.degenerate_vertices, np.flatnonzero(np.isin(bound_to, expected)))
    assert any("degenerate node triangles" in line for line in b.report.lines())
    np.testing.assert_allclose(b.distance, brute_force_distance(verts, x[node_tris]), atol=1e-12)
    assert_finite_and_rest(b, x, normals, verts)


@pytest.mark.parametrize("move", ["repeated", "collinear"])
def test_vertices_bound_to_a_degenerate_triangle(move):
    """A hand-made surface whose triangle 1 (nodes 2, 3, 4) is a segment from (0,1,0) to (0,3,0)."""
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 3, 0], [0, 3, 0.0]])
    if move == "collinear":
        x[3] = [0, 2, 0]
    surface = GridSurface(np.arange(5), np.array([[0, 1, 2], [2, 3, 4]]), np.zeros(2, bool))
    normals = np.tile([0.0, 0.0, 1.0], (5, 1))
    verts = np.array([[0.1, 2.0, 0.2], [0.0, 2.5, -0.3], [0.2, 0.2, 0.5], [-0.1, 3.5, 0.0]])
    faces = np.array([[0, 1, 2], [1, 3, 2]])
    b = bind(verts, faces, x, normals, surface, spacing=1.0)
    np.testing.assert_array_equal(b.report.degenerate_triangles, [1])
    np.testing.assert_array_equal(b.report.degenerate_vertices, [0, 1, 3])
    np.testing.assert_array_equal(b.tri_nodes[[0, 1, 3]], [[2, 3, 4]] * 3)
    r = verts - b.offset_world
    np.testing.assert_allclose(r[[0, 1, 3]], [[0, 2, 0], [0, 2.5, 0], [0, 3, 0]], atol=1e-15)
    np.testing.assert_allclose(b.distance[[0, 1, 3]], [np.hypot(0.1, 0.2), 0.3, np.hypot(0.1, 0.5)],
                               atol=1e-15)
    assert not b.curvature_ok[[0, 1, 3]].any() and b.curvature_ok[2]
    assert_finite_and_rest(b, x, normals, verts)


def test_far_vertices_are_reported(sphere):
    c = sphere
    h = c.grid.spacing
    verts = c.mesh.vertices.copy()
    pushed = np.array([3, 50, 400])
    centre = verts.mean(axis=0)
    out = verts[pushed] - centre
    verts[pushed] += 3.0 * h * out / np.linalg.norm(out, axis=1, keepdims=True)
    b = bind(verts, c.mesh.faces, c.positions, c.normals, c.surface, spacing=h)
    corners = c.positions[c.surface.nodes[c.surface.triangles]]
    exact = brute_force_distance(verts, corners)
    np.testing.assert_array_equal(b.report.far_vertices, np.flatnonzero(exact > 1.5 * h))
    assert set(pushed) <= set(b.report.far_vertices)
    np.testing.assert_allclose(b.report.far_distances, exact[b.report.far_vertices], atol=1e-12)
    assert any(f"{len(b.report.far_vertices)} vertices farther than 1.5 spacings" in line
               for line in b.report.lines())
    tight = bind(verts, c.mesh.faces, c.positions, c.normals, c.surface, spacing=h, far=100.0)
    assert len(tight.report.far_vertices) == 0


def undefined_touch(b: Binding, normals: np.ndarray) -> np.ndarray:
    """Vertices whose node triangle has a node without a normal."""
    return (np.linalg.norm(normals, axis=1) == 0)[b.tri_nodes].any(axis=1)


def test_sphere_curvature_not_ok_exactly_where_a_node_has_no_normal(sphere):
    """On a round shape node normals agree with the triangles; only nodes without a Mosegaard & Sørensen 2005, eq. 3
    normal (concave steps of the voxel surface, missing only a body-diagonal neighbour, so their
    18 unit vectors cancel) make the curvature basis unreliable."""
    b = sphere.binding
    touches = undefined_touch(b, sphere.normals)
    assert 0 < touches.sum() < 0.5 * b.vertex_count
    np.testing.assert_array_equal(b.curvature_ok, ~touches)
    assert b.report.no_normal == touches.sum() == b.report.curvature_fallback
    assert b.report.flipped == 0 and b.report.parallel == 0


def test_curvature_not_ok_where_a_node_has_no_normal(sphere):
    c = sphere
    normals = c.normals.copy()
    node = int(np.bincount(c.binding.tri_nodes[c.binding.curvature_ok].ravel()).argmax())
    normals[node] = 0.0
    b = bind(c.mesh.vertices, c.mesh.faces, c.positions, normals, c.surface, spacing=c.grid.spacing)
    on_node = (b.tri_nodes == node).any(axis=1)
    assert (on_node & c.binding.curvature_ok).sum() > 5
    assert not b.curvature_ok[on_node].any()
    assert b.report.no_normal == undefined_touch(b, normals).sum()
    np.testing.assert_array_equal(b.curvature_ok, c.binding.curvature_ok & ~on_node)
    assert np.isfinite(b.offset_curvature).all() and np.isfinite(b.normal_curvature).all()
    for mode in ("curvature", "auto"):
        out, _, _ = mapped(b, c.positions, normals, modes(b)[mode])
        assert np.abs(out - c.mesh.vertices).max() <= TOL * c.diag


def test_curvature_offsets_fall_back_to_constant_where_the_basis_cannot_be_built(sphere):
    c = sphere
    b = bind(c.mesh.vertices, c.mesh.faces, c.positions, np.zeros_like(c.normals), c.surface,
             spacing=c.grid.spacing)
    assert not b.curvature_ok.any() and b.report.no_normal == b.vertex_count
    np.testing.assert_array_equal(b.offset_curvature, b.offset_constant)
    np.testing.assert_array_equal(b.normal_curvature, b.normal_constant)
    np.testing.assert_array_equal(b.tangent_curvature, b.tangent_constant)


def test_flipped_node_normals_make_curvature_not_ok(sphere):
    c = sphere
    b = bind(c.mesh.vertices, c.mesh.faces, c.positions, -c.normals, c.surface, spacing=c.grid.spacing)
    assert not b.curvature_ok.any()
    defined = ~undefined_touch(b, c.normals)
    assert b.report.flipped == defined.sum() > 0
    assert b.report.curvature_fallback == b.vertex_count


def test_normal_near_parallel_to_t_makes_curvature_not_ok(sphere):
    c = sphere
    x = c.positions
    tri = c.surface.nodes[c.surface.triangles]
    t = x[tri[:, 1]] - x[tri[:, 0]]
    # Every defined node normal 3 degrees off the T of one triangle: on the triangles whose T is
    # that direction |Nc x T| = sin 3 deg = 0.052, below MIN_SIN_NC_T.
    t0 = t[0] / np.linalg.norm(t[0])
    side = np.cross(t0, [0.3, 0.5, 0.8])
    direction = np.cos(np.radians(3)) * t0 + np.sin(np.radians(3)) * side / np.linalg.norm(side)
    normals = np.where(np.linalg.norm(c.normals, axis=1, keepdims=True) > 0, direction, 0.0)
    b = bind(c.mesh.vertices, c.mesh.faces, x, normals, c.surface, spacing=c.grid.spacing)
    p = x[b.tri_nodes]
    bt = p[:, 1] - p[:, 0]
    sin = np.linalg.norm(np.cross(bt / np.linalg.norm(bt, axis=1, keepdims=True), direction), axis=1)
    parallel = (sin <= bd.MIN_SIN_NC_T) & ~undefined_touch(b, normals)
    assert parallel.sum() > 10
    assert not b.curvature_ok[parallel].any()
    assert b.report.parallel == parallel.sum()
    assert b.report.no_normal + b.report.parallel + b.report.flipped == b.report.curvature_fallback


@pytest.mark.parametrize(("tilt", "ok"), [(0.0, True), (74.0, True), (76.0, False), (120.0, False)])
def test_curvature_ok_angle_threshold(tilt, ok):
    """One node triangle in the z = 0 plane (T = +x, N = +z), node normals tilted about T."""
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]])
    surface = GridSurface(np.arange(3), np.array([[0, 1, 2]]), np.zeros(1, bool))
    a = np.radians(tilt)
    normals = np.tile([0.0, -np.sin(a), np.cos(a)], (3, 1))
    verts = np.array([[0.2, 0.3, 0.1], [0.5, 0.1, -0.05]])
    b = bind(verts, np.array([[0, 1, 1]]), x, normals, surface, spacing=1.0)
    assert (b.curvature_ok == ok).all()
    assert b.report.flipped == (0 if ok else 2)
    assert_finite_and_rest(b, x, normals, verts)


def test_report_lines_summarise(dragon):
    lines = dragon.binding.report.lines()
    assert lines[0].startswith(f"bound {dragon.binding.vertex_count} vertices to "
                               f"{len(dragon.surface.triangles)} node-surface triangles")
    fallback = int((~dragon.binding.curvature_ok).sum())
    assert fallback == dragon.binding.report.curvature_fallback
    if fallback:
        assert any(f"unreliable for {fallback} vertices" in line for line in lines)


# --- Input errors ---------------------------------------------------------------------------------


def test_bad_inputs_are_input_errors_naming_mesh_and_vertex(sphere):
    c = sphere
    args = (c.positions, c.normals, c.surface)
    verts = c.mesh.vertices.copy()
    verts[17, 1] = np.nan
    with pytest.raises(InputError, match=r"ball\.ply: vertex 17 is not finite"):
        bind(verts, c.mesh.faces, *args, spacing=c.grid.spacing, name="ball.ply")
    faces = c.mesh.faces.copy()
    faces[4, 2] = len(verts)
    with pytest.raises(InputError, match=r"ball\.ply: face 4 uses a vertex index out of range"):
        bind(c.mesh.vertices, faces, *args, spacing=c.grid.spacing, name="ball.ply")
    with pytest.raises(InputError, match="no triangles"):
        bind(c.mesh.vertices, c.mesh.faces, c.positions, c.normals,
             GridSurface(np.zeros(0, np.int64), np.zeros((0, 3), np.int64), np.zeros(0, bool)),
             spacing=c.grid.spacing)
    with pytest.raises(InputError, match="spacing"):
        bind(c.mesh.vertices, c.mesh.faces, *args, spacing=0.0)
    with pytest.raises(InputError, match=r"3 texture coordinates for \d+ vertices"):
        bind(c.mesh.vertices, c.mesh.faces, *args, spacing=c.grid.spacing, uv=np.zeros((3, 2)))
    with pytest.raises(InputError, match=r"vertex must be an array of shape \(n, 3\)"):
        bind(c.mesh.vertices[:, :2], c.mesh.faces, *args, spacing=c.grid.spacing)


def test_default_tangents_follow_the_procedural_uv_across_its_seam(sphere):
    c = sphere
    b = c.binding
    v, f = c.mesh.vertices, c.mesh.faces
    np.testing.assert_array_equal(b.uv, procedural_uv(v, b.normal_world))
    wrapped = vertex_tangents(v, f, b.normal_world, b.uv, periodic_u=True)
    np.testing.assert_allclose(b.tangent_world, wrapped, atol=1e-15)
    plain = vertex_tangents(v, f, b.normal_world, b.uv)
    assert np.abs(plain - wrapped).max() > 0.5  # the seam matters on this mesh


def test_given_uv_and_tangents_are_used(sphere):
    c = sphere
    v = c.mesh.vertices
    uv = np.stack([v[:, 0], v[:, 2]], axis=1)
    b = bind(v, c.mesh.faces, c.positions, c.normals, c.surface, spacing=c.grid.spacing, uv=uv)
    np.testing.assert_array_equal(b.uv, uv)
    # dP/du is +x where the surface is not perpendicular to x (e.g. the top): the tangent is +x there.
    top = np.argmax(v[:, 1])
    np.testing.assert_allclose(b.tangent_world[top, :3], [1.0, 0.0, 0.0], atol=0.05)
    given = np.tile([0.0, 0.0, 1.0, -1.0], (len(v), 1))
    b2 = bind(v, c.mesh.faces, c.positions, c.normals, c.surface, spacing=c.grid.spacing, tangents=given)
    assert (b2.tangent_world[:, 3] == -1).all()
    assert np.abs(np.einsum("ij,ij->i", b2.tangent_world[:, :3], b2.normal_world)).max() < 1e-12
    np.testing.assert_allclose(b2.tangent_world[top, :3], [0.0, 0.0, 1.0], atol=0.05)


# --- Cache ------------------------------------------------------------------------------------------


def key_of(c: Case, **change) -> str:
    args = dict(vertices=c.mesh.vertices, faces=c.mesh.faces, node_positions=c.positions,
                surface_triangles=c.surface.triangles, spacing=c.grid.spacing, options={"far": 1.5})
    args.update(change)
    return binding_key(**args)


def assert_bindings_equal(a: Binding, b: Binding) -> None:
    for f in fields(Binding):
        if f.name != "report":
            np.testing.assert_array_equal(getattr(a, f.name), getattr(b, f.name), err_msg=f.name)
            assert getattr(a, f.name).dtype == getattr(b, f.name).dtype, f.name
    for f in fields(type(a.report)):
        np.testing.assert_array_equal(getattr(a.report, f.name), getattr(b.report, f.name), err_msg=f.name)


def test_cache_round_trip(tmp_path, dragon):
    key = key_of(dragon)
    path = tmp_path / "dragon.npz"
    save_binding(path, dragon.binding, key)
    assert sorted(os.listdir(tmp_path)) == ["dragon.npz"]  # no temporary file left behind
    loaded = load_binding(path, key)
    assert loaded is not None
    assert_bindings_equal(loaded, dragon.binding)
    assert loaded.report.lines() == dragon.binding.report.lines()
    save_binding(path, dragon.binding, key)  # overwriting is fine too
    assert sorted(os.listdir(tmp_path)) == ["dragon.npz"]


def test_cache_key_changes_with_inputs(tmp_path, dragon):
    key = key_of(dragon)
    assert len(key) == 64 and int(key, 16) >= 0
    assert key == key_of(dragon)  # deterministic
    moved = dragon.mesh.vertices.copy()
    moved[123, 0] += 1e-12
    others = [key_of(dragon, spacing=dragon.grid.spacing * 1.001), key_of(dragon, vertices=moved),
              key_of(dragon, options={"far": 2.0}), key_of(dragon, faces=dragon.mesh.faces[::-1]),
              key_of(dragon, node_positions=dragon.positions + 1e-9),
              binding_key(dragon.mesh.vertices, dragon.mesh.faces, dragon.positions, dragon.surface.triangles,
                          dragon.grid.spacing, {"far": 1.5}, uv=np.zeros((len(moved), 2)))]
    assert len(set(others)) == len(others) and key not in others
    path = tmp_path / "b.npz"
    save_binding(path, dragon.binding, key)
    for other in others:
        assert load_binding(path, other) is None
    assert load_binding(path, key) is not None


def test_cache_key_ignores_dtype_of_equal_values(dragon):
    assert key_of(dragon, faces=dragon.mesh.faces.astype(np.int32)) == key_of(dragon)


@pytest.mark.parametrize("damage", ["garbage", "truncated", "empty", "missing", "directory", "no_key",
                                    "bad_shape", "nan", "version"])
def test_bad_cache_files_give_none(tmp_path, dragon, damage):
    key = key_of(dragon)
    path = tmp_path / "b.npz"
    save_binding(path, dragon.binding, key)
    data = path.read_bytes()
    if damage == "garbage":
        path.write_bytes(b"not a zip file at all" * 10)
    elif damage == "truncated":
        path.write_bytes(data[: len(data) // 2])
    elif damage == "empty":
        path.write_bytes(b"")
    elif damage == "missing":
        path.unlink()
    elif damage == "directory":
        path.unlink()
        path.mkdir()
    else:
        with np.load(path) as npz:
            arrays = dict(npz)
        if damage == "no_key":
            del arrays["key"]
        elif damage == "bad_shape":
            arrays["weights"] = arrays["weights"][:-1]
        elif damage == "nan":
            arrays["offset_constant"][0, 0] = np.nan
        elif damage == "version":
            arrays["version"] = np.asarray(cache.BINDING_VERSION + 1)
        with open(path, "wb") as fh:
            np.savez_compressed(fh, **arrays)
    assert load_binding(path, key) is None


def test_failed_save_leaves_no_temporary_file(tmp_path, dragon, monkeypatch):
    def boom(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(cache.np, "savez_compressed", boom)
    with pytest.raises(OSError, match="disk full"):
        save_binding(tmp_path / "b.npz", dragon.binding, "k")
    assert os.listdir(tmp_path) == []


def test_binding_arrays_are_read_only(dragon):
    with pytest.raises(ValueError):
        dragon.binding.weights[0, 0] = 0.5


# --- Benchmark helper -------------------------------------------------------------------------------


def test_jittered_copies_has_exact_vertex_count(dragon):
    v, f = bench_bd._jittered_copies(dragon.mesh.vertices, dragon.mesh.faces, 12_000)
    assert len(v) == 12_000 and f.max() < 12_000 and len(f) > 2 * len(dragon.mesh.faces)
    np.testing.assert_array_equal(v[: len(dragon.mesh.vertices)], dragon.mesh.vertices)
