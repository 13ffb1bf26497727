"""Several nodes per fragment (issue 30): the blocked node layout (deformgl.grid.blocks) and the
foundation's Verlet pass on it (deformgl.sim.backends.blocked). Node positions, packed normals and
velocities are bit for bit those of the compact layout under every block shape, on dense boxes
(neighbour blocks by strides) and shapes with holes (the block-neighbour table), with fixed nodes,
pulls, damping, the calibrated lattice's levels codes and the volumetric term; the compact view
the draw passes and the census read is a bit-exact copy."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from deformgl.bench.sim_speed import bench_occupancy
from deformgl.grid.blocks import BLOCK_SHAPES, CORNER_OFFSETS, BlockedLayout, parse_block
from deformgl.grid.nodes import NEIGHBOUR_OFFSETS, NodeGrid
from deformgl.sim.backends.blocked import BLOCK_TABLE, blocked_refusal, default_block
from deformgl.sim.backends.explicit_gpu import FragmentIntegrator
from deformgl.sim.backends.verlet_pass import FoundationVerlet
from deformgl.sim.integrators import initial_state
from deformgl.sim.materials import ElasticMaterial, lattice_system
from deformgl.sim.springs import from_grid
from deformgl.sim.scripted import Load
from deformgl.sim.terms.volume.energy import corner_jacobians

H = 0.01
SHAPES = [s for s in BLOCK_SHAPES if s != (1, 1, 1)]


def ids(shape):
    return "x".join(map(str, shape))


def holed(shape=(7, 6, 8), seed=3):
    """A box with a tenth of its nodes missing and a 4x4x4 corner cut off (so that in every block
    shape a block is missing: the block-neighbour table)."""
    occupied = np.random.default_rng(seed).random(shape) > 0.1
    occupied[:4, :4, :4] = False
    return NodeGrid(np.array([0.2, -0.1, 0.05]), H, occupied)


def box(shape=(5, 6, 7)):
    return NodeGrid(np.array([0.2, -0.1, 0.05]), H, np.ones(shape, bool))


# -- the layout (CPU) -----------------------------------------------------------------------------

@pytest.mark.parametrize("shape", BLOCK_SHAPES, ids=ids)
@pytest.mark.parametrize("kind", ["box", "holed", "ball"])
def test_layout_places_every_node_once(shape, kind):
    """Every node has one (member, texel); values go in and come out by node; the block-neighbour
    table names the block holding each node's neighbour at every offset."""
    grid = {"box": box, "holed": holed, "ball": lambda: NodeGrid(np.zeros(3), H, bench_occupancy("ball9"))}[kind]()
    layout = BlockedLayout.for_grid(grid, shape, 4096)
    member, texel = layout.place(grid.ijk)
    keys = (member * layout.size[1] + texel[:, 1]) * layout.size[0] + texel[:, 0]
    assert len(np.unique(keys)) == grid.count and member.max() < layout.members
    assert layout.dense == (kind == "box")
    values = np.random.default_rng(0).random((grid.count, 4))
    np.testing.assert_array_equal(layout.gather(grid.ijk, layout.scatter(grid.ijk, values)),
                                  values.astype(np.float32))
    table = layout.neighbour_layers().reshape(7, -1, 4).transpose(1, 0, 2).reshape(-1, 28)
    offsets = np.concatenate([NEIGHBOUR_OFFSETS, CORNER_OFFSETS])
    block_of = layout.block_index[tuple((grid.ijk // np.array(shape)).T)]
    for off in offsets:  # (the corners: the cell term's body diagonals)
        q = grid.ijk + off
        inside = np.all((q >= 0) & (q < np.array(grid.shape)), axis=1)
        has = inside.copy()
        has[inside] = grid.index[tuple(q[inside].T)] >= 0
        moved = (q[has] // np.array(shape)) - grid.ijk[has] // np.array(shape)
        slot = [next(i for i, o in enumerate(offsets) if np.array_equal(o, m)) if np.any(m) else -1
                for m in moved]
        want = layout.block_index[tuple((q[has] // np.array(shape)).T)]
        got = np.where(np.array(slot) >= 0, table[block_of[has], np.maximum(slot, 0)], block_of[has])
        np.testing.assert_array_equal(got, want)


def test_block_names():
    assert parse_block("1x2x2") == (1, 2, 2) and parse_block("2X2X2") == (2, 2, 2)
    for bad in ("3x1x1", "2x2", "a", "1x1x8"):
        with pytest.raises(ValueError, match="is not one of 1x1x1, 1x1x2"):
            parse_block(bad)
    with pytest.raises(ValueError, match="is not one of"):
        BlockedLayout.for_grid(box(), (3, 1, 1), 4096)


def test_the_table_picks_by_size_and_turns_to_the_thin_axis():
    small, large = box((8, 8, 8)), box((32, 32, 16))
    assert default_block(small) is None and sorted(default_block(large)) == sorted(BLOCK_TABLE[0][1])
    assert BLOCK_TABLE[-1][0] == 0  # every grid gets a row
    # the block's side of one node along the thinnest axis; a sheet: 2 nodes along its first axis
    assert default_block(box((64, 1, 64))) == (2, 1, 1)
    assert default_block(box((1, 50, 50))) == (1, 2, 1) and default_block(box((50, 50, 1))) == (2, 1, 1)
    assert default_block(box((64, 64, 32))) == (2, 2, 1) and default_block(box((27, 27, 27))) == (1, 2, 2)


def test_refusal_names_what_the_renderer_lacks():
    webgl2 = {"GL_MAX_DRAW_BUFFERS": 4, "GL_MAX_COLOR_ATTACHMENTS": 4, "GL_MAX_TEXTURE_IMAGE_UNITS": 16}
    assert blocked_refusal(webgl2, (1, 2, 2)) is None  # 4 targets, 11 units
    assert "needs 8 render targets, the renderer has 4" in blocked_refusal(webgl2, (2, 2, 2))
    assert "samples up to 19 textures, the renderer has 16 units" in blocked_refusal(
        dict(webgl2, GL_MAX_DRAW_BUFFERS=8, GL_MAX_COLOR_ATTACHMENTS=8), (2, 2, 2))


# -- the pass (GPU) -------------------------------------------------------------------------------

def perturbed(system, grid, seed=1, amount=0.2):
    x = grid.rest_positions + np.random.default_rng(seed).uniform(-amount, amount, (grid.count, 3)) * H
    x[system.fixed] = grid.rest_positions[system.fixed]
    return initial_state(system, 1e-4, x=x)


def springs_system(grid):
    top = grid.ijk[:, 1] == grid.ijk[:, 1].max()
    system = from_grid(grid, k_structural=40.0, k_shear=25.0, mass=1e-3, fixed=top, velocity_damping=2e-3)
    return dataclasses.replace(system, mass_damping=3.0)


def pulls(grid):
    left, low = grid.ijk[:, 0] == 0, grid.ijk[:, 2] == 0
    return (Load(left, lambda t: (-0.02 * (1 + 100 * t), 0.01, 0.0)), Load(low, lambda t: (0.0, 0.0, 0.015)))


def run(ctx, system, grid, steps, state, *, weight_texture=False, **kwargs):
    if weight_texture:  # (a switch the user options leave out: the pass itself)
        assert system.grid is grid
        sim = FoundationVerlet.for_system(ctx, system, 1e-4, state=state, weight_texture=True, **kwargs)
    else:
        sim = FragmentIntegrator(ctx, system, grid, "verlet", 1e-4, state=state, path="foundation", **kwargs)
    try:
        sim.step(steps)
        view = np.frombuffer(sim.position_texture.read(), "f4").reshape(-1, 4)[: grid.count]
        normals = sim.normals() if weight_texture else sim.foundation.normals()
        return sim.positions(), normals, sim.velocities(), view, sim.block
    finally:
        sim.release()


#: The README run's shapes (each shape is a program of its own, 0.4-1 s to compile on llvmpipe
#: without Mesa's shader cache): the default, a block of 2, the block of 8; every shape in the slow run.
QUICK_SHAPES = [(1, 2, 2), (1, 1, 2), (2, 2, 2)]


@pytest.mark.gl
@pytest.mark.parametrize("kind, shapes", [("box", "quick"), ("holed", "quick"), ("holed", "all")])
def test_springs_bit_identical_in_every_block(ctx, kind, shapes):
    """Springs of two stiffnesses, fixed nodes, two time-varying pulls, velocity and mass damping:
    25 steps from a perturbed start give the compact layout's float32 positions, packed normals
    and velocities bit for bit in every block shape; the compact view holds the same texels."""
    grid = box() if kind == "box" else holed()
    system = springs_system(grid)
    loads = pulls(grid)
    state = perturbed(system, grid)
    x, n, v, view, block = run(ctx, system, grid, 25, state, loads=loads, layout="compact")
    assert block is None and np.abs(x - state.x).max() > 0.05 * H  # it moved
    for shape in (SHAPES if shapes == "all" else QUICK_SHAPES):
        bx, bn, bv, bview, block = run(ctx, system, grid, 25, state, loads=loads, block=shape)
        assert block == shape
        np.testing.assert_array_equal(bx, x, err_msg=f"block {shape}")
        np.testing.assert_array_equal(bn, n)
        np.testing.assert_array_equal(bv, v)
        np.testing.assert_array_equal(bview, view)


@pytest.mark.gl
@pytest.mark.parametrize("shape", [(9, 1, 7), (3, 1, 1), (1, 1, 1)], ids=ids)
def test_thin_grids_bit_identical(ctx, shape):
    """Sheets, a rod and a single node (boxes thinner than a block along some axis): every block
    shape as the compact layout (the sheet in the README run: the sheet's default block and two
    that span its thin axis)."""
    grid = box(shape)
    system = from_grid(grid, k_structural=40.0, k_shear=25.0, mass=1e-3, fixed=grid.ijk[:, 0] == 0,
                       velocity_damping=2e-3)
    state = perturbed(system, grid)
    loads = (Load(grid.ijk[:, 0] == grid.shape[0] - 1, lambda t: (0.0, -0.01, 0.004)),)
    x = run(ctx, system, grid, 15, state, loads=loads, layout="compact")
    for block in (SHAPES if shape != (9, 1, 7) else [default_block(box((90, 1, 70))), (1, 2, 2), (2, 2, 2)]):
        bx = run(ctx, system, grid, 15, state, loads=loads, block=block)
        for a, b in zip(bx[:4], x[:4]):
            np.testing.assert_array_equal(a, b, err_msg=f"{shape} in blocks of {block}")


@pytest.mark.gl
def test_the_view_follows_the_steps_and_pads_with_zeros(ctx):
    """The compact view is refreshed after every step (and only then: a second read draws no
    copy), and its padding texels hold 0 as the compact layout's do."""
    grid = holed()
    system = springs_system(grid)
    state = perturbed(system, grid)
    compact = FragmentIntegrator(ctx, system, grid, "verlet", 1e-4, state=state, layout="compact")
    blocked = FragmentIntegrator(ctx, system, grid, "verlet", 1e-4, state=state, block=(1, 2, 2))
    try:
        for _ in range(3):
            compact.step(2)
            blocked.step(2)
            whole = np.frombuffer(compact.position_texture.read(), "f4")
            view = blocked.position_texture
            assert blocked.position_texture is view
            np.testing.assert_array_equal(np.frombuffer(view.read(), "f4"), whole)
        w, h = blocked.textures.size
        assert w * h > grid.count and not np.any(whole.reshape(-1, 4)[grid.count:])  # padding there, all 0
    finally:
        compact.release()
        blocked.release()


@pytest.mark.gl
@pytest.mark.parametrize("kind, nu, shapes", [("holed", 0.45, "default"), ("box", 0.45, "default"),
                                              ("box", 0.25, "default"), ("holed", 0.25, "all"), ("box", 0.45, "all")])
def test_lattice_with_cells_bit_identical(ctx, nu, kind, shapes):
    """The calibrated lattice (per-spring levels codes, the volumetric term: the barrier alone at
    nu = 1/4, with the centre term at 0.45), squashed so that the barrier acts: 30 steps bit for
    bit as the compact layout, in the default block and 2x2x2 (every shape: the slow variant;
    each shape is a program of its own, ~1 s to compile on llvmpipe)."""
    grid = box((5, 6, 6)) if kind == "box" else holed((6, 6, 6), seed=5)
    system, _ = lattice_system(grid, ElasticMaterial(1e4, 1000.0, poissons_ratio=nu),
                               fixed=grid.ijk[:, 1] == grid.shape[1] - 1)
    assert system.cells is not None
    x0 = grid.rest_positions.copy()
    x0[:, 1] = grid.origin[1] + 0.4 * (x0[:, 1] - grid.origin[1])
    x0 += np.random.default_rng(2).uniform(-0.2, 0.2, x0.shape) * H
    x0[system.fixed] = grid.rest_positions[system.fixed]
    state = initial_state(system, 1e-4, x=x0)
    det, _ = corner_jacobians(system.cells, x0)
    assert np.sum(det < system.cells.barrier_j) > 20  # the barrier acts
    x = run(ctx, system, grid, 30, state, layout="compact")[0]
    assert np.abs(x - x0).max() > 0.1 * H
    for shape in (SHAPES if shapes == "all" else [default_block(box((30, 30, 30))), (2, 2, 2)]):
        np.testing.assert_array_equal(run(ctx, system, grid, 30, state, block=shape)[0], x, err_msg=f"{shape}")


@pytest.mark.gl
@pytest.mark.parametrize("weight_texture", [False, True], ids=["weights", "levels-as-texture"])
def test_spring_weights_bit_identical(ctx, weight_texture):
    """Per-spring weights (springs of one class differing) from the weight texture, and the
    lattice's levels codes stored as a texture instead: bit for bit as the compact layout."""
    grid = holed((6, 6, 6), seed=9)
    if weight_texture:
        system, _ = lattice_system(grid, ElasticMaterial(1e4, 1000.0), fixed=grid.ijk[:, 1] == 5)
    else:
        system = springs_system(grid)
        stiffness = system.stiffness.copy()
        stiffness[::7] *= 1.3  # weights that are no lattice's cell shares
        system = dataclasses.replace(system, stiffness=stiffness)
    state = perturbed(system, grid)
    x = run(ctx, system, grid, 20, state, layout="compact", weight_texture=weight_texture)[0]
    for shape in ((1, 2, 2), (2, 2, 2)):
        bx = run(ctx, system, grid, 20, state, block=shape, weight_texture=weight_texture)[0]
        np.testing.assert_array_equal(bx, x)


@pytest.mark.gl
def test_auto_layout_and_refusals(ctx):
    """"auto" takes the table's block, "compact" none; a general-path simulation refuses a block."""
    grid = box((32, 32, 9))
    system = springs_system(grid)
    with FragmentIntegrator(ctx, system, grid, "verlet", 1e-4) as sim:
        assert sim.block == default_block(grid) is not None and sim.packed_normals
    with FragmentIntegrator(ctx, system, grid, "verlet", 1e-4, layout="compact") as sim:
        assert sim.block is None
    with FragmentIntegrator(ctx, system, grid, "semi-implicit", 1e-4) as sim:
        assert sim.block is None
    with pytest.raises(ValueError, match="the blocked layout is the foundation pass's"):
        FragmentIntegrator(ctx, system, grid, "verlet", 1e-4, path="general", block=(1, 2, 2))


# -- scenes ---------------------------------------------------------------------------------------

@pytest.mark.gl
def test_scene_layouts_draw_the_same_image(ctx):
    """[physics] layout forces the node layout; the jelly (pulls, fixed nodes) drawn from the
    blocked pass's compact view is the compact layout's image, pixel for pixel."""
    import deformgl as dg
    from deformgl.scene.node_state import NodeState
    from deformgl.scene.pipeline import build_scene_model

    from deformgl.data import packaged_scene

    scene = dg.load_scene(packaged_scene("jelly_springs")).with_overrides(steps=40)
    images = {}
    for layout in ("compact", "1x2x2", "2x2x2"):
        forced = dataclasses.replace(scene, physics=dataclasses.replace(scene.physics, layout=layout))
        state = NodeState(ctx, forced, build_scene_model(forced), progress=False)
        try:
            assert state.sim.block == (None if layout == "compact" else parse_block(layout))
        finally:
            state.release()
        images[layout] = dg.render_scene(forced, ctx=ctx)
    assert images["compact"].std() > 0
    for layout in ("1x2x2", "2x2x2"):
        np.testing.assert_array_equal(images[layout], images["compact"])


def test_scene_layout_key_is_checked(tmp_path):
    import deformgl as dg

    scene = tmp_path / "s.toml"
    for physics, message in (('layout = "3x1x1"', r"physics\.layout.*one of"),
                             ('layout = "1x2x2"\nintegrator = "rk4"', r"physics\.layout.*Verlet pass.*'rk4'")):
        scene.write_text(f'[cloth]\nnodes = [6, 6]\n\n[physics]\n{physics}\n')
        with pytest.raises(dg.SceneError, match=message):
            dg.load_scene(scene)


@pytest.mark.gl
def test_a_forced_block_on_a_scene_the_pass_does_not_model(ctx, tmp_path):
    """The foundation pass does not model obstacles: a forced block is refused naming the key and
    why, before the run (the default layout runs the scene on the general stages)."""
    import deformgl as dg

    scene_file = tmp_path / "s.toml"
    scene_file.write_text('[cloth]\nnodes = [6, 6]\n\n[physics]\nsteps = 3\nlayout = "2x1x2"\n\n'
                          '[physics.ground]\nat = 0.1\n\n[render]\nsize = [32, 24]\n')
    with pytest.raises(dg.SceneError, match=r"s\.toml: physics\.layout: '2x1x2' .* does not model obstacles; use"):
        dg.render_scene(dg.load_scene(scene_file), ctx=ctx)
    scene_file.write_text(scene_file.read_text().replace('layout = "2x1x2"', 'layout = "auto"'))
    assert dg.render_scene(dg.load_scene(scene_file), ctx=ctx).shape == (24, 32, 3)
