"""Tests for :mod:`deformgl.grid.voxelize`: grid definition, exact surface cover, interior fill."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy import ndimage

from deformgl.grid import voxelize as vz
from deformgl.errors import InputError
from deformgl.grid.meshio import load_mesh
from deformgl.grid.voxelize import Voxelization, node_positions, voxelize

DRAGON = Path(__file__).resolve().parents[1] / "scenes" / "assets" / "dragon_vrip_res4.ply.gz"
HALF_DIAGONAL = np.sqrt(3) / 2  # centre-to-corner distance of a unit cube


def grid_points(vox: Voxelization, pad: int = 0) -> np.ndarray:
    """``(nx+2p, ny+2p, nz+2p, 3)`` world positions of every node of the grid, padded."""
    idx = np.indices(np.array(vox.occupied.shape) + 2 * pad).transpose(1, 2, 3, 0) - pad
    return vox.origin + vox.spacing * idx


def cube_meets_box(centres: np.ndarray, h: float, box_centre, half_extents, rotation) -> np.ndarray:
    """Exact closed test of axis-aligned cubes against an oriented box (15 separating axes)."""
    box_axes = np.asarray(rotation, dtype=np.float64).T  # rows: the box's unit axes
    axes = list(np.eye(3)) + list(box_axes)
    axes += [np.cross(a, b) for a in np.eye(3) for b in box_axes]
    offset = centres - np.asarray(box_centre)
    meets = np.ones(centres.shape[:-1], dtype=bool)
    for axis in axes:
        if np.linalg.norm(axis) < 1e-12:
            continue
        r_cube = h / 2 * np.abs(axis).sum()
        r_box = sum(e * abs(axis @ b) for e, b in zip(half_extents, box_axes))
        meets &= np.abs(offset @ axis) <= r_cube + r_box
    return meets


def surface_samples(mesh: trimesh.Trimesh, per_edge: int = 40) -> np.ndarray:
    """Points on every face on a barycentric grid, vertices and edges included."""
    i, j = np.meshgrid(np.arange(per_edge + 1), np.arange(per_edge + 1), indexing="ij")
    keep = i + j <= per_edge
    u, v = i[keep] / per_edge, j[keep] / per_edge
    bary = np.stack([1 - u - v, u, v], axis=1)
    return np.einsum("kb,fbd->fkd", bary, mesh.triangles).reshape(-1, 3)


def containing_nodes(vox: Voxelization, points: np.ndarray) -> np.ndarray:
    """Index of the node whose cube contains each point (nearest node)."""
    return np.rint((points - vox.origin) / vox.spacing).astype(np.int64)


def assert_points_covered(vox: Voxelization, points: np.ndarray) -> None:
    idx = containing_nodes(vox, points)
    assert (idx >= 0).all() and (idx < vox.occupied.shape).all()
    assert vox.occupied[tuple(idx.T)].all()


def winding_numbers(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Generalized winding numbers (solid angle sums / 4 pi) of points w.r.t. a mesh."""
    out = np.empty(len(points))
    tri = mesh.triangles
    for s in range(0, len(points), 32):
        a = tri[None] - points[s : s + 32, None, None]
        n = np.linalg.norm(a, axis=3)
        det = np.einsum("pij,pij->pi", a[:, :, 0], np.cross(a[:, :, 1], a[:, :, 2]))
        dot = lambda x, y: np.einsum("pij,pij->pi", x, y)  # noqa: E731
        den = (
            n[..., 0] * n[..., 1] * n[..., 2]
            + dot(a[:, :, 0], a[:, :, 1]) * n[..., 2]
            + dot(a[:, :, 1], a[:, :, 2]) * n[..., 0]
            + dot(a[:, :, 2], a[:, :, 0]) * n[..., 1]
        )
        out[s : s + 32] = 2 * np.arctan2(det, den).sum(axis=1) / (4 * np.pi)
    return out


def with_holes(mesh: trimesh.Trimesh, directions, radius: float) -> trimesh.Trimesh:
    """The mesh without the faces whose centre is within ``radius`` of a unit direction."""
    centres = mesh.triangles_center
    keep = np.ones(len(centres), dtype=bool)
    for d in directions:
        d = np.asarray(d, dtype=np.float64) / np.linalg.norm(d)
        keep &= np.linalg.norm(centres - d, axis=1) > radius
    return trimesh.Trimesh(mesh.vertices, mesh.faces[keep], process=False)


# --- grid definition -------------------------------------------------------------------------


def test_box_gives_full_block_with_n_nodes_along_longest_axis():
    box = trimesh.creation.box(extents=(2.0, 1.0, 0.6))
    box.apply_translation((3.0, -1.0, 0.5))
    vox = voxelize(box, nodes_along_longest=5)
    assert vox.spacing == pytest.approx(0.5)
    assert vox.occupied.shape == (5, 3, 2)  # round(extent / h) + 1 per axis
    assert vox.occupied.all()
    np.testing.assert_allclose(vox.origin, [2.0, -1.5, 0.25])  # grid centred on the box


@pytest.mark.parametrize("order", [(0, 1, 2), (2, 0, 1), (1, 2, 0)])
@pytest.mark.parametrize("n", [2, 3, 7, 12])
def test_longest_axis_gets_n_nodes_whatever_its_direction(order, n):
    extents = np.array([1.3, 0.7, 0.45])[list(order)]
    vox = voxelize(trimesh.creation.box(extents=extents), nodes_along_longest=n)
    h = extents.max() / (n - 1)
    assert vox.spacing == pytest.approx(h)
    assert vox.occupied.shape == tuple(int(v) for v in np.rint(extents / h) + 1)
    assert vox.occupied.shape[int(np.argmax(extents))] == n
    assert vox.occupied.all()


def test_box_with_spacing():
    vox = voxelize(trimesh.creation.box(extents=(2.0, 1.0, 0.6)), spacing=0.25)
    assert vox.spacing == 0.25
    assert vox.occupied.shape == (9, 5, 3) and vox.occupied.all()


def test_rotated_box_matches_exact_cube_box_intersection():
    rotation = trimesh.transformations.euler_matrix(0.4, -0.7, 1.1)
    half = np.array([0.5, 0.3, 0.17])
    box = trimesh.creation.box(extents=2 * half, transform=rotation)
    box.apply_translation((0.2, -0.1, 0.3))
    vox = voxelize(box, nodes_along_longest=12)
    points = grid_points(vox, pad=1)
    expected = cube_meets_box(points, vox.spacing, (0.2, -0.1, 0.3), half, rotation[:3, :3])
    assert expected.sum() == expected[1:-1, 1:-1, 1:-1].sum()  # nothing expected off the grid
    np.testing.assert_array_equal(vox.occupied, expected[1:-1, 1:-1, 1:-1])


def test_overlapping_parts_give_their_union():
    # Two boxes crossing each other: parity alone calls the shared block outside.
    bar_x = trimesh.creation.box(extents=(2.0, 1.0, 1.0))
    bar_y = trimesh.creation.box(extents=(1.0, 2.0, 1.0))
    both = trimesh.util.concatenate([bar_x, bar_y])
    vox = voxelize(both, spacing=0.25)
    assert vox.occupied.shape == (9, 9, 5)
    points = grid_points(vox)
    identity = np.eye(3)
    expected = cube_meets_box(points, 0.25, (0, 0, 0), (1.0, 0.5, 0.5), identity) | cube_meets_box(
        points, 0.25, (0, 0, 0), (0.5, 1.0, 0.5), identity
    )
    np.testing.assert_array_equal(vox.occupied, expected)


def test_node_positions_in_nonzero_order():
    occupied = np.zeros((3, 2, 2), dtype=bool)
    occupied[2, 1, 0] = occupied[0, 0, 1] = occupied[1, 1, 1] = True
    vox = Voxelization(origin=np.array([1.0, 2.0, 3.0]), spacing=0.5, occupied=occupied)
    expected = [[1.0, 2.0, 3.5], [1.5, 2.5, 3.5], [2.0, 2.5, 3.0]]
    np.testing.assert_array_equal(node_positions(vox), expected)
    assert node_positions(vox).dtype == np.float64


def test_voxelization_is_read_only_and_validated():
    occupied = np.ones((2, 2, 2), dtype=bool)
    vox = Voxelization(origin=[0, 0, 0], spacing=1, occupied=occupied)
    occupied[0, 0, 0] = False  # the caller's array was copied
    assert vox.occupied.all() and vox.origin.dtype == np.float64 and isinstance(vox.spacing, float)
    with pytest.raises(ValueError):
        vox.occupied[0, 0, 0] = False
    with pytest.raises(ValueError, match="origin"):
        Voxelization(origin=[0, 0], spacing=1.0, occupied=occupied)
    with pytest.raises(ValueError, match="spacing"):
        Voxelization(origin=[0, 0, 0], spacing=0.0, occupied=occupied)
    with pytest.raises(ValueError, match="3-D"):
        Voxelization(origin=[0, 0, 0], spacing=1.0, occupied=occupied[0])


# --- surface: nothing missed, nothing added --------------------------------------------------


@pytest.mark.parametrize("n", [4, 9, 23])
def test_open_triangle_is_covered_without_thickening(n):
    corners = [[0, 0, 0], [1, 0.1, 0.05], [0.2, 0.9, 0.1]]
    sheet = trimesh.Trimesh(corners, [[0, 1, 2]], process=False)
    vox = voxelize(sheet, nodes_along_longest=n)
    assert_points_covered(vox, surface_samples(sheet, per_edge=200))
    _, distance, _ = trimesh.proximity.closest_point(sheet, node_positions(vox))
    assert distance.max() <= vox.spacing * HALF_DIAGONAL  # every occupied cube touches the sheet


def test_thin_needle_is_covered():
    # A closed sliver 1000 times thinner than a cell.
    needle = trimesh.Trimesh(
        [[0, 0, 0], [1, 0.3, 0.2], [0.5, 0.1502, 0.1001], [0.4, 0.1201, 0.0799]],
        [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        process=False,
    )
    vox = voxelize(needle, nodes_along_longest=15)
    assert_points_covered(vox, surface_samples(needle, per_edge=300))
    _, distance, _ = trimesh.proximity.closest_point(needle, node_positions(vox))
    assert distance.max() <= vox.spacing * HALF_DIAGONAL


# --- interior --------------------------------------------------------------------------------


@pytest.mark.parametrize("n", [6, 11, 16, 25])
def test_sphere_matches_analytic_inside_test(n):
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    vox = voxelize(sphere, nodes_along_longest=n)
    assert vox.occupied.shape == (n, n, n)
    h = vox.spacing
    r = np.linalg.norm(grid_points(vox, pad=1), axis=-1)
    padded = np.pad(vox.occupied, 1)
    assert padded[r < 1.0 - h * HALF_DIAGONAL].all()
    assert not padded[r > 1.0 + h * HALF_DIAGONAL].any()
    # Tighter: the polyhedron lies between its inscribed sphere and the unit sphere, so a cube
    # is occupied if it reaches the inscribed sphere and empty if it misses the unit sphere.
    inradius = np.abs(np.einsum("ij,ij->i", sphere.face_normals, sphere.triangles_center)).min()
    gap = np.linalg.norm(np.maximum(np.abs(grid_points(vox, pad=1)) - h / 2, 0), axis=-1)
    assert padded[gap < inradius - 1e-9].all()
    assert not padded[gap > 1.0 + 1e-9].any()


@pytest.mark.parametrize("cells_across", [10.4, 12.4, 14.4])
def test_sphere_with_holes_gives_same_occupancy_as_watertight(cells_across):
    # Six holes of radius 1.2 cells, one on each axis, so every axis line through the middle
    # passes two holes. Where surface is missing its position is unknown, so a cube that only
    # met the missing part is undecidable; 2 / h = k + 0.4 puts the outermost node planes
    # 0.2 h inside the poles and the next ones clear of the sphere, which keeps every node near
    # a hole clearly inside or clearly outside.
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    h = 2.0 / cells_across
    poles = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]
    holed = with_holes(sphere, poles, 1.2 * h)
    assert len(holed.faces) < len(sphere.faces) - 6 * 30 and not holed.is_watertight
    whole, leaky = voxelize(sphere, spacing=h), voxelize(holed, spacing=h)
    np.testing.assert_array_equal(leaky.origin, whole.origin)
    np.testing.assert_array_equal(leaky.occupied, whole.occupied)
    assert ndimage.binary_erosion(whole.occupied).sum() > 0.3 * whole.occupied.sum()


@pytest.mark.parametrize("n, radius_cells", [(12, 2.0), (16, 2.5), (21, 1.5)])
def test_sphere_with_oblique_holes_keeps_its_interior(n, radius_cells):
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    whole = voxelize(sphere, nodes_along_longest=n)
    h = whole.spacing
    holes = [(1, 1, 1), (-1, 1, -1), (1, -1, -1), (-1, -2, 1.5), (2, 0.5, -1)]
    holed = with_holes(sphere, holes, radius_cells * h)
    np.testing.assert_array_equal(holed.bounds, sphere.bounds)  # same grid
    leaky = voxelize(holed, spacing=h)
    np.testing.assert_array_equal(leaky.origin, whole.origin)
    assert leaky.occupied.shape == whole.occupied.shape
    assert not (leaky.occupied & ~whole.occupied).any()  # nothing spurious
    r = np.linalg.norm(grid_points(whole), axis=-1)
    assert leaky.occupied[r < 1.0 - h * HALF_DIAGONAL].all()  # interior filled despite holes
    missing = whole.occupied & ~leaky.occupied
    assert (r[missing] > 0.9).all()  # only cubes near the missing surface are lost


def test_half_ray_parity_is_exact_on_lattice_aligned_edges_and_vertices():
    # An octahedron with its vertices on lattice points: lines along all 13 directions run
    # exactly through its vertices and along or across its edges.
    vertices = np.array([[3, 0, 0], [-3, 0, 0], [0, 3, 0], [0, -3, 0], [0, 0, 3], [0, 0, -3]]) + 4
    faces = [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]]
    octahedron = trimesh.Trimesh(vertices.astype(np.float64), faces, process=False)
    assert octahedron.is_watertight and octahedron.volume > 0
    taxicab = np.abs(np.indices((9, 9, 9)) - 4).sum(axis=0)
    for direction in vz.RAY_DIRECTIONS:
        odd = vz._odd_half_rays(octahedron.triangles, (9, 9, 9), direction)
        assert (odd[taxicab < 3] == 2).all(), direction
        assert (odd[taxicab > 3] == 0).all(), direction


def test_box_parity_with_vertices_on_the_lattice():
    box = trimesh.creation.box(bounds=[[1, 1, 1], [4, 6, 3]]).subdivide()
    inside = np.zeros((6, 8, 5), dtype=bool)
    inside[2:4, 2:6, 2:3] = True
    outside = np.ones_like(inside)
    outside[1:5, 1:7, 1:4] = False
    for direction in vz.RAY_DIRECTIONS:
        odd = vz._odd_half_rays(box.triangles, inside.shape, direction)
        assert (odd[inside] == 2).all() and (odd[outside] == 0).all(), direction


@pytest.mark.parametrize("n", [8, 16])
def test_dragon_is_filled_and_covers_every_vertex(n):
    dragon = load_mesh(DRAGON)
    vox = voxelize(dragon, nodes_along_longest=n, source=str(DRAGON))
    h = vox.spacing
    assert h == pytest.approx(dragon.extents.max() / (n - 1))
    assert vox.occupied.shape == tuple(int(v) for v in np.rint(dragon.extents / h) + 1)
    assert vox.occupied.shape[0] == n
    # Every file vertex lies in the cube of an occupied node.
    assert_points_covered(vox, dragon.vertices)
    # No empty node is enclosed: each empty component (6-connected) touches the grid border.
    labels, count = ndimage.label(~vox.occupied)
    border = np.ones_like(vox.occupied)
    border[1:-1, 1:-1, 1:-1] = False
    assert set(np.unique(labels[border & ~vox.occupied])) == set(range(1, count + 1))
    # Nodes whose cube cannot reach the surface are occupied exactly when they are inside.
    points = node_positions(Voxelization(vox.origin, h, np.ones_like(vox.occupied)))
    _, distance, _ = trimesh.proximity.closest_point(dragon, points)
    far = distance > h * HALF_DIAGONAL
    inside = winding_numbers(dragon, points[far]) > 0.5
    np.testing.assert_array_equal(vox.occupied.reshape(-1)[far], inside)
    if n == 16:
        assert inside.sum() >= 10  # the check above is not vacuous


def test_dragon_with_extra_holes_keeps_its_interior():
    dragon = load_mesh(DRAGON)
    whole = voxelize(dragon, nodes_along_longest=16)
    rng = np.random.default_rng(7)
    keep = np.ones(len(dragon.faces), dtype=bool)
    keep[rng.choice(len(dragon.faces), 200, replace=False)] = False  # about 2% of the faces
    holed = trimesh.Trimesh(dragon.vertices, dragon.faces[keep], process=False)
    leaky = voxelize(holed, spacing=whole.spacing)
    np.testing.assert_array_equal(leaky.origin, whole.origin)
    np.testing.assert_array_equal(leaky.occupied, whole.occupied)


# --- errors ----------------------------------------------------------------------------------


def test_mesh_without_faces_is_an_input_error():
    vertices = np.random.default_rng(0).random((5, 3))
    points = trimesh.Trimesh(vertices=vertices, faces=np.zeros((0, 3), dtype=np.int64))
    with pytest.raises(InputError, match=r"^thin\.ply: the mesh has no faces"):
        voxelize(points, spacing=0.1, source="thin.ply")


def test_zero_extent_mesh_is_an_input_error():
    dot = trimesh.Trimesh([[1.0, 1.0, 1.0]] * 3, [[0, 1, 2]], process=False)
    with pytest.raises(InputError, match=r"^dot\.ply: the mesh has zero extent"):
        voxelize(dot, nodes_along_longest=4, source="dot.ply")
    vox = voxelize(dot, spacing=0.5)  # with an explicit spacing a point still occupies a node
    assert vox.occupied.shape == (1, 1, 1) and vox.occupied.all()
    np.testing.assert_array_equal(vox.origin, [1.0, 1.0, 1.0])


def test_flat_mesh_gives_one_layer():
    square = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]])
    vox = voxelize(square, nodes_along_longest=5)
    assert vox.occupied.shape == (5, 5, 1) and vox.occupied.all()


def test_too_fine_spacing_is_an_input_error():
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    with pytest.raises(InputError, match=r"^box\.obj: spacing 0\.001 is too fine"):
        voxelize(box, spacing=0.001, source="box.obj")


def test_bad_mesh_data_is_an_input_error():
    corners = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    bad_index = trimesh.Trimesh(corners, [[0, 1, 5]], process=False, validate=False)
    with pytest.raises(InputError, match="face index is out of range"):
        voxelize(bad_index, spacing=0.1)
    nan = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, np.nan, 0]], [[0, 1, 2]], process=False)
    with pytest.raises(InputError, match="non-finite"):
        voxelize(nan, spacing=0.1)


@pytest.mark.parametrize(
    "kwargs",
    [
        {},
        {"nodes_along_longest": 4, "spacing": 0.1},
        {"nodes_along_longest": 1},
        {"nodes_along_longest": 0},
        {"nodes_along_longest": 2.5},
        {"nodes_along_longest": True},
        {"spacing": 0.0},
        {"spacing": -0.1},
        {"spacing": float("nan")},
        {"spacing": float("inf")},
        {"spacing": "0.1"},
    ],
)
def test_resolution_argument_errors(kwargs):
    with pytest.raises(ValueError):
        voxelize(trimesh.creation.box(), **kwargs)
