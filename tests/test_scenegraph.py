"""The trilinear scene graph on the CPU: traversal, composition (4.1), draw-path choice (3.2)."""

import numpy as np
import pytest

from deformgl.errors import GLError, InputError
from deformgl.trilinear.scenegraph import compose_scene
from deformgl.trilinear.graph_nodes import Geometry, GeometryNode, GroupNode, TransformNode
from deformgl.trilinear.renderer import atlas_image, instance_data, pack_atlas, shader_defines
from deformgl.trilinear.transforms import (
    Bend, Box, Taper, Trilinear, Twist, apply_coefficients, coefficient_matrix, compose, trilinear_corners,
)
from deformgl.trilinear.scenes import depth_scene, tile_scene, tubes_scene
from deformgl.trilinear.shapes import uv_sphere

RNG = np.random.default_rng(7)


def cloud(n=200, lo=(-1.0, -1.0, 0.0), hi=(1.0, 1.0, 2.0)):
    v = RNG.uniform(lo, hi, (n, 3))
    v[:8] = Box(np.array(lo), np.array(hi)).corners()  # the box of the cloud is exactly (lo, hi)
    return Geometry(v, RNG.normal(size=(n, 3)), np.zeros((0, 3)), "cloud")


def affine(rng):
    m = np.identity(4)
    m[:3, :3] = rng.normal(size=(3, 3))
    m[:3, 3] = rng.normal(size=3)
    return m


def test_nested_affine_nodes_compose_to_the_matrix_product():
    a, b, c = affine(RNG), affine(RNG), affine(RNG)
    leaf = GeometryNode(cloud())
    root = TransformNode(a, [GroupNode([TransformNode(b, [TransformNode(c, [leaf])])])])
    scene = compose_scene(root)
    t, path = scene.transform_of(leaf)
    assert path == "affine"
    assert np.allclose(t, a @ b @ c, rtol=0, atol=1e-12)


def test_a_leaf_whose_composed_transform_is_linear_takes_the_affine_path():
    geo = cloud()
    a, b = affine(RNG), affine(RNG)
    as_grid = Trilinear.from_affine(b, geo.box, cells=(3, 3, 3))  # linear, but given as a grid
    leaf = GeometryNode(geo)
    scene = compose_scene(TransformNode(a, [TransformNode(as_grid, [leaf])]))
    t, path = scene.transform_of(leaf)
    assert path == "affine" and scene.paths() == {"affine": 1, "cuboid": 0, "grid": 0}
    assert np.allclose(t, a @ b, rtol=0, atol=1e-10)
    bent = GeometryNode(geo)
    scene = compose_scene(TransformNode(Trilinear.from_function(Twist(0.8), geo.box, (3, 3, 3)), [bent]))
    assert scene.transform_of(bent)[1] == "grid"
    corners = geo.box.corners() + RNG.normal(scale=0.2, size=(8, 3))
    one = GeometryNode(geo)
    scene = compose_scene(TransformNode(Trilinear.from_corners(geo.box, corners), [one]))
    t, path = scene.transform_of(one)
    assert path == "cuboid" and np.allclose(t.corners, corners)


def test_scene_graph_composition_equals_composing_by_hand():
    geo = cloud()
    twist = Trilinear.from_function(Twist(1.0), geo.box, (6, 6, 6))
    outer = Box(np.array([-1.5, -1.5, -0.5]), np.array([1.5, 1.5, 2.5]))
    bend = Trilinear.from_function(Bend(3.0), outer, (6, 6, 6))
    move = np.identity(4)
    move[:3, 3] = [0.1, -0.2, 0.05]
    leaf = GeometryNode(geo)
    scene = compose_scene(TransformNode(bend, [TransformNode(move, [TransformNode(twist, [leaf])])]))
    t, path = scene.transform_of(leaf)
    by_hand = compose(bend, twist, between=move)
    assert path == "grid" and t.cells == by_hand.cells
    assert np.allclose(t.points, by_hand.points, rtol=0, atol=1e-12)
    p = geo.vertices
    exact = Bend(3.0)(Twist(1.0)(p) + move[:3, 3])
    assert np.linalg.norm(t(p) - exact, axis=1).max() < 0.05


def test_leaf_resolution_is_the_parent_cells_it_crosses():
    geo = uv_sphere(0.25, 8, 6)   # box 0.5 wide
    parent = Trilinear.from_function(Bend(2.0), Box(np.full(3, -2.0), np.full(3, 2.0)), (16, 16, 16))
    leaf = GeometryNode(geo)
    move = np.identity(4)
    move[:3, 3] = [0.3, -0.2, 0.1]
    t, path = compose_scene(TransformNode(parent, [TransformNode(move, [leaf])])).transform_of(leaf)
    assert path == "grid" and t.cells == (2, 2, 2)  # 0.5 / (4 / 16) cells per axis
    assert t.box.lo == pytest.approx(geo.box.lo) and t.box.hi == pytest.approx(geo.box.hi)
    p = geo.vertices
    assert np.linalg.norm(t(p) - Bend(2.0)(p + move[:3, 3]), axis=1).max() < 2 * parent.error + 1e-3
    # scaled by 4 along x: crosses 8 cells there
    s = np.diag([4.0, 1.0, 1.0, 1.0])
    t, _ = compose_scene(TransformNode(parent, [TransformNode(s, [leaf])])).transform_of(leaf)
    assert t.cells == (8, 2, 2)
    # right under the grid node (no affine between) the leaf is drawn with the node's grid itself
    t, _ = compose_scene(TransformNode(parent, [leaf])).transform_of(leaf)
    assert t.cells == (16, 16, 16) and np.array_equal(t.points, parent.points)
    assert np.allclose([t.box.lo, t.box.hi], [parent.box.lo, parent.box.hi], rtol=0, atol=1e-15)


def test_depth_1_and_depth_8_give_the_same_shader_and_per_vertex_work():
    one, eight = compose_scene(depth_scene(1, segments=12, rings=8).root), compose_scene(
        depth_scene(8, segments=12, rings=8).root)
    (b1,), (b8,) = one.batches, eight.batches
    assert b1.path == b8.path == "grid"
    assert shader_defines(b1.path, b1.normals) == shader_defines(b8.path, b8.normals)
    assert b1.grids[0].shape == b8.grids[0].shape == (1, 9, 9, 9, 3)
    assert instance_data(b1, origins=np.zeros((1, 3))).shape == instance_data(b8, origins=np.zeros((1, 3))).shape
    # the depth-8 grid approximates the eight functions applied in order
    built = depth_scene(8, segments=12, rings=8)
    p = b8.geometry.vertices
    exact = p
    for level in range(8):
        exact = (Twist(0.6 / 8) if level % 2 == 0 else Taper(0.15 / 8))(exact)
    (t,) = b8.transforms()
    stated = sum(g.error for g in built.grids.values())
    assert np.linalg.norm(t(p) - exact, axis=1).max() < 3 * stated + 1e-9


def test_normal_mode_and_colour_are_inherited_and_split_batches():
    geo = cloud()
    a = GeometryNode(geo, colour=(1, 0, 0))
    b = GeometryNode(geo, colour=(1, 0, 0), normals="direct")
    c = GeometryNode(geo, colour=(0, 1, 0))
    root = GroupNode([GroupNode([a, b], normals="tangent"), c])
    scene = compose_scene(root)
    modes = {id(leaf): batch.normals for batch in scene.batches for leaf in batch.leaves}
    assert modes[id(a)] == "tangent" and modes[id(b)] == "direct" and modes[id(c)] == "direct"
    assert len(scene.batches) == 3 and scene.leaf_count == 3


def test_tubes_stay_in_contact_with_trilinear_transforms_and_not_with_linear_ones():
    """Figure 1 as numbers: the end face of tube (i, j) against the start face of tube (i+1, j)."""
    gaps = {}
    for mode in ("linear", "trilinear"):
        built = tubes_scene(mode, along=6, around=8)
        scene = compose_scene(built.root)
        leaves = [n for n in built.root.walk() if isinstance(n, GeometryNode)]
        geo = leaves[0].geometry
        end = geo.vertices[np.isclose(geo.vertices[:, 0], 1.0)]
        start = end - [1.0, 0.0, 0.0]

        def world(leaf, p):
            t, _ = scene.transform_of(leaf)
            return t(p) if isinstance(t, Trilinear) else p @ t[:3, :3].T + t[:3, 3]

        gaps[mode] = max(np.linalg.norm(world(leaves[k * 8], end) - world(leaves[(k + 1) * 8], start), axis=1).max()
                         for k in range(5))
    assert gaps["trilinear"] < 1e-9
    assert gaps["linear"] > 0.05


def test_tiles_join_seamlessly_on_the_torus():
    built = tile_scene(along=6, around=4)
    scene = compose_scene(built.root)
    assert scene.paths()["grid"] == 24
    leaves = [n for n in built.root.walk() if isinstance(n, GeometryNode)]
    y = np.linspace(0.0, 1.0, 7)
    edge = np.stack([np.ones(7), y, np.full(7, 0.02)], 1)
    left, _ = scene.transform_of(leaves[0])       # tile (0, 0)
    right, _ = scene.transform_of(leaves[4])      # tile (1, 0)
    assert np.allclose(left(edge), right(edge - [1.0, 0.0, 0.0]), rtol=0, atol=1e-9)


def test_reference_and_bounds_of_batches():
    geo = cloud()
    corners = geo.box.corners() + RNG.normal(scale=0.2, size=(8, 3))
    t = Trilinear.from_corners(geo.box, corners)
    scene = compose_scene(TransformNode(t, [GeometryNode(geo)]))
    world, normals = scene.batches[0].reference()
    assert np.allclose(world[0], t(geo.vertices), rtol=0, atol=1e-12)
    assert np.allclose(np.linalg.norm(normals[0], axis=1), 1.0)
    lo, hi = scene.bounds()
    assert np.all(world[0] >= lo - 1e-12) and np.all(world[0] <= hi + 1e-12)


def test_instance_data_layout_of_both_cuboid_forms():
    geo = cloud()
    corners = geo.box.corners() + RNG.normal(scale=0.2, size=(8, 3))
    scene = compose_scene(TransformNode(Trilinear.from_corners(geo.box, corners), [GeometryNode(geo)]))
    batch = scene.batches[0]
    eq4 = instance_data(batch, cuboid_form=4)[0].astype(np.float64)
    eq1 = instance_data(batch, cuboid_form=1)[0].astype(np.float64)
    assert np.allclose(eq4[0:3], geo.box.lo) and np.allclose(eq4[4:7], 1.0 / geo.box.size, rtol=1e-6)
    u = RNG.random((10, 3))
    assert np.allclose(apply_coefficients(eq4[8:].reshape(3, 8), u), trilinear_corners(corners, u), atol=1e-5)
    assert np.allclose(eq1[8:].reshape(3, 8).T, corners, atol=1e-6)
    assert np.allclose(eq4[8:].reshape(3, 8), coefficient_matrix(corners), atol=1e-5)


def test_atlas_packing_has_no_overlap_and_respects_the_limit():
    shapes = [tuple(int(v) for v in RNG.integers(2, 7, 3)) for _ in range(60)]
    offsets, size = pack_atlas(shapes, 24)
    assert max(size) <= 24 and size[2] > 6  # several layers were needed
    occupied = np.zeros(size[::-1], bool)
    for (x, y, z), (sx, sy, sz) in zip(offsets, shapes):
        block = occupied[z:z + sz, y:y + sy, x:x + sx]
        assert block.shape == (sz, sy, sx) and not block.any()
        block[...] = True
    with pytest.raises(GLError, match="3D texture limit"):
        pack_atlas([(17, 2, 2)], 16)
    with pytest.raises(GLError, match="layers"):
        pack_atlas([(16, 16, 9)] * 2, 16)


def test_atlas_image_puts_lattice_points_at_their_texels():
    stacks = [RNG.normal(size=(2, 3, 2, 4, 3)), RNG.normal(size=(1, 2, 5, 2, 3))]
    shapes = [s.shape[1:4] for s in stacks for _ in range(len(s))]
    offsets, size = pack_atlas(shapes, 8)
    image = atlas_image(stacks, offsets, size)
    assert image.shape == (size[2], size[1], size[0], 4) and np.all(image[..., 3] == 1.0)
    lattices = [p for s in stacks for p in s]
    for (x, y, z), p in zip(offsets, lattices):
        i, j, k = 1, p.shape[1] - 1, p.shape[2] - 1
        assert np.allclose(image[z + k, y + j, x + i, :3], p[i, j, k], atol=1e-6)


def test_bad_scene_input_is_an_input_error():
    geo = cloud()
    with pytest.raises(InputError, match="normals"):
        GroupNode(normals="smooth")
    with pytest.raises(InputError, match="cannot have children"):
        GeometryNode(geo).add(GroupNode())
    with pytest.raises(InputError, match="4x4"):
        TransformNode(np.identity(3))
    with pytest.raises(InputError, match="must be a Node"):
        GroupNode(["not a node"])
    with pytest.raises(InputError, match="non-finite"):
        Geometry(np.full((3, 3), np.nan), np.ones((3, 3)), [[0, 1, 2]])
    with pytest.raises(InputError, match="out of range"):
        Geometry(np.eye(3), np.ones((3, 3)), [[0, 1, 3]])
    with pytest.raises(InputError, match="no geometry"):
        compose_scene(GroupNode()).bounds()
