"""Anchors on a deforming mesh and the attachment grids they drive (section 5), CPU part."""

import numpy as np
import pytest

from deformgl.trilinear.anchors import Anchor, AnchorArray, anchor_frames, attachment_grid, locate_on_mesh
from deformgl.errors import InputError
from deformgl.trilinear.scenegraph import compose_scene
from deformgl.trilinear.graph_nodes import Geometry, GeometryNode, TransformNode
from deformgl.trilinear.transforms import Bend, Box, Twist, unit_lattice

LENGTH, WIDTH, RADIUS = 4.0, 2.0, 2.0


def plane(nx, ny):
    """A triangulated plane [0, LENGTH] x [0, WIDTH] at z = 0 (normals +z)."""
    x, y = np.meshgrid(np.linspace(0, LENGTH, nx + 1), np.linspace(0, WIDTH, ny + 1), indexing="ij")
    v = np.stack([x, y, np.zeros_like(x)], -1).reshape(-1, 3)
    idx = np.arange(len(v)).reshape(nx + 1, ny + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return v, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


OBJECT = Box(np.array([0.5, 0.4, 0.0]), np.array([3.5, 1.6, 0.3]))


def anchors_2d(v, t, shape=(7, 4), box=OBJECT):
    u = unit_lattice((shape[0] - 1, shape[1] - 1, 1))[:, :, 0]
    pos = box.from_unit(u)
    pos[..., 2] = 0.0
    return AnchorArray.on_mesh(v, t, pos, pos + [0.05, 0.0, 0.0])


def cylinder_distance(p):
    """Distance from the axis of the bend (the line x = 0, z = RADIUS along y)."""
    return np.hypot(p[..., 0], p[..., 2] - RADIUS)


def test_frames_are_orthonormal_right_handed_and_follow_the_mesh():
    v, t = plane(8, 4)
    anchors = anchors_2d(v, t)
    bent = Twist(0.4)(Bend(RADIUS)(v) - [0, 0, 1.0])
    f = anchor_frames(anchors, bent, t)
    assert f.origin.shape == (7, 4, 3)
    for a, b in ((f.tangent, f.tangent), (f.bitangent, f.bitangent), (f.normal, f.normal)):
        assert np.allclose((a * b).sum(-1), 1.0)
    assert np.allclose((f.tangent * f.normal).sum(-1), 0.0, atol=1e-12)
    assert np.allclose(np.cross(f.tangent, f.bitangent), f.normal, atol=1e-12)
    # the origin is the barycentric combination of the deformed triangle's vertices
    corners = bent[t[anchors.triangles]]
    assert np.allclose(f.origin, np.einsum("ijc,ijcd->ijd", anchors.points, corners))
    edges = corners[..., 1, :] - corners[..., 0, :]
    assert np.allclose((edges * f.normal).sum(-1), 0.0, atol=1e-12)


def test_rest_grid_of_anchors_on_a_flat_plane_is_the_identity():
    v, t = plane(8, 4)
    grid = anchors_2d(v, t).grid(v, t, OBJECT)
    assert grid.cells == (6, 3, 1) and grid.is_linear()
    p = OBJECT.from_unit(np.random.default_rng(0).random((200, 3)))
    assert np.allclose(grid(p), p, rtol=0, atol=1e-12)


@pytest.mark.parametrize("nx, ny", [(8, 4), (32, 16)])
def test_2d_anchor_grid_follows_a_plane_bent_into_a_cylinder(nx, ny):
    v, t = plane(nx, ny)
    anchors = anchors_2d(v, t)
    grid = anchors.grid(Bend(RADIUS)(v), t, OBJECT)
    # lattice points: anchors on the cylinder, heights along its inward normal
    exact = Bend(RADIUS)(OBJECT.from_unit(unit_lattice(grid.cells)).reshape(-1, 3))
    h = LENGTH / nx
    chord = h * h / (8 * RADIUS)                 # a flat triangle below the arc
    tilt = OBJECT.hi[2] * h / RADIUS             # the face normal, half an edge off
    err = np.linalg.norm(grid.points.reshape(-1, 3) - exact, axis=1).max()
    assert err <= chord + tilt
    # the attached object's vertices keep their height above the surface
    rng = np.random.default_rng(1)
    local = OBJECT.from_unit(rng.random((500, 3)))
    moved = grid(local)
    assert np.abs(cylinder_distance(moved) - (RADIUS - local[:, 2])).max() <= 2 * (chord + tilt)


def test_finer_meshes_make_the_attachment_more_accurate():
    errors = []
    for n in (8, 16, 32):
        v, t = plane(n, n // 2)
        grid = anchors_2d(v, t).grid(Bend(RADIUS)(v), t, OBJECT)
        exact = Bend(RADIUS)(OBJECT.from_unit(unit_lattice(grid.cells)).reshape(-1, 3))
        errors.append(np.linalg.norm(grid.points.reshape(-1, 3) - exact, axis=1).max())
    assert errors[0] > 1.6 * errors[1] > 1.6 * 1.6 * errors[2]


def test_1d_anchor_strip_follows_the_bend():
    v, t = plane(32, 8)
    xs = np.linspace(0.5, 3.5, 9)
    pos = np.stack([xs, np.full(9, 1.0), np.zeros(9)], 1)
    anchors = AnchorArray.on_mesh(v, t, pos, pos + [0.05, 0.0, 0.0])
    strip = Box(np.array([0.5, -0.2, 0.0]), np.array([3.5, 0.2, 0.25]))
    rest = anchors.grid(v, t, strip)
    assert rest.cells == (8, 1, 1)
    p = strip.from_unit(np.random.default_rng(2).random((300, 3)))
    assert np.allclose(rest(p), p + [0.0, 1.0, 0.0], atol=1e-12)  # the strip sits on the line y = 1
    bent = anchors.grid(Bend(RADIUS)(v), t, strip)
    moved = bent(p)
    assert np.abs(cylinder_distance(moved) - (RADIUS - p[:, 2])).max() < 0.02
    assert np.allclose(moved[:, 1], p[:, 1] + 1.0, atol=1e-9)  # the bend keeps y; b stays along y


def test_attached_object_in_the_scene_graph_follows_the_surface():
    v, t = plane(16, 8)
    anchors = anchors_2d(v, t)
    rng = np.random.default_rng(3)
    local = OBJECT.from_unit(rng.random((400, 3)))
    local[:8] = OBJECT.corners()
    leaf = GeometryNode(Geometry(local, rng.normal(size=local.shape), np.zeros((0, 3)), "badge"))
    node = TransformNode(anchors.grid(v, t, OBJECT), [leaf])
    assert compose_scene(node).transform_of(leaf)[1] == "affine"   # flat: the linear path
    node.transform = anchors.grid(Bend(RADIUS)(v), t, OBJECT)      # the mesh moved: update the node
    scene = compose_scene(node)
    (batch,) = scene.batches
    assert batch.path == "grid"
    world, _ = batch.reference()
    assert np.abs(cylinder_distance(world[0]) - (RADIUS - local[:, 2])).max() < 0.02


def test_anchor_array_from_anchor_objects():
    v, t = plane(2, 2)
    row = [Anchor(0, (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)), Anchor(1, (0.2, 0.3, 0.5), (0.0, 0.0, 1.0))]
    one = AnchorArray.of(row)
    two = AnchorArray.of([row, row])
    assert one.shape == (2,) and two.shape == (2, 2)
    f = two.frames(v, t)
    assert np.allclose(f.origin[0, 0], v[t[0, 0]])
    assert np.allclose(f.origin[1, 1], 0.2 * v[t[1, 0]] + 0.3 * v[t[1, 1]] + 0.5 * v[t[1, 2]])
    tri, bary = locate_on_mesh(v, t, f.origin.reshape(-1, 3))
    assert np.allclose(np.einsum("kc,kcd->kd", bary, v[t[tri]]), f.origin.reshape(-1, 3))


def test_bad_anchors_are_input_errors():
    v, t = plane(2, 2)
    good = Anchor(0, (1.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    with pytest.raises(InputError, match="at least 2"):
        AnchorArray.of([good])
    with pytest.raises(InputError, match="equal length"):
        AnchorArray.of([[good, good], [good]])
    with pytest.raises(InputError, match="summing to 1"):
        AnchorArray.of([good, Anchor(0, (0.5, 0.0, 0.0), (0.0, 1.0, 0.0))])
    with pytest.raises(InputError, match="out of range"):
        AnchorArray.of([good, Anchor(99, (1.0, 0.0, 0.0), (0.0, 1.0, 0.0))]).frames(v, t)
    with pytest.raises(InputError, match="tangent point"):
        AnchorArray.of([good, Anchor(0, (1.0, 0.0, 0.0), (1.0, 0.0, 0.0))]).frames(v, t)
    with pytest.raises(InputError, match="does not project"):
        locate_on_mesh(v, t, np.array([[10.0, 10.0, 0.0]]))
    with pytest.raises(InputError, match="1D or 2D"):
        attachment_grid(AnchorArray.of([good, good]).frames(v, t).__class__(*(np.zeros((2, 2, 2, 3)),) * 4),
                        OBJECT)
