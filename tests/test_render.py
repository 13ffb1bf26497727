"""Render target, cameras and the progress bar."""

import io
import time

import numpy as np
import pytest

from deformgl.render.camera import frame_box, look_at, orthographic, perspective
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.backends.verlet_data import NodeTextures
from deformgl.progress import Progress
from deformgl.render.passes import GridSurfacePass, Lighting, RenderTarget


def block_grid():
    return NodeGrid(np.array([-0.2, -0.1, -0.15]), 0.1, np.ones((5, 3, 4), bool))


def render(ctx, *, projection="perspective", azimuth=30.0, elevation=20.0, samples=4, size=(160, 120),
           overlay=False, background=(1.0, 1.0, 1.0)):
    grid = block_grid()
    sim = NodeTextures(ctx, grid)  # the rest state and its packed normals
    target = RenderTarget(ctx, size, samples)
    surface = GridSurfacePass(ctx, grid, sim.layout, overlay=overlay)
    try:
        lo, hi = grid.rest_positions.min(0), grid.rest_positions.max(0)
        view = frame_box(lo, hi, projection=projection, azimuth=azimuth, elevation=elevation, fov=35.0,
                         distance=1.6, target=np.full(3, 0.5), aspect=size[0] / size[1])
        target.begin(background)
        surface.draw(sim.state[0], view, Lighting(direction=(0.2, 0.5, 1.0)))
        return target.read_rgb()
    finally:
        surface.release()
        target.release()
        sim.release()


def object_mask(img, background=(255, 255, 255)):
    return np.any(np.abs(img.astype(int) - np.array(background)) > 3, axis=2)


def test_orthographic_front_view_of_a_block_is_a_filled_rectangle(ctx):
    img = render(ctx, projection="orthographic", azimuth=0.0, elevation=0.0, samples=0)
    mask = object_mask(img)
    rows, cols = np.nonzero(mask)
    box = mask[rows.min():rows.max() + 1, cols.min():cols.max() + 1]
    assert box.all()  # the front face exactly covers its bounding rectangle
    # aspect of the front face is 4:2 (grid 5x3 nodes, spacing 0.1)
    assert (np.ptp(cols) + 1) / (np.ptp(rows) + 1) == pytest.approx(2.0, rel=0.05)


def test_perspective_shows_foreshortening(ctx):
    ortho = object_mask(render(ctx, projection="orthographic", azimuth=0.0, elevation=0.0, samples=0))
    persp = object_mask(render(ctx, projection="perspective", azimuth=0.0, elevation=0.0, samples=0))
    assert not np.array_equal(ortho, persp)


def test_msaa_smooths_edges(ctx):
    plain = render(ctx, samples=0)
    msaa = render(ctx, samples=4)
    assert plain.shape == msaa.shape == (120, 160, 3)
    # antialiased edges blend object and background: more distinct colours along silhouettes
    assert len(np.unique(msaa.reshape(-1, 3), axis=0)) > len(np.unique(plain.reshape(-1, 3), axis=0))
    assert abs(object_mask(plain).mean() - object_mask(msaa).mean()) < 0.02


def test_background_colour_and_overlay(ctx):
    img = render(ctx, background=(0.0, 0.0, 1.0), overlay=True)
    assert np.array_equal(img[0, 0], [0, 0, 255])
    plain = render(ctx, background=(0.0, 0.0, 1.0))
    # the overlay draws dark spring lines and red node points over the surface
    reddish = (img[..., 0] > 150) & (img[..., 1] < 60) & (img[..., 2] < 60)
    assert reddish.sum() > 20 and not np.array_equal(img, plain)


def test_too_many_samples_is_an_error(ctx):
    from deformgl.errors import GLError

    with pytest.raises(GLError, match="MSAA"):
        RenderTarget(ctx, (8, 8), 1024)


def test_camera_matrices():
    v = look_at(np.array([0.0, 0.0, 5.0]), np.zeros(3), np.array([0.0, 1.0, 0.0]))
    assert np.allclose(v @ [0, 0, 0, 1], [0, 0, -5, 1])
    p = perspective(90.0, 1.0, 1.0, 10.0)
    near = p @ [0, 0, -1, 1]
    far = p @ [0, 0, -10, 1]
    assert near[2] / near[3] == pytest.approx(-1.0) and far[2] / far[3] == pytest.approx(1.0)
    o = orthographic(2.0, 2.0, 1.0, 3.0)
    assert np.allclose(o @ [4, 2, -1, 1], [1, 1, -1, 1])


def test_progress_bar_only_after_delay():
    out = io.StringIO()
    with Progress(10, "steps", delay=10.0, stream=out) as bar:
        bar.update(5)
    assert out.getvalue() == ""
    out = io.StringIO()
    with Progress(10, "steps", delay=0.0, stream=out) as bar:
        time.sleep(0.001)
        bar.update(5)
    text = out.getvalue()
    assert "5/10 steps" in text and text.endswith("\n") and "#" * 15 in text
