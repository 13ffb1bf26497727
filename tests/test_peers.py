"""The Taichi, Warp and Numba CPU peers of the Verlet step against the float64 NumPy reference."""

import subprocess
import sys

import numpy as np
import pytest

from deformgl.bench import peers
from deformgl.grid.nodes import NodeGrid
from deformgl.sim.backends.verlet_data import MAX_PULLS
from deformgl.sim.integrators import State
from deformgl.sim.simulation import NumpySimulation
from deformgl.sim.springs import from_grid
from deformgl.sim.scripted import Load

H = 0.05
#: float32 peers after 50 steps of the jelly block below: max |x - x_ref| <= TOL * spacing
#: (measured ~3.5e-5 on every peer, with the nodes moving ~0.3 spacing).
TOL = 2e-4


class Jelly:
    """A test body: its spring system, two loads, fixed nodes."""

    def __init__(self, system, loads):
        self.system, self.loads = system, loads
        self.grid, self.fixed = system.grid, system.fixed

    def reference(self, dt, loads=True, x0=None, x_prev=None):
        """The float64 reference, started as the peers are: at rest, x_prev = x (or given)."""
        x = self.grid.rest_positions.copy() if x0 is None else x0
        state = State(x, np.zeros_like(x), x.copy() if x_prev is None else x_prev)
        return NumpySimulation(self.system, "verlet", dt, loads=self.loads if loads else (), state=state)


def jelly(shape=(6, 5, 4), k=(60.0, 15.0), damping=0.02, origin=(0.2, -0.1, 0.3), hole=False):
    """Block, top face fixed, two pull groups (x = 0 face; far z face), per-class stiffness;
    ``hole``: one inner node missing (the peers then read the neighbour table, not offsets)."""
    occupied = np.ones(shape, bool)
    occupied[2, 2, 2] = not hole
    grid = NodeGrid(np.array(origin, float), H, occupied)
    ijk = grid.ijk
    system = from_grid(grid, k_structural=k[0], k_shear=k[1], mass=0.01, fixed=ijk[:, 1] == shape[1] - 1,
                       velocity_damping=damping)
    loads = (Load(ijk[:, 0] == 0, lambda t: pull_schedule(t)[0]),
             Load(ijk[:, 2] == shape[2] - 1, lambda t: pull_schedule(t)[1]))
    return Jelly(system, loads)


def pull_schedule(t):
    f = np.zeros((MAX_PULLS, 3))
    f[0] = [0.3 * min(t / 0.02, 1.0), 0.0, 0.1]
    f[1] = [0.0, 0.0, -0.2] if t > 0.02 else 0.0
    return f


def need(peer):
    """Skip unless the peer is installed (the optional 'peers' extra; CI does not install it)."""
    pytest.importorskip(peer, reason=f"optional extra 'peers': {peer} is not installed")


def stepper(peer, model, dt=1e-3, pull=True):
    need(peer)
    return peers.make_stepper(peer, model.system, dt, model.loads if pull else ())


@pytest.mark.peers
@pytest.mark.parametrize("hole", [False, True], ids=["dense", "holed"])
@pytest.mark.parametrize("peer", peers.PEERS)
def test_fifty_steps_match_reference(peer, hole):
    model = jelly(hole=hole)
    ref = model.reference(1e-3)
    sim = stepper(peer, model)
    try:
        assert sim.dense is not hole
        ref.step(50)
        sim.step(50)
        x = sim.positions()
        assert x.dtype == np.float32 and x.shape == (model.grid.count, 3)
        assert np.abs(ref.positions() - model.grid.rest_positions).max() > 0.2 * H  # really deforms
        assert np.abs(x - ref.positions()).max() <= TOL * H
        assert sim.steps_done == 50 and sim.time == pytest.approx(0.05)
    finally:
        sim.release()


@pytest.mark.peers
@pytest.mark.parametrize("peer", peers.PEERS)
def test_one_step_from_random_deformation(peer):
    """Every spring stretched or compressed, both stiffness classes and both pulls active."""
    model = jelly()
    rng = np.random.default_rng(1)
    x0 = model.grid.rest_positions + rng.normal(scale=0.1 * H, size=(model.grid.count, 3))
    x0[model.fixed] = model.grid.rest_positions[model.fixed]
    xp = x0 + rng.normal(scale=0.01 * H, size=x0.shape)
    xp[model.fixed] = x0[model.fixed]
    ref = NumpySimulation(model.system, "verlet", 1e-3, loads=model.loads,
                          state=State(x0.copy(), np.zeros_like(x0), xp.copy()), t0=0.03)
    sim = stepper(peer, model)
    try:
        sim.set_state(x0, xp)
        sim.steps_done = 30
        ref.step(1)
        sim.step(1)
        extent = np.ptp(ref.positions(), axis=0).max()
        assert np.abs(sim.positions() - ref.positions()).max() / extent <= 1e-5
    finally:
        sim.release()


@pytest.mark.peers
@pytest.mark.parametrize("peer", peers.PEERS)
def test_fixed_nodes_bit_identical_to_rest(peer):
    model = jelly()
    sim = stepper(peer, model)
    try:
        sim.step(50)
        x = sim.positions()
        rest32 = model.grid.rest_positions.astype(np.float32)
        assert np.array_equal(x[model.fixed], rest32[model.fixed])
        assert not np.array_equal(x[~model.fixed], rest32[~model.fixed])
    finally:
        sim.release()


@pytest.mark.peers
@pytest.mark.parametrize("peer", peers.PEERS)
def test_two_models_in_one_process(peer):
    """Two steppers of different sizes, stepped interleaved, each matches its own reference."""
    a, b = jelly(), jelly(shape=(4, 7, 3), k=(40.0, 40.0), damping=0.05, origin=(0.0, 0.0, 0.0))
    sa = stepper(peer, a)
    sb = stepper(peer, b, dt=5e-4, pull=False)
    ra, rb = a.reference(1e-3), b.reference(5e-4, loads=False)
    try:
        for _ in range(5):
            sa.step(10)
            sb.step(10)
        ra.step(50)
        rb.step(50)
        assert np.abs(rb.positions() - b.grid.rest_positions).max() > 1e-3 * H  # b sags under gravity
        assert np.abs(sa.positions() - ra.positions()).max() <= TOL * H
        assert np.abs(sb.positions() - rb.positions()).max() <= TOL * H
        sa.release()
        sc = stepper(peer, jelly(shape=(3, 3, 3)))  # a model after one was freed
        sc.step(5)
        sb.step(1)
        rb.step(1)
        assert np.abs(sb.positions() - rb.positions()).max() <= TOL * H
        sc.release()
    finally:
        sa.release()
        sb.release()


@pytest.mark.peers
@pytest.mark.parametrize("peer", peers.PEERS)
def test_bench_peers_reports_a_timing(peer):
    need(peer)
    model = jelly(shape=(5, 4, 3))
    from studies.peer_timing import bench_peers

    timing = bench_peers(model.system, 1e-3, steps=3, peers=[peer], repeats=2)[peer]
    assert timing.nodes == model.grid.count
    assert timing.ms_per_step > 0 and timing.jit_s >= 0 and timing.setup_s >= 0
    assert timing.nodes_per_s == pytest.approx(model.grid.count / (timing.ms_per_step * 1e-3))
    assert timing.version == peers.available_peers()[peer]
    assert timing.threads >= 1


def test_available_peers_and_lazy_import(monkeypatch):
    found = peers.available_peers()
    assert set(found) == set(peers.PEERS)
    monkeypatch.setitem(sys.modules, "warp", None)  # import warp now raises ImportError
    assert peers.available_peers()["warp"] is None
    assert "import of warp halted" in peers.peer_import_errors()["warp"]
    with pytest.raises(ValueError, match="peer must be one of"):
        peers.make_stepper("jax", jelly(), 1e-3)
    # importing deformgl.bench.peers imports no peer package
    code = ("import sys, deformgl.bench.peers, deformgl.bench.peer_numba; "
            "print(*(p in sys.modules for p in ('taichi', 'warp', 'numba')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "False", "False"]


def test_invalid_dt():
    with pytest.raises(ValueError, match="dt must be > 0"):
        peers.PeerStepper(jelly(), 0.0)


@pytest.mark.peers
def test_peers_report_times_every_peer_in_alternating_rounds(ctx):
    for peer in peers.PEERS:
        need(peer)
    from deformgl.bench.sim_speed import peers_report

    text = peers_report(ctx, steps=2, grids=((4, 4, 3),), rounds=2)
    assert "renderer" in text and "2 alternating rounds" in text and "4x4x3 (48 nodes): fragment" in text
    for peer in peers.PEERS:
        assert f"-> fragment / {peer} = " in text


@pytest.mark.peers
def test_numba_runs_on_the_workqueue_layer(monkeypatch):
    """Not OpenMP's spin-waiting pool (20x slower per step on a shared 2-core machine)."""
    need("numba")
    monkeypatch.delenv("NUMBA_THREADING_LAYER", raising=False)
    sim = stepper("numba", jelly())
    try:
        sim.step(2)
        assert sim.threading_layer == "workqueue" and sim.threads >= 1
    finally:
        sim.release()
