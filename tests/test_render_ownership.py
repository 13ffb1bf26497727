"""GL ownership of the render, mapping and trilinear passes (issue 11): each derives from
:class:`~deformgl.gl.resources.GLOwner`; a constructor failing half-way releases every GL object it
made, and ``release()`` then and later neither raises nor releases twice."""

from __future__ import annotations

import numpy as np
import pytest

from deformgl.gl.resources import GLOwner, is_released
from deformgl.grid.nodes import CompactLayout, NodeGrid
from deformgl.render.mapped import MappedMeshPass, MappedVertices, StaticMeshPass
from deformgl.render.passes import FeedbackCapture, GridSurfacePass, RenderTarget
from deformgl.mapping.node_drivers import DrivenNodes
from deformgl.trilinear.renderer import TrilinearRenderer


class _Created:
    """Records every GL object a context makes, whoever registers it."""

    MAKERS = ("buffer", "texture", "texture3d", "vertex_array", "program", "framebuffer",
              "simple_framebuffer", "renderbuffer", "depth_renderbuffer")

    def __init__(self, ctx, monkeypatch: pytest.MonkeyPatch) -> None:
        self.objects: list = []
        for name in self.MAKERS:
            original = getattr(ctx, name)

            def make(*args, _original=original, **kwargs):
                obj = _original(*args, **kwargs)
                self.objects.append(obj)
                return obj

            monkeypatch.setattr(ctx, name, make)


def _grid_and_data() -> tuple[NodeGrid, CompactLayout, np.ndarray, MappedVertices]:
    grid = NodeGrid(np.zeros(3), 1.0, np.ones((2, 2, 2), bool))
    layout = CompactLayout.for_grid(grid, 256)
    v = 3
    data = MappedVertices(tri_nodes=np.array([[0, 1, 2]] * v), weights=np.full((v, 3), 1 / 3),
                          offset=np.zeros((v, 3)), offset_world=np.zeros((v, 3)),
                          normal=np.tile([0.0, 0.0, 1.0], (v, 1)), normal_world=np.tile([0.0, 0.0, 1.0], (v, 1)),
                          use_curvature=np.zeros(v, bool))
    return grid, layout, np.array([[0, 1, 2]]), data


@pytest.mark.parametrize("cls", [RenderTarget, FeedbackCapture, GridSurfacePass, MappedMeshPass, StaticMeshPass,
                                 DrivenNodes, TrilinearRenderer])
def test_gl_holders_are_gl_owners(cls):
    assert issubclass(cls, GLOwner)


def test_two_stage_set_up_failing_half_way_releases_what_it_made(ctx, monkeypatch):
    """The second stage fails (its program does not build): the buffers, the stage-one capture and
    the mapped buffer made before are all released, and ``release()`` does not raise (it used to
    read ``cached_vao`` before that existed)."""
    import deformgl.render.mapped as mapped_module

    grid, layout, faces, data = _grid_and_data()
    real_program = mapped_module.Program

    def failing_program(ctx_, vertex, *args, **kwargs):
        if vertex == "render/mapped_cached.vert":
            raise RuntimeError("second stage fails")
        return real_program(ctx_, vertex, *args, **kwargs)

    monkeypatch.setattr(mapped_module, "Program", failing_program)
    owners: list[GLOwner] = []
    real_own = GLOwner.own

    def recording_own(self, obj):
        if isinstance(self, MappedMeshPass) and self not in owners:
            owners.append(self)
        return real_own(self, obj)

    monkeypatch.setattr(GLOwner, "own", recording_own)
    created = _Created(ctx, monkeypatch)
    with pytest.raises(RuntimeError, match="second stage fails"):
        MappedMeshPass(ctx, grid, layout, faces, data, mapping_pass="feedback")
    assert len(created.objects) >= 5  # vertex buffers, index buffer, capture program/vao/fbo, mapped buffer
    assert [obj for obj in created.objects if not is_released(obj)] == []
    (half_built,) = owners
    assert half_built.released and half_built.owned_count == 0
    half_built.release()  # again: does nothing, does not raise


def test_two_stage_pass_releases_everything_once(ctx, monkeypatch):
    grid, layout, faces, data = _grid_and_data()
    created = _Created(ctx, monkeypatch)
    with MappedMeshPass(ctx, grid, layout, faces, data, mapping_pass="feedback") as draw:
        assert draw.owned_count > 0
    assert created.objects and all(is_released(obj) for obj in created.objects)
    draw.release()


def test_render_target_failing_half_way_releases_what_it_made(ctx, monkeypatch):
    created = _Created(ctx, monkeypatch)
    real = ctx.framebuffer
    calls = {"n": 0}

    def second_framebuffer_fails(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:
            raise RuntimeError("resolve framebuffer fails")
        return real(*args, **kwargs)

    monkeypatch.setattr(ctx, "framebuffer", second_framebuffer_fails)
    with pytest.raises(RuntimeError, match="resolve framebuffer fails"):
        RenderTarget(ctx, (8, 8), samples=4)
    assert len(created.objects) >= 3 and all(is_released(obj) for obj in created.objects)


def test_trilinear_renderer_releases_everything_it_made_and_binds_back_the_callers_framebuffer(ctx, monkeypatch):
    from deformgl.render.camera import frame_box
    from deformgl.render.passes import Lighting
    from deformgl.trilinear.cuboid import Box
    from deformgl.trilinear.deformations import Twist
    from deformgl.trilinear.grid import Trilinear
    from deformgl.trilinear.shapes import uv_sphere
    from deformgl.trilinear.scenegraph import compose_scene
    from deformgl.trilinear.graph_nodes import GeometryNode, GroupNode, TransformNode

    sphere = uv_sphere(0.4, 8, 6)
    box = Box(np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0]))
    twisted = Trilinear.from_function(Twist(0.8), box, (2, 2, 2))
    shifted = np.identity(4)
    shifted[0, 3] = 0.3
    root = GroupNode([TransformNode(shifted, [GeometryNode(sphere)]),
                      TransformNode(twisted, [GeometryNode(sphere)])])
    scene = compose_scene(root)
    created = _Created(ctx, monkeypatch)
    target = RenderTarget(ctx, (32, 32), samples=0)
    with TrilinearRenderer(ctx) as renderer:
        target.begin((1.0, 1.0, 1.0))
        lo, hi = scene.bounds()
        renderer.draw(scene, frame_box(lo, hi, projection="perspective", azimuth=20.0, elevation=20.0,
                                       fov=40.0, distance=3.0, target=np.full(3, 0.5), aspect=1.0), Lighting((0.3, 0.5, 1.0)))
        renderer.capture(scene)
        assert ctx.fbo.glo == target.fbo.glo  # the caller's framebuffer is bound again
        made = [obj for obj in created.objects if obj not in (target.fbo, target.colour, target.depth)]
    assert made and all(is_released(obj) for obj in made)
    assert not is_released(target.fbo)
    target.release()
    renderer.release()


def test_driven_nodes_release_their_pass_not_the_textures(ctx):
    from deformgl.grid.nodes import NodeGrid
    from deformgl.sim.backends.verlet_data import NodeTextures

    grid = NodeGrid(np.zeros(3), 1.0, np.ones((2, 2, 2), bool))
    textures = NodeTextures(ctx, grid)
    nodes = DrivenNodes(ctx, textures, grid)
    nodes.set_positions(grid.rest_positions)
    program = nodes.program
    nodes.release()
    nodes.release()
    assert is_released(program.gl) and nodes.owned_count == 0
    assert not is_released(textures.state[0])
    textures.release()
