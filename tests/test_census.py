"""NodeCensus: node counts by occlusion query against NumPy, on random and simulated states."""

from __future__ import annotations

import moderngl
import numpy as np
import pytest

from deformgl.sim import springs
from deformgl.sim.census import NodeCensus
from deformgl.sim.backends.feedback import FeedbackSimulation
from deformgl.sim.backends.explicit_gpu import FragmentIntegrator
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.integrators import initial_state

#: (count, row, slots): a partly filled last row, a single partial row, a full square
LAYOUTS = [(203, 16, 1), (203, 16, 2), (5, 8, 2), (64, 8, 1)]


def state_image(rng, count, row, slots, *, scale=1.0):
    """(rows, slots * row, 4) float32 random state; padding texels and w hold garbage that must
    never be counted (NaN, Inf, huge values)."""
    rows = -(-count // row)
    img = (rng.normal(size=(rows * row, slots, 4)) * scale).astype(np.float32)
    img[:, :, 3] = np.nan  # w is never looked at
    garbage = np.array([np.nan, np.inf, -np.inf, 1e30], np.float32)
    img[count:, :, :3] = garbage[np.arange(3 * (rows * row - count) * slots) % 4].reshape(
        -1, slots, 3)
    return img.reshape(rows, row * slots, 4)


def texture(ctx, img):
    tex = ctx.texture((img.shape[1], img.shape[0]), 4, np.ascontiguousarray(img).tobytes(),
                      dtype="f4")
    tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
    return tex


def nodes(img, count, slots, slot):
    """(count, 3) xyz of slot ``slot`` of every node of a state image."""
    return img.reshape(-1, slots, 4)[:count, slot, :3]


@pytest.fixture
def census_of(ctx):
    made = []

    def make(**kwargs):
        made.append(NodeCensus(ctx, **kwargs))
        return made[-1]
    yield make
    for c in made:
        c.release()


@pytest.mark.parametrize("count,row,slots", LAYOUTS)
def test_moved_and_bad_match_numpy(ctx, census_of, count, row, slots):
    rng = np.random.default_rng(count * slots)
    now_img = state_image(rng, count, row, slots)
    before_img = now_img.copy()
    for s in range(slots):
        # about half the nodes move, by various amounts; the others are bit-identical
        sel = rng.random(count) < 0.5
        flat = before_img.reshape(-1, slots, 4)
        flat[:count, s, :3][sel] += rng.normal(size=(int(sel.sum()), 3)).astype(np.float32)
    now, before = texture(ctx, now_img), texture(ctx, before_img)
    census = census_of(count=count, row=row, slots=slots)
    try:
        for slot in range(slots):
            d = np.linalg.norm(nodes(now_img, count, slots, slot).astype(np.float64)
                               - nodes(before_img, count, slots, slot), axis=1)
            moving = np.sort(d[d > 0])
            for threshold in (0.0, 0.5 * (moving[len(moving) // 2 - 1] + moving[len(moving) // 2])
                              if len(moving) > 1 else 0.0, 1e9):
                expected = int(np.sum(d > threshold))
                assert census.moved(now, before, threshold, slot=slot) == expected
            assert census.moved(now, before, 0.0, slot=slot) == len(moving) > 0
            x = nodes(now_img, count, slots, slot)
            for limit in (0.5, 1.5, 1e9):
                expected = int(np.sum(np.any(np.abs(x) > limit, axis=1)))
                assert census.bad(now, limit, slot=slot) == expected
            assert census.bad(now, 1e9, slot=slot) == 0  # the garbage padding is not counted
    finally:
        now.release()
        before.release()


def boundary_textures(ctx, values_now, values_before, row=4):
    count = len(values_now)
    imgs = []
    for values in (values_now, values_before):
        img = np.zeros((-(-count // row) * row, 4), np.float32)
        img[:count, :3] = values
        imgs.append(texture(ctx, img.reshape(-1, row, 4)))
    return imgs


def test_threshold_and_limit_are_strict(ctx, census_of):
    before = np.array([[1.0, 2.0, 3.0]] * 3, np.float32)
    now = before + np.array([[0.375, 0.5, 0.0], [0.0, -0.625, 0.0], [0.0, 0.0, 0.25]],
                            np.float32)  # distances 0.625 (exact), 0.625, 0.25
    a, b = boundary_textures(ctx, now, before)
    census = census_of(count=3, row=4)
    below = float(np.nextafter(np.float32(0.625), np.float32(0)))
    assert census.moved(a, b, 0.625) == 0
    assert census.moved(a, b, below) == 2
    assert census.moved(a, b, 0.25) == 2
    assert census.moved(a, b, float(np.nextafter(np.float32(0.25), np.float32(0)))) == 3
    c, d = boundary_textures(ctx, [[1.0, 3.0, 2.0], [0.5, 0.0, 3.0]], [[-3.0, 1.0, 0.0]] * 2)
    census = census_of(count=2, row=4)
    limit = float(np.nextafter(np.float32(3.0), np.float32(0)))
    for t in (c, d):
        assert census.bad(t, 3.0) == 0  # |3.0| > 3.0 is false
        assert census.bad(t, limit) == 2
    for t in (a, b, c, d):
        t.release()


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf, 3e38, -2e10])
@pytest.mark.parametrize("component", [0, 1, 2])
def test_each_non_finite_or_huge_value_is_detected(ctx, census_of, value, component):
    rng = np.random.default_rng(7)
    x = rng.normal(size=(10, 3)).astype(np.float32)
    bad = x.copy()
    bad[[3, 9], component] = value
    a, b = boundary_textures(ctx, bad, x)
    census = census_of(count=10, row=4)
    assert census.bad(b, 1e9) == 0
    assert census.bad(a, 1e9) == 2
    if not np.isfinite(value):
        # a non-finite position is not at rest: moved, on either side, at any threshold
        assert census.moved(a, b, 1e30) == 2
        assert census.moved(b, a, 1e30) == 2
        assert census.moved(a, a, 1e30) == 2
    for t in (a, b):
        t.release()


def test_w_is_ignored(ctx, census_of):
    img = np.zeros((2, 8, 4), np.float32)
    img[..., :3] = 0.5
    img[0, :, 3] = np.nan
    img[1, :, 3] = np.inf
    other = img.copy()
    other[..., 3] = -1e30
    a, b = texture(ctx, img), texture(ctx, other)
    census = census_of(count=16, row=8)
    assert census.bad(a, 1.0) == 0
    assert census.moved(a, b, 0.0) == 0
    img[1, 2, 1] = np.nan  # and the same texture with one NaN in y is seen
    a.write(img.tobytes())
    assert census.bad(a, 1.0) == 1 and census.moved(a, b, 0.0) == 1
    a.release()
    b.release()


@pytest.mark.parametrize("count,row,slots", LAYOUTS)
def test_snapshot_is_a_bit_exact_copy_of_the_slot(ctx, census_of, count, row, slots):
    rng = np.random.default_rng(3)
    img = state_image(rng, count, row, slots, scale=1e3)
    img.reshape(-1, slots, 4)[:count, :, 3] = rng.normal(size=(count, slots))
    img.reshape(-1, slots, 4)[count // 2, 0, :] = [np.nan, -0.0, np.inf, 1e-45]  # denormal w
    tex = texture(ctx, img)
    census = census_of(count=count, row=row, slots=slots)
    for slot in range(slots):
        snap = census.snapshot(tex, slot=slot)
        assert (snap.width, snap.height, snap.components, snap.dtype) == (row, -(-count // row),
                                                                          4, "f4")
        got = np.frombuffer(snap.read(), np.uint32).reshape(-1, 4)[:count]
        want = img.reshape(-1, slots, 4)[:count, slot].view(np.uint32)
        np.testing.assert_array_equal(got, want)
        assert census.snapshot(tex, slot=slot) is snap  # reused
        # a 1-slot snapshot compares with the slot it copied: nothing moved but the NaN node
        assert census.moved(tex, snap, 0.0, slot=slot) == (1 if slot == 0 else 0)
    tex.release()


def test_snapshot_ignores_the_callers_blending(ctx, census_of):
    img = np.random.default_rng(4).random((2, 8, 4)).astype(np.float32)
    tex = texture(ctx, img)
    census = census_of(count=16, row=8)
    ctx.enable(moderngl.BLEND)
    ctx.blend_func = moderngl.ONE, moderngl.ONE  # additive: a blended copy would double
    try:
        snap = census.snapshot(tex)
        snap = census.snapshot(tex)
    finally:
        ctx.disable(moderngl.BLEND)
        ctx.blend_func = moderngl.ONE, moderngl.ZERO  # the GL default
    np.testing.assert_array_equal(np.frombuffer(snap.read(), np.float32), img.ravel())
    tex.release()


def test_callers_framebuffer_is_restored(ctx, census_of):
    img = np.zeros((1, 4, 4), np.float32)
    tex = texture(ctx, img)
    census = census_of(count=4, row=4)
    mine = ctx.simple_framebuffer((3, 3))
    mine.use()
    try:
        assert census.bad(tex, 1.0) == 0
        assert ctx.fbo is mine
        census.snapshot(tex)
        assert ctx.fbo is mine
        assert census.moved(tex, census.snapshot(tex), 0.0) == 0
        assert ctx.fbo is mine
    finally:
        mine.release()
    # a caller's framebuffer released while bound: framebuffer 0 afterwards, no GL error
    ctx.error  # clear
    assert census.bad(tex, -1.0) == 4
    assert ctx.fbo.glo == 0 and ctx.error == "GL_NO_ERROR"
    tex.release()


def test_release_is_idempotent_and_checks_arguments(ctx):
    census = NodeCensus(ctx, count=10, row=4, slots=2)
    img = np.zeros((3, 8, 4), np.float32)
    tex = texture(ctx, img)
    assert census.moved(tex, census.snapshot(tex), 0.0) == 0
    with pytest.raises(ValueError, match="slot 2"):
        census.bad(tex, 1.0, slot=2)
    small = ctx.texture((8, 2), 4, dtype="f4")
    with pytest.raises(ValueError, match="8x2 texels, 8x3 needed"):
        census.bad(small, 1.0)
    with pytest.raises(ValueError, match="before is 8x3 texels, 16x3 needed"):
        census.moved(tex, tex, 0.0, before_slots=4)
    owned = list(census._owned)
    assert owned
    census.release()
    assert all(type(o.gl.mglo if hasattr(o, "gl") else o.mglo).__name__ == "InvalidObject"
               for o in owned)
    census.release()
    with pytest.raises(RuntimeError, match="released"):
        census.bad(tex, 1.0)
    with pytest.raises(ValueError):
        NodeCensus(ctx, count=0, row=4)
    with NodeCensus(ctx, count=3, row=4) as c:
        assert c.bad(tex, 1.0) == 0
    assert c._released
    tex.release()
    small.release()


def cloth(nx, nz, dt, rng):
    grid = NodeGrid(np.zeros(3), 0.05, np.ones((nx, 1, nz), bool))
    fixed = np.zeros(grid.count, bool)
    fixed[[0, nz - 1]] = True
    system = springs.from_grid(grid, k_structural=100.0, k_shear=50.0, k_flexion=10.0,
                               mass=0.1, fixed=fixed, gravity=(0.0, 0.0, 0.0))
    v = rng.normal(size=(grid.count, 3)) * 0.5
    v[rng.random(grid.count) < 0.3] = 0.0  # some nodes at rest
    return system, grid, initial_state(system, dt, v=v)


def check_step(census, now, before, x0, x1, **kw):
    """The census of one step against positions read back before and after it."""
    d = np.linalg.norm(x1.astype(np.float64) - x0, axis=1)
    s = np.sort(d)
    lo, hi = len(s) // 4, 3 * len(s) // 4
    k = lo + int(np.argmax(np.diff(s[lo:hi])))
    assert s[k + 1] - s[k] > 1e-3 * s[k + 1]  # a clean gap, far above float32 rounding
    for threshold in (0.5 * (s[k] + s[k + 1]), 0.5 * s[-1], 1e-6):
        expected = int(np.sum(d > threshold))
        assert 0 < expected < len(d)
        assert census.moved(now, before, threshold, **kw) == expected


@pytest.mark.parametrize("name", ["verlet", "semi-implicit"])
def test_fragment_integrator_step(ctx, name):
    dt, rng = 1e-2, np.random.default_rng(11)
    system, grid, state = cloth(15, 13, dt, rng)  # 195 nodes in rows of 16: the last row partial
    sim = FragmentIntegrator(ctx, system, grid, name, dt, state=state)
    census = NodeCensus(ctx, count=sim.count, row=sim.layout.width)
    try:
        x0 = sim.positions()
        snap = census.snapshot(sim.pool[sim.roles[0]])
        sim.step(1)
        x1 = sim.positions()
        now = sim.pool[sim.roles[0]]
        check_step(census, now, snap, x0, x1)
        # the integrator's own previous positions say the same
        check_step(census, now, sim.pool[sim.roles[1 if name == "verlet" else 2]], x0, x1)
        assert census.bad(now, 10.0) == 0
    finally:
        census.release()
        sim.release()


@pytest.mark.parametrize("name", ["verlet", "euler"])
def test_feedback_simulation_step(ctx, name):
    dt, rng = 1e-2, np.random.default_rng(12)
    system, _, state = cloth(9, 23, dt, rng)  # 207 nodes in one row of 256
    sim = FeedbackSimulation(ctx, system, name, dt, state=state)
    slots = 1 if name == "verlet" else 2
    census = NodeCensus(ctx, count=sim.count, row=sim.node_row, slots=slots)

    def current():
        return sim.tex_x[sim._current] if name == "verlet" else sim.tex_state
    try:
        x0 = sim.positions()
        snap = census.snapshot(current())  # the step overwrites x in place
        sim.step(1)
        x1 = sim.positions()
        check_step(census, current(), snap, x0, x1)
        if name == "verlet":
            check_step(census, current(), sim.tex_x[1 - sim._current], x0, x1)
        else:  # velocities (slot 1) against the initial ones
            v = census.snapshot(current(), slot=1)
            assert census.moved(current(), v, 0.0, slot=1) == 0
        assert census.bad(current(), 10.0) == 0
    finally:
        census.release()
        sim.release()
