"""The trilinear vertex shader against the float64 NumPy reference, captured with transform
feedback (Knuth, Kohlhammer & Kuijper eq. 1-4, grids by 3D-texture filtering, normals of 4.2)."""

import numpy as np
import pytest

from deformgl.render.camera import frame_box
from deformgl.render.passes import Lighting, RenderTarget
from deformgl.trilinear.scenegraph import compose_scene
from deformgl.trilinear.graph_nodes import Geometry, GeometryNode, GroupNode, TransformNode
from deformgl.trilinear.renderer import TrilinearRenderer
from deformgl.trilinear.transforms import Box, Trilinear, Twist, finite_difference_jacobian, unit_lattice

RNG = np.random.default_rng(99)
BOX = Box(np.array([-1.0, -0.5, 0.0]), np.array([1.0, 0.5, 3.0]))
REL = 1e-5


def random_points(n, cells=None, margin=0.0):
    """Points of BOX (its 8 corners first); with cells, kept ``margin`` away from cell borders."""
    if cells is None:
        u = RNG.random((n, 3))
    else:
        c = np.array(cells)
        u = (np.floor(RNG.random((n, 3)) * c) + RNG.uniform(margin, 1 - margin, (n, 3))) / c
    if margin == 0.0:
        u[:8] = Box(np.zeros(3), np.ones(3)).corners()
    return BOX.from_unit(u)


def geometry(points):
    n = RNG.normal(size=points.shape)
    return Geometry(points, n, np.zeros((0, 3)), "points")


def random_grid(cells, noise=0.15):
    base = BOX.from_unit(unit_lattice(cells))
    return Trilinear(BOX, base + RNG.normal(scale=noise, size=base.shape))


def random_affine():
    m = np.identity(4)
    m[:3, :3] = RNG.normal(size=(3, 3))
    m[:3, 3] = RNG.normal(size=3) * 4
    return m


def capture(ctx, transforms, geo, *, normals="direct", cuboid_form=4, max_3d=None):
    """Capture one leaf per transform (all sharing ``geo``); returns (scene, [(world, normal)])."""
    root = GroupNode([TransformNode(t, [GeometryNode(geo, normals=normals)]) for t in transforms])
    scene = compose_scene(root)
    renderer = TrilinearRenderer(ctx, cuboid_form=cuboid_form)
    if max_3d is not None:
        renderer.max_3d = max_3d
    try:
        return scene, renderer.capture(scene)
    finally:
        renderer.release()


def apply(t, p):
    return t(p) if isinstance(t, Trilinear) else p @ t[:3, :3].T + t[:3, 3]


def check_positions(transforms, geo, scene, results, path):
    assert [b.path for b in scene.batches] == [path]
    (world, _), = results
    assert world.shape == (len(transforms), len(geo.vertices), 3)
    for t, got in zip(transforms, world):
        ref = apply(t, geo.vertices)
        err = np.abs(got - ref).max() / np.abs(ref).max()
        assert err <= REL, f"{path}: relative error {err:.2e}"


@pytest.mark.parametrize("form", [4, 1])
def test_single_cuboids_on_the_gpu_match_numpy(ctx, form):
    geo = geometry(random_points(2000))
    cuboids = [Trilinear.from_corners(BOX, BOX.corners() + RNG.normal(scale=0.4, size=(8, 3)) * s)
               for s in (0.1, 1.0, 3.0, 10.0)]
    scene, results = capture(ctx, cuboids, geo, cuboid_form=form)
    check_positions(cuboids, geo, scene, results, "cuboid")


def test_grids_by_3d_texture_filtering_match_numpy(ctx):
    geo = geometry(random_points(3000))
    grids = [random_grid(c) for c in ((3, 4, 5), (1, 2, 7), (6, 1, 1), (2, 2, 2), (5, 5, 5))]
    grids.append(Trilinear.from_function(Twist(1.1), BOX, (4, 4, 12)))
    # a small atlas limit forces several rows and layers: every block's offset is exercised
    scene, results = capture(ctx, grids, geo, max_3d=14)
    check_positions(grids, geo, scene, results, "grid")


def test_grid_lattice_points_land_on_texel_centres(ctx):
    grid = random_grid((3, 4, 5))
    lattice = grid.box.from_unit(unit_lattice(grid.cells)).reshape(-1, 3)
    scene, ((world, _),) = capture(ctx, [grid], geometry(lattice))
    # half a texel off would move each point by up to half a cell (about 0.3 here)
    assert np.abs(world[0] - grid.points.reshape(-1, 3)).max() < 1e-5


def test_affine_fast_path_matches_numpy(ctx):
    geo = geometry(random_points(2000))
    mats = [random_affine() for _ in range(5)]
    scene, results = capture(ctx, mats, geo)
    check_positions(mats, geo, scene, results, "affine")
    # the same matrices given as trilinear grids are recognised as linear: same path, same result
    as_grids = [Trilinear.from_affine(m, geo.box, (2, 3, 2)) for m in mats]
    scene2, results2 = capture(ctx, as_grids, geo)
    check_positions(mats, geo, scene2, results2, "affine")


def fd_normals(t, points, normals, mode):
    j = finite_difference_jacobian(lambda q: apply(t, q), points, 1e-6)
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    if mode == "direct":
        out = np.einsum("nij,nj->ni", j, n)
    else:
        out = np.einsum("nji,nj->ni", np.linalg.inv(j), n)  # J^-T n: orthogonal to deformed tangents
    return out / np.linalg.norm(out, axis=1, keepdims=True)


@pytest.mark.parametrize("mode", ["direct", "tangent"])
@pytest.mark.parametrize("kind, form", [("affine", 4), ("cuboid", 4), ("cuboid", 1), ("grid", 4)])
def test_normals_both_ways_match_finite_difference_jacobian(ctx, mode, kind, form):
    if kind == "affine":
        t, cells = random_affine(), None
    elif kind == "cuboid":
        t, cells = Trilinear.from_corners(BOX, BOX.corners() + RNG.normal(scale=0.3, size=(8, 3))), None
    else:
        t, cells = random_grid((3, 2, 4), noise=0.08), (3, 2, 4)
    geo = geometry(random_points(1500, cells, margin=0.05))
    scene, ((_, got),) = capture(ctx, [t], geo, normals=mode, cuboid_form=form)
    assert scene.batches[0].path == kind
    expected = fd_normals(t, geo.vertices, geo.normals, mode)
    assert np.abs(got[0] - expected).max() < 1e-4
    other = fd_normals(t, geo.vertices, geo.normals, "tangent" if mode == "direct" else "direct")
    assert np.abs(got[0] - other).max() > 1e-2  # the two methods really differ here


def test_draw_picks_the_path_per_leaf_and_renders_all(ctx):
    sphere = Geometry(*_sphere(), name="sphere")
    lin = TransformNode(np.diag([0.5, 0.5, 0.5, 1.0]) + np.array([[0, 0, 0, -1.2]] + [[0] * 4] * 3),
                        [GeometryNode(sphere, colour=(1, 0, 0))])
    bent = TransformNode(Trilinear.from_function(Twist(1.5), sphere.box, (4, 4, 4)),
                         [GeometryNode(sphere, colour=(0, 0, 1))])
    scene = compose_scene(GroupNode([lin, bent]))
    assert scene.paths() == {"affine": 1, "cuboid": 0, "grid": 1}
    lo, hi = scene.bounds()
    view = frame_box(lo, hi, projection="perspective", azimuth=0.0, elevation=10.0, fov=35.0, distance=1.4,
                     target=np.full(3, 0.5), aspect=1.0)
    target = RenderTarget(ctx, (96, 96), 0)
    renderer = TrilinearRenderer(ctx)
    try:
        target.begin((1.0, 1.0, 1.0))
        renderer.draw(scene, view, Lighting(direction=(0.3, 0.5, 1.0)))
        img = target.read_rgb().astype(int)
        assert {k[0] for k in renderer.programs} == {"affine", "grid"}
    finally:
        renderer.release()
        target.release()
    red = (img[..., 0] > 100) & (img[..., 2] < 60)
    blue = (img[..., 2] > 100) & (img[..., 0] < 60)
    assert red.sum() > 100 and blue.sum() > 100
    assert np.median(np.nonzero(red)[1]) < np.median(np.nonzero(blue)[1])  # the small sphere is on the left


def _sphere(n=16):
    from deformgl.trilinear.shapes import uv_sphere

    g = uv_sphere(1.0, n, n)
    return g.vertices, g.normals, g.triangles
