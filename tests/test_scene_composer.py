"""SceneComposer: composing a scene graph frame after frame, recomposing only what changed
(Knuth, Kohlhammer & Kuijper, section 4.1), with the output of compose_scene bit for bit."""

import numpy as np

from deformgl.trilinear.scenegraph import SceneComposer, compose_scene
from deformgl.trilinear.graph_nodes import GeometryNode, GroupNode, TransformNode
from deformgl.trilinear.scenes import depth_scene, helix_scene
from deformgl.trilinear.shapes import uv_sphere


def same(a, b):
    """Two composed scenes are identical: batches, leaves (by identity) and every array."""
    assert len(a.batches) == len(b.batches)
    for x, y in zip(a.batches, b.batches):
        assert (x.geometry, x.path, x.normals, x.colour) == (y.geometry, y.path, y.normals, y.colour)
        assert [id(leaf) for leaf in x.leaves] == [id(leaf) for leaf in y.leaves]
        for name in ("affine", "box_lo", "box_size", "corners"):
            u, v = getattr(x, name), getattr(y, name)
            assert (u is None and v is None) or np.array_equal(u, v), name
        assert len(x.grids) == len(y.grids) and all(np.array_equal(u, v) for u, v in zip(x.grids, y.grids))
    return True


def test_unchanged_frames_reuse_every_leaf_and_match():
    root = helix_scene("trilinear", 40, segments=6, rings=4).root
    composer = SceneComposer()
    first = composer.compose(root)
    assert composer.recomposed == 40 and composer.reused == 0
    assert same(first, compose_scene(root))
    again = composer.compose(root)
    assert composer.recomposed == 0 and composer.reused == 40
    assert same(again, compose_scene(root))


def test_a_changed_affine_recomposes_its_group_and_matches():
    root = helix_scene("trilinear", 40, segments=6, rings=4).root
    composer = SceneComposer()
    composer.compose(root)
    grid_node = root.children[0]
    leaf_parent = grid_node.children[7]
    before = compose_scene(root)
    leaf_parent.transform[0, 3] += 0.05  # changed in place: found by content
    out = composer.compose(root)
    # the helix alternates two meshes: the moved leaf's group (20 leaves) only
    assert composer.recomposed == 20 and composer.reused == 20
    assert same(out, compose_scene(root))
    assert any(not np.array_equal(x.corners, y.corners) for x, y in zip(out.batches, before.batches))
    out = composer.compose(root)
    assert composer.recomposed == 0 and same(out, compose_scene(root))


def test_only_the_changed_group_is_recomposed():
    """Two meshes under one grid: moving a leaf of one leaves the other's group as it was."""
    root = helix_scene("trilinear", 20, segments=6, rings=4).root
    grid_node = root.children[0]
    other = uv_sphere(0.3, 8, 6, name="small")
    for k in range(5):  # at the places of the first five objects
        m = np.array(grid_node.children[k].transform, copy=True)
        grid_node.add(TransformNode(m, [GeometryNode(other, colour=(0.2, 0.3, 0.9))]))
    composer = SceneComposer()
    composer.compose(root)
    assert composer.recomposed == 25
    grid_node.children[-1].transform = grid_node.children[-1].transform @ np.diag([1.0, 1.1, 1.0, 1.0])
    out = composer.compose(root)
    assert composer.recomposed == 5 and composer.reused == 20
    assert same(out, compose_scene(root))


def test_a_changed_grid_recomposes_the_chain_below_it():
    scene = depth_scene(3)
    root = scene.root
    composer = SceneComposer()
    composer.compose(root)
    middle = root.children[0]
    assert isinstance(middle, TransformNode)
    middle.transform.points[1, 1, 1] += 0.01  # a lattice point moved in place
    out = composer.compose(root)
    assert composer.recomposed == 1 and same(out, compose_scene(root))
    assert composer.compose(root) is not out and composer.reused == 1


def test_affine_only_and_shared_nodes():
    """Leaves without a grid, and one grid node reached twice on one chain, as compose_scene."""
    sphere = uv_sphere(0.5, 8, 6)
    root = helix_scene("trilinear", 6, segments=6, rings=4).root
    grid_node = root.children[0]
    group = GroupNode([grid_node, GeometryNode(sphere)])
    twice = GroupNode([group, group])
    composer = SceneComposer()
    for _ in range(2):
        assert same(composer.compose(twice), compose_scene(twice))
