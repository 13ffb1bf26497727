"""Back-face culling of the detailed mesh ([render] cull): when a mesh may be culled, that the
draw really culls and leaves the GL state as it found it, and that a closed surface's image is
unchanged by it."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import trimesh

from deformgl.grid.nodes import NodeGrid
from deformgl.render.camera import frame_box
from deformgl.render.mapped import MappedMeshPass, StaticMeshPass, closed_front_face
from deformgl.render.passes import Lighting, RenderTarget
from deformgl.scene.pipeline import render_scene
from deformgl.scene.schema import load_scene
SCENES = Path(__file__).resolve().parent.parent / "scenes"


def test_a_closed_consistent_mesh_may_be_culled_with_its_own_winding():
    box = trimesh.creation.box()
    assert closed_front_face(box.vertices, box.faces) == "ccw"
    assert closed_front_face(box.vertices, box.faces[:, ::-1]) == "cw"  # wound inward


def test_open_or_inconsistent_meshes_are_never_culled():
    box = trimesh.creation.box()
    assert closed_front_face(box.vertices, box.faces[1:]) is None  # a hole
    flipped = box.faces.copy()
    flipped[0] = flipped[0, ::-1]
    assert closed_front_face(box.vertices, flipped) is None  # one face turned over
    assert closed_front_face(box.vertices, box.faces[:0]) is None


def test_shells_wound_against_each_other_are_not_culled():
    """An outward box beside a smaller inward-wound one: every edge balances and the total volume
    is positive, but culling would take the inward shell's near faces."""
    a = trimesh.creation.box()
    b = trimesh.creation.box(extents=(0.6, 0.6, 0.6))
    b.apply_translation([1.5, 0.0, 0.0])
    b.invert()
    both = trimesh.util.concatenate([a, b])
    assert closed_front_face(both.vertices, both.faces) is None
    b.invert()
    same = trimesh.util.concatenate([a, b])
    assert closed_front_face(same.vertices, same.faces) == "ccw"


def test_a_sliver_shell_wound_either_way_does_not_stop_the_culling():
    """A shell under a millionth of the largest's volume (the res3 dragon has a 6-face one of
    1.6e-12 m^3 beside its 4.8e-4 m^3 body) covers a pixel at most: it does not count."""
    body = trimesh.creation.box()
    sliver = trimesh.creation.box(extents=(1e-3, 1e-3, 1e-3))
    sliver.apply_translation([2.0, 0.0, 0.0])
    sliver.invert()
    both = trimesh.util.concatenate([body, sliver])
    assert closed_front_face(both.vertices, both.faces) == "ccw"


def test_an_edge_shared_by_four_faces_still_counts_as_closed():
    """Two boxes touching along an edge (as scanned meshes have): closed, consistent."""
    a = trimesh.creation.box()
    b = trimesh.creation.box()
    b.apply_translation([1.0, 1.0, 0.0])  # (shares the edge x = y = 0.5)
    both = trimesh.util.concatenate([a, b])
    both.merge_vertices()
    edges = np.sort(both.edges, axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert counts.max() == 4
    assert closed_front_face(both.vertices, both.faces) == "ccw"


def _draw(ctx, pass_, view, size=(96, 96)) -> np.ndarray:
    target = RenderTarget(ctx, size, 0)
    try:
        target.begin((1.0, 1.0, 1.0))
        pass_.draw(view, Lighting(direction=(0.3, 0.6, 1.0)))
        return target.read_rgb()
    finally:
        target.release()


def test_culling_draws_what_faces_the_eye_and_turns_itself_off(ctx):
    """A closed box: culling the back faces ("ccw") gives the image of drawing all of them; culling
    the front ones ("cw") shows only the far inside, a different image; and a draw after a culled
    one is not culled (the pass restores the state)."""
    box = trimesh.creation.box()
    view = frame_box(box.vertices.min(0), box.vertices.max(0), projection="perspective", azimuth=30.0, elevation=25.0, fov=40.0,
                     distance=2.5, target=np.full(3, 0.5), aspect=1.0)
    passes = {f: StaticMeshPass(ctx, box.vertices, box.vertex_normals, box.faces, front_face=f)
              for f in (None, "ccw", "cw")}
    # wound inward: its near faces are back faces, drawn unless culling stays on
    passes["inward"] = StaticMeshPass(ctx, box.vertices, -box.vertex_normals, box.faces[:, ::-1])
    try:
        inward = _draw(ctx, passes["inward"], view)
        everything = _draw(ctx, passes[None], view)
        assert np.array_equal(_draw(ctx, passes["ccw"], view), everything)
        inside = _draw(ctx, passes["cw"], view)
        assert np.abs(inside.astype(int) - everything.astype(int)).max() > 30
        # culling is off again, the front face "ccw" again
        assert np.array_equal(_draw(ctx, passes[None], view), everything)
        assert np.array_equal(_draw(ctx, passes["ccw"], view), everything)
        assert np.array_equal(_draw(ctx, passes["inward"], view), inward)
    finally:
        for p in passes.values():
            p.release()


def test_mapped_mesh_pass_refuses_an_unknown_winding(ctx):
    grid = NodeGrid(np.zeros(3), 0.1, np.ones((2, 2, 2), bool))
    with pytest.raises(ValueError, match="front_face"):
        MappedMeshPass(ctx, grid, None, np.zeros((0, 3), int), None, front_face="up")  # type: ignore[arg-type]


def test_cull_leaves_a_closed_unfolded_mesh_scene_as_it_was(ctx):
    """The jelly (its closed box mesh drawn through the constant mapping, no fold): the same pixels culled or not; the fin
    (a scanned mesh whose surface meets itself in places) differs only in a handful of pixels,
    where a back face showed."""
    from deformgl.scene.pipeline import build_scene_model, make_draw_pass
    from deformgl.sim.backends.verlet_data import NodeTextures
    for name, most in (("jelly", 0), ("fin", 20)):
        scene = load_scene(SCENES / f"{name}.toml").with_overrides(steps=50, mapping="constant")
        assert scene.render.cull is False  # (the default)
        culled = dataclasses.replace(scene, render=dataclasses.replace(scene.render, cull=True))
        built = build_scene_model(culled)
        textures = NodeTextures(ctx, built.grid)
        try:
            for s, front in ((scene, None), (culled, "ccw")):  # (the renderer's draw pass takes the setting)
                draw = make_draw_pass(ctx, s, built, textures.layout)
                try:
                    assert isinstance(draw, MappedMeshPass) and draw.front_face == front, name
                finally:
                    draw.release()
        finally:
            textures.release()
        a, b = render_scene(ctx, scene), render_scene(ctx, culled)
        off = np.abs(a.astype(int) - b.astype(int)).max(axis=2) > 4
        assert off.sum() <= most, name


@pytest.mark.parametrize("mapping_pass", ["vertex", "feedback", "fragment"])
def test_every_mapping_pass_culls_either_winding(ctx, mapping_pass):
    """The jelly's box mesh wound outward and inward: culled with its own winding, every mapping
    pass draws what it draws unculled (the fragment pass's full-screen triangle runs before the
    culling, so "cw" does not cull the mapping away)."""
    from deformgl.render.mapped_setup import get_binding, mapped_vertices
    from deformgl.scene.pipeline import build_scene_model, scene_lighting, scene_view
    from deformgl.sim.backends.verlet_data import NodeTextures
    from deformgl.sim.normals import rest_normals
    from deformgl.grid.surface import grid_surface

    scene = load_scene(SCENES / "jelly.toml").with_overrides(size=(96, 72))
    built = build_scene_model(scene)
    textures = NodeTextures(ctx, built.grid)
    binding = get_binding(built.mesh, built.grid, grid_surface(built.grid), use_cache=False, uv=None)
    data = mapped_vertices(binding, "constant", built.grid.rest_positions, rest_normals(built.grid))
    view, lighting = scene_view(scene, built.bbox), scene_lighting(scene)
    try:
        for faces in (built.mesh.faces, built.mesh.faces[:, ::-1]):
            front = closed_front_face(built.mesh.vertices, faces)
            images = []
            for f in (None, front):
                draw = MappedMeshPass(ctx, built.grid, textures.layout, faces, data, mapping_pass=mapping_pass,
                                      front_face=f)
                target = RenderTarget(ctx, scene.render.size, 0)
                try:
                    target.begin((1.0, 1.0, 1.0))
                    draw.draw(textures.state[0], view, lighting)
                    images.append(target.read_rgb())
                finally:
                    target.release()
                    draw.release()
            assert front is not None
            assert (np.abs(images[0].astype(int) - 255).max(axis=2) > 3).any()
            assert np.array_equal(images[0], images[1]), (mapping_pass, front)
    finally:
        textures.release()
