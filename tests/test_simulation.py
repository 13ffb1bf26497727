"""The fragment backend's Verlet fast path (Mosegaard & Sørensen 2005, section 3.1) against the
float64 NumPy reference, and physics facts.

Both start as the foundation did, at rest with ``x_prev = x`` (an explicit :class:`State`)."""

from dataclasses import dataclass

import moderngl
import numpy as np
import pytest

from deformgl.grid.nodes import NodeGrid
from deformgl.sim.backends.explicit_gpu import FragmentIntegrator
from deformgl.sim.backends.verlet_data import MAX_PULLS
from deformgl.sim.backends.verlet_pass import FoundationVerlet
from deformgl.sim.integrators import State
from deformgl.sim.normals import pack_normals, unit_sums, unpack_normals
from deformgl.sim.simulation import NumpySimulation, make_simulation
from deformgl.sim.springs import SpringSystem, from_grid
from deformgl.sim.scripted import Load

H = 0.05


@dataclass
class Body:
    """A test body: the system, its loads, the rest start state."""

    system: SpringSystem
    loads: tuple
    fixed: np.ndarray

    @property
    def grid(self) -> NodeGrid:
        return self.system.grid

    def start(self, x0=None) -> State:
        x = self.grid.rest_positions.copy() if x0 is None else np.asarray(x0, float)
        return State(x, np.zeros_like(x), x.copy())

    def gpu(self, ctx, dt, x0=None, **variant):
        return FragmentIntegrator(ctx, self.system, None, "verlet", dt, loads=self.loads, state=self.start(x0),
                                  path="foundation", **variant)

    def foundation(self, ctx, dt, x0=None, **switches):
        """The pass itself, with the switches the user options leave out (layout="indexed")."""
        return FoundationVerlet.for_system(ctx, self.system, dt, loads=self.loads, state=self.start(x0), **switches)

    def reference(self, dt, x0=None):
        return NumpySimulation(self.system, "verlet", dt, loads=self.loads, state=self.start(x0))


def model_for(occ, *, fixed=None, k=(40.0, 40.0), damping=0.02, gravity=(0.0, -9.81, 0.0),
              mass=0.01, pulls=None, origin=(0.2, -0.1, 0.3)) -> Body:
    grid = NodeGrid(np.array(origin, float), H, np.asarray(occ, bool))
    n = grid.count
    fixed_nodes = np.zeros(n, bool) if fixed is None else fixed(grid)
    system = from_grid(grid, k_structural=k[0], k_shear=k[1], mass=mass, fixed=fixed_nodes,
                       velocity_damping=damping, gravity=gravity)
    loads = ()
    if pulls is not None:
        groups = pulls(grid)
        loads = tuple(Load((groups >> g) & 1 == 1, lambda t, g=g: pull_schedule(t)[g]) for g in range(2))
    return Body(system, loads, fixed_nodes)


def dragon_like_occupancy():
    rng = np.random.default_rng(7)
    occ = rng.random((7, 6, 5)) < 0.8
    occ[:, 0, :] = True
    return occ


def top_fixed(grid):
    return grid.ijk[:, 1] == grid.shape[1] - 1


def pull_schedule(t):
    f = np.zeros((MAX_PULLS, 3))
    f[0] = [0.3 * min(t / 0.02, 1.0), 0.0, 0.1]
    f[1] = [0.0, 0.0, -0.2] if t > 0.05 else 0.0
    return f


def pulls(grid):
    return (grid.ijk[:, 0] == 0) * 1 + (grid.ijk[:, 2] == grid.shape[2] - 1) * 2


#: the one-node layout, and the blocked one (1x2x2 nodes per fragment)
VARIANTS = [dict(layout="compact"), dict(block=(1, 2, 2))]


def rel_error(gpu, ref):
    extent = np.ptp(ref, axis=0).max()
    return np.abs(gpu - ref).max() / extent


@pytest.mark.parametrize("variant", VARIANTS, ids=lambda v: "+".join(f"{k}={x}" for k, x in v.items()))
@pytest.mark.parametrize("k", [(40.0, 40.0), (60.0, 15.0)], ids=["eq2-equal-k", "eq1-per-class-k"])
def test_one_step_matches_reference(ctx, variant, k):
    model = model_for(dragon_like_occupancy(), fixed=top_fixed, k=k, pulls=pulls)
    dt = 1e-3
    # start both from a random deformation so every spring is stretched or compressed
    rng = np.random.default_rng(1)
    x0 = model.grid.rest_positions + rng.normal(scale=0.1 * H, size=(model.grid.count, 3))
    x0[model.fixed] = model.grid.rest_positions[model.fixed]
    ref = model.reference(dt, x0)
    sim = model.gpu(ctx, dt, x0, **variant)
    try:
        assert sim.fast is not None
        ref.step(1)
        sim.step(1)
        assert rel_error(sim.positions(), ref.positions()) <= 1e-5
    finally:
        sim.release()


@pytest.mark.parametrize("variant", VARIANTS, ids=lambda v: "+".join(f"{k}={x}" for k, x in v.items()))
def test_two_hundred_damped_steps_within_1e_3_spacing(ctx, variant):
    model = model_for(dragon_like_occupancy(), fixed=top_fixed, damping=0.05, pulls=pulls)
    dt = 1e-3
    ref = model.reference(dt)
    sim = model.gpu(ctx, dt, **variant)
    try:
        ref.step(200)
        sim.step(200)
        moved = np.abs(ref.positions() - model.grid.rest_positions).max()
        assert moved > H  # the scene really deforms: the comparison is not trivial
        assert np.abs(sim.positions() - ref.positions()).max() <= 1e-3 * H
    finally:
        sim.release()


def test_normals_match_reference_and_point_outwards(ctx):
    occ = np.ones((5, 5, 5), bool)
    model = model_for(occ, gravity=(0, 0, 0))
    ref = model.reference(1e-3)
    sim = model.gpu(ctx, 1e-3)
    try:
        before = ref.positions()
        sim.step(1)
        ref.step(1)
        # the pass writes, with the new position, the normal of the positions it read
        gpu, cpu = unpack_normals(sim.fast.normals()), unpack_normals(pack_normals(unit_sums(model.grid, before)))
        sums = unit_sums(model.grid, model.grid.rest_positions)
        defined = np.linalg.norm(sums, axis=1) > 0.5
        assert defined.sum() == 98  # the 5^3 block's surface nodes (interior sums cancel)
        sin = np.linalg.norm(np.cross(gpu[defined], cpu[defined]), axis=1)
        cos = np.sum(gpu[defined] * cpu[defined], axis=1)
        # float32 vs float64 may round one octahedral level apart (about 0.005 degree)
        assert np.degrees(np.arctan2(sin, cos)).max() < 0.01
        # outward: a face-centre node on the +x face has normal +x
        i = model.grid.index[4, 2, 2]
        assert np.allclose(gpu[i], [1, 0, 0], atol=1e-3)
        # interior nodes carry the defined "no normal" code, not NaN
        assert np.all(sim.fast.normals()[~defined] == 0.0)  # NO_NORMAL
    finally:
        sim.release()


def test_rest_state_is_an_equilibrium(ctx):
    model = model_for(dragon_like_occupancy(), gravity=(0, 0, 0), damping=0.0)
    sim = model.gpu(ctx, 1e-3)
    try:
        sim.step(100)
        assert np.abs(sim.positions() - model.grid.rest_positions).max() <= 1e-6 * H
    finally:
        sim.release()


def test_fixed_nodes_are_bit_identical(ctx):
    model = model_for(dragon_like_occupancy(), fixed=top_fixed, pulls=pulls)
    sim = model.gpu(ctx, 1e-3)
    try:
        before = sim.positions()[model.fixed].copy()
        assert np.array_equal(before, model.grid.rest_positions[model.fixed].astype(np.float32))
        sim.step(150)
        after = sim.positions()
        assert np.array_equal(after[model.fixed], before)
        assert np.abs(after[~model.fixed] - model.grid.rest_positions[~model.fixed]).max() > H
    finally:
        sim.release()


def test_unconstrained_grid_falls_half_g_t_squared(ctx):
    model = model_for(dragon_like_occupancy(), damping=0.0, origin=(0.0, 0.0, 0.0))
    dt, steps = 1e-3, 400
    sim = model.gpu(ctx, dt)
    try:
        sim.step(steps)
        drop = np.mean(model.grid.rest_positions[:, 1] - sim.positions()[:, 1])
        t = steps * dt
        assert drop == pytest.approx(0.5 * 9.81 * t * t, rel=0.01)
        # a rigid fall: the shape is unchanged
        shape_change = sim.positions() - model.grid.rest_positions
        # float32 rounding of positions near 0.8 m feeds the springs: about 1e-5 m over 0.4 s
        assert np.ptp(shape_change, axis=0).max() < 1e-3 * H
    finally:
        sim.release()


def test_no_texture_read_back_while_stepping_and_drawing(ctx, monkeypatch):
    from deformgl.render.camera import frame_box
    from deformgl.render.passes import GridSurfacePass, Lighting, RenderTarget

    model = model_for(dragon_like_occupancy(), fixed=top_fixed)
    sim = model.gpu(ctx, 1e-3)
    target = RenderTarget(ctx, (64, 48), 4)
    surface = GridSurfacePass(ctx, model.grid, sim.fast.textures.layout, overlay=True)
    reads = []

    def forbid(name):
        original = getattr(getattr(moderngl, name), "read")

        def read(self, *a, **kw):
            reads.append(name)
            return original(self, *a, **kw)
        monkeypatch.setattr(getattr(moderngl, name), "read", read)

    for name in ("Texture", "Framebuffer", "Buffer"):
        forbid(name)
    try:
        lo, hi = model.grid.rest_positions.min(0), model.grid.rest_positions.max(0)
        view = frame_box(lo, hi, projection="perspective", azimuth=30, elevation=20, fov=35,
                         distance=1.6, target=np.full(3, 0.5), aspect=64 / 48)
        for _ in range(5):
            sim.step(10)
            target.begin((1, 1, 1))
            surface.draw(sim.position_texture, view, Lighting(direction=(0.3, 1, 0.5)))
        assert reads == []
        sim.positions()  # the check itself works: an explicit read is seen
        assert reads == ["Texture"]
    finally:
        surface.release()
        target.release()
        sim.release()


def test_invalid_dt_and_release(ctx):
    model = model_for(np.ones((2, 2, 2)))
    with pytest.raises(ValueError, match="dt must be > 0"):
        model.gpu(ctx, -1.0)


def test_dense_blocks_find_neighbours_by_arithmetic_with_the_same_result(ctx):
    """A full block: no neighbour-index texture (COMPACT_DENSE), bit-identical to the indexed
    pass (layout "indexed"), normals included."""
    model = model_for(np.ones((5, 4, 3), bool), fixed=top_fixed, pulls=pulls)
    states = {}
    for dense in (True, False):
        sim = model.foundation(ctx, 1e-3, layout="compact" if dense else "indexed")
        try:
            assert (sim.textures.neighbours is None) is dense
            assert ("#define COMPACT_DENSE" in sim.verlet.program.fragment_source.text) is dense
            sim.step(30)
            states[dense] = sim.read_state()
        finally:
            sim.release()
    np.testing.assert_array_equal(states[True], states[False])
    assert np.abs(states[True][:, :3] - model.grid.rest_positions).max() > 0


# --- the fast path is chosen by itself --------------------------------------------------------

def test_verlet_picks_the_foundation_pass_where_it_models_the_system(ctx):
    from deformgl.sim.integrators import Constraints
    from deformgl.sim.scripted import Drag

    grid = NodeGrid(np.zeros(3), H, np.ones((4, 3, 3), bool))
    plain = from_grid(grid, k_structural=40.0, k_shear=20.0, mass=0.01, velocity_damping=0.02)
    load = Load(grid.ijk[:, 0] == 0, lambda t: (0.1, 0.0, 0.0))
    cases = {  # what the pass does not model -> the general Verlet stage
        "flexion springs": (from_grid(grid, k_structural=40.0, k_shear=20.0, k_flexion=5.0, mass=0.01), {}),
        "spring damping": (from_grid(grid, k_structural=40.0, k_shear=20.0, damping_shear=0.01, mass=0.01), {}),
        "wind": (from_grid(grid, k_structural=40.0, k_shear=20.0, mass=0.01, wind=(1.0, 0, 0), wind_drag=0.1), {}),
        "drags": (plain, dict(drags=(Drag(0, lambda t: (0.0, 0.0, 0.0), 5.0),))),
        "obstacles": (plain, dict(constraints=Constraints(ground=-1.0))),
    }
    for integrator, loads in (("verlet", ()), ("verlet", (load,)), ("rk4", ())):
        sim = make_simulation(plain, integrator, "fragment", ctx=ctx, dt=1e-3, loads=loads)
        try:
            assert (sim.fast is not None) is (integrator == "verlet") and sim.packed_normals is (integrator == "verlet")
        finally:
            sim.release()
    for reason, (system, options) in cases.items():
        sim = make_simulation(system, "verlet", "fragment", ctx=ctx, dt=1e-3, **options)
        try:
            assert sim.fast is None and not sim.packed_normals and len(sim.passes) == 1
        finally:
            sim.release()
        with pytest.raises(ValueError, match=f"the foundation pass does not model {reason}"):
            make_simulation(system, "verlet", "fragment", ctx=ctx, dt=1e-3, path="foundation", **options)
        with pytest.raises(ValueError, match="does not model"):  # the blocked layout needs the pass
            make_simulation(system, "verlet", "fragment", ctx=ctx, dt=1e-3, block=(1, 2, 2), **options)
    with pytest.raises(ValueError, match="the foundation pass is verlet, not rk4"):
        make_simulation(plain, "rk4", "fragment", ctx=ctx, dt=1e-3, path="foundation")
    with pytest.raises(ValueError, match="the blocked layout is the foundation pass's"):
        FragmentIntegrator(ctx, plain, None, "verlet", 1e-3, path="general", block=(1, 2, 2))
    sim = make_simulation(plain, "verlet", "fragment", ctx=ctx, dt=1e-3, path="general")
    try:
        assert sim.fast is None and not sim.packed_normals
    finally:
        sim.release()


def test_both_verlet_paths_start_and_step_as_the_reference(ctx):
    """From the default start (the reference's second-order Taylor x_prev) the foundation pass,
    the general Verlet stage and the float64 reference take the same 200 steps, per-class
    stiffness, fixed nodes and two loads included; velocities are the same backward difference."""
    model = model_for(dragon_like_occupancy(), fixed=top_fixed, k=(60.0, 15.0), damping=0.05, pulls=pulls)
    dt = 1e-3
    ref = NumpySimulation(model.system, "verlet", dt, loads=model.loads)
    ref.step(200)
    assert np.abs(ref.positions() - model.grid.rest_positions).max() > H
    for path in ("foundation", "general"):
        sim = make_simulation(model.system, "verlet", "fragment", ctx=ctx, dt=dt, loads=model.loads, path=path)
        try:
            sim.step(200)
            assert sim.time == pytest.approx(ref.time)
            assert np.abs(sim.positions() - ref.positions()).max() <= 1e-3 * H, path
            assert np.abs(sim.velocities() - ref.velocities()).max() <= 0.05 * np.abs(ref.velocities()).max(), path
            assert np.all(sim.velocities()[model.fixed] == 0.0)
        finally:
            sim.release()


def test_both_verlet_paths_give_the_caller_its_framebuffer_back(ctx):
    """Stepping binds the state framebuffers; afterwards the caller's is bound again, so its next
    clear or draw cannot land in the simulation's state. After release the context is not left
    on a released framebuffer."""
    from deformgl.gl.resources import is_released

    model = model_for(np.ones((3, 3, 3), bool))
    mine = ctx.simple_framebuffer((4, 4))
    try:
        for path in ("foundation", "general"):
            sim = make_simulation(model.system, "verlet", "fragment", ctx=ctx, dt=1e-3, path=path)
            mine.use()
            sim.step(3)
            assert ctx.fbo is mine, path
            x = sim.positions()
            mine.clear(7.0, 7.0, 7.0, 7.0)
            np.testing.assert_array_equal(sim.positions(), x)
            sim.fast.textures.framebuffers[0].use() if sim.fast else None
            sim.release()
            assert not is_released(ctx.fbo), path
            with pytest.raises(RuntimeError, match="released"):
                sim.positions()
    finally:
        mine.release()


def test_a_layout_the_backend_does_not_have_is_refused_in_one_line(ctx):
    """The z-slice atlas and the forced index lookup left the user options (issue 43): asked
    for, they are a setup error naming the layouts there are."""
    from deformgl.sim.simulation import SimulationSetupError

    model = model_for(np.ones((3, 3, 3), bool))
    for layout in ("atlas", "indexed"):  # (a ValueError, as every option value the backend refuses)
        with pytest.raises(ValueError, match="layout must be one of auto, compact, blocked, got"):
            make_simulation(model.system, "verlet", "fragment", ctx=ctx, dt=1e-3, path="foundation", layout=layout)
    with pytest.raises(SimulationSetupError, match="unknown option.*'draw'"):
        make_simulation(model.system, "verlet", "fragment", ctx=ctx, dt=1e-3, draw="points")
