"""A physics term defined only here — a spring from each node to its rest position, stiffness in
N/m — runs on every backend that has a form of it, with no edit outside this module (issue 43,
item 2): the NumPy reference, the fragment backend's five explicit integrators (the general
stages), the foundation Verlet pass in the compact and the blocked layout, implicit Euler with
Jacobi and multigrid in NumPy and on the GPU, each matched to float64 as the springs are; the dt
bound sees it; transform feedback and XPBD refuse it in one line naming it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.sparse as sp

from deformgl.grid.nodes import NodeGrid
from deformgl.sim import integrators as I
from deformgl.sim import springs
from deformgl.sim.integrators import EXPLICIT_INTEGRATORS
from deformgl.sim.limits import dt_limit
from deformgl.sim.simulation import make_simulation
from deformgl.sim.spectrum import stiffness_matrix
from deformgl.sim.terms import GlslTerm, NodeTable, Term, block_diagonal

# The GLSL form: the rest position and the node's weight w in a one-layer table, the stiffness a
# uniform; force -w k (x - x_rest), stiffness block w k I.
ANCHOR_GLSL = """
uniform sampler2DArray u_anchor_table;  // xyz rest position (m), w the node's weight
uniform float u_anchor_k;               // N/m
void anchor_force(inout vec3 f, TermNode n) {
    vec4 r = term_table(u_anchor_table, 1, 0, n);
    f -= (r.w * u_anchor_k) * (n.x - r.xyz);
}
void anchor_product(inout vec3 q, TermNode n, vec3 y) {
    q += (term_table(u_anchor_table, 1, 0, n).w * u_anchor_k) * y;
}
void anchor_diagonal(inout vec3 d, inout vec3 off, inout float held, TermNode n) {
    d += vec3(term_table(u_anchor_table, 1, 0, n).w * u_anchor_k);
}
"""


class RestAnchors(Term):
    """A zero-length spring of stiffness ``weight * k`` (N/m) from each node to its rest position."""

    name = "rest anchors"

    def __init__(self, rest: np.ndarray, k: float, weight: np.ndarray) -> None:
        self.rest = np.asarray(rest, np.float64)
        self.k = float(k)
        self.weight = np.asarray(weight, np.float64)

    def add_forces(self, x, v, t, out):
        out -= (self.k * self.weight)[:, None] * (x - self.rest)

    def energy(self, x):
        return 0.5 * float(np.sum(self.k * self.weight * np.sum((x - self.rest) ** 2, axis=1)))

    def stiffness(self, x):
        return block_diagonal((self.k * self.weight)[:, None, None] * np.eye(3))

    def glsl(self, grid):
        table = np.concatenate([self.rest, self.weight[:, None]], axis=1)
        return GlslTerm("anchor", source=ANCHOR_GLSL, implicit=True, uniforms={"u_anchor_k": self.k},
                        tables=(NodeTable("u_anchor_table", table),))


def anchored(n=4, k_anchor=30.0, **options):
    grid = NodeGrid(np.array([0.2, 0.5, -0.1]), 0.1, np.ones((n, n, n), bool))
    fixed = np.zeros(grid.count, bool)
    fixed[[0, n - 1]] = True
    base = springs.from_grid(grid, k_structural=50.0, k_shear=20.0, mass=0.1, fixed=fixed,
                             velocity_damping=0.02, **options)
    weight = np.linspace(0.5, 1.5, grid.count)  # unequal per node: the table is read per node
    return dataclasses.replace(base, extra_terms=(RestAnchors(grid.rest_positions, k_anchor, weight),)), grid


def start(system, dt):
    return I.initial_state(system, dt, v=np.random.default_rng(7).normal(size=(system.count, 3)) * 0.3)


def reference(system, name, dt, steps, state):
    s = state
    for k in range(steps):
        s = I.step(system, name, s, dt, k * dt)
    return s


def gpu_run(ctx, system, name, dt, steps, state, **options):
    sim = make_simulation(system, name, "fragment", dt=dt, ctx=ctx, state=state, **options)
    try:
        sim.step(steps)
        return sim.positions().astype(np.float64), sim
    finally:
        sim.release()


def test_numpy_reference_has_the_term():
    system, _ = anchored()
    base = dataclasses.replace(system, extra_terms=())
    rng = np.random.default_rng(1)
    x = system.rest_positions + rng.normal(size=(system.count, 3)) * 0.01
    v = np.zeros_like(x)
    anchors = system.terms[0]
    df = springs.forces(system, x, v, 0.0) - springs.forces(base, x, v, 0.0)
    assert np.allclose(df, -(anchors.k * anchors.weight)[:, None] * (x - system.rest_positions), rtol=1e-12, atol=1e-15)
    # the energy's gradient is minus the force (central differences)
    h, e = 1e-7, np.zeros(3)
    for c in range(3):
        e[c] = 1.0
        xp, xm = x.copy(), x.copy()
        xp[5] += h * e
        xm[5] -= h * e
        e[c] = 0.0
        grad = (anchors.energy(xp) - anchors.energy(xm)) / (2 * h)
        assert grad == pytest.approx(anchors.k * anchors.weight[5] * (x[5, c] - system.rest_positions[5, c]), rel=1e-6)


def test_a_numpy_run_oscillates_at_the_anchor_frequency():
    # one free node, no springs: x'' = -(w k / m) x exactly, so after a quarter period from rest at
    # an offset the node passes through its rest position
    grid = NodeGrid(np.zeros(3), 0.1, np.ones((1, 1, 1), bool))
    base = springs.from_grid(grid, k_structural=0.0, k_shear=0.0, mass=0.2, gravity=(0.0, 0.0, 0.0))
    system = dataclasses.replace(base, extra_terms=(RestAnchors(grid.rest_positions, 20.0, np.ones(1)),))
    omega = np.sqrt(20.0 / 0.2)
    dt = 1e-4
    steps = int(round(np.pi / 2 / omega / dt))
    x0 = grid.rest_positions + [[0.01, 0.0, 0.0]]
    sim = make_simulation(system, "rk4", "numpy", dt=dt, state=I.State(x=x0, v=np.zeros((1, 3)), x_prev=x0))
    sim.step(steps)
    assert abs(sim.positions()[0, 0]) < 0.01 * 2e-3


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_fragment_general_stages_match_float64(ctx, name):
    system, _ = anchored()
    dt = 2e-3
    state = start(system, dt)
    x, _ = gpu_run(ctx, system, name, dt, 100, state, path="general")
    ref = reference(system, name, dt, 100, state)
    without = reference(dataclasses.replace(system, extra_terms=()), name, dt, 100, state)
    assert np.abs(ref.x - without.x).max() > 0.05 * system.spacing  # the term matters
    assert np.abs(x - ref.x).max() <= 1e-3 * system.spacing


@pytest.mark.parametrize("layout, block", [("compact", None), ("blocked", (1, 2, 2)), ("blocked", (2, 2, 1))])
def test_foundation_verlet_in_both_layouts_matches_float64(ctx, layout, block):
    system, _ = anchored()
    dt = 2e-3
    state = start(system, dt)
    sim = make_simulation(system, "verlet", "fragment", dt=dt, ctx=ctx, state=state, path="foundation",
                          layout=layout, block=block)
    try:
        assert sim.block == block
        sim.step(100)
        x = sim.positions().astype(np.float64)
    finally:
        sim.release()
    ref = reference(system, "verlet", dt, 100, state)
    assert np.abs(x - ref.x).max() <= 1e-3 * system.spacing
    general, _ = gpu_run(ctx, system, "verlet", dt, 100, state, path="general")
    assert np.abs(x - general).max() <= 1e-4 * system.spacing


@pytest.mark.parametrize("preconditioner", ["jacobi", "multigrid"])
def test_implicit_euler_numpy_and_gpu_match_float64(ctx, preconditioner):
    system, _ = anchored(5, k_anchor=400.0)
    dt = 1e-2
    state = start(system, dt)
    options = dict(cg_preconditioner=preconditioner, cg_tolerance=1e-6, cg_iterations=200, state=state)
    cpu = make_simulation(system, "implicit-euler", "numpy", dt=dt, **options)
    cpu.step(20)
    without = make_simulation(dataclasses.replace(system, extra_terms=()), "implicit-euler", "numpy", dt=dt, **options)
    without.step(20)
    assert np.abs(cpu.positions() - without.positions()).max() > 0.05 * system.spacing
    gpu = make_simulation(system, "implicit-euler", "fragment", dt=dt, ctx=ctx, **options)
    try:
        gpu.step(20)
        x = gpu.positions().astype(np.float64)
    finally:
        gpu.release()
    assert np.abs(x - cpu.positions()).max() <= 1e-3 * system.spacing


def test_dt_limit_sees_the_term():
    system, _ = anchored(3, k_anchor=5000.0)
    base = dataclasses.replace(system, extra_terms=())
    for integrator in ("verlet", "semi-implicit", "rk4"):
        with_term = dt_limit(system, integrator).dt
        assert with_term < 0.7 * dt_limit(base, integrator).dt
    # the exact limit: 2 / w_max of the free nodes' M^-1 K, the anchors' w k I in K
    free = np.repeat(~system.fixed, 3)
    k = stiffness_matrix(system)[np.ix_(free, free)]
    m = np.repeat(system.mass, 3)[free]
    omega = np.sqrt(np.linalg.eigvalsh(k / np.sqrt(np.outer(m, m))).max())
    exact = dt_limit(system, "verlet", exact=True)
    assert exact.omega == pytest.approx(omega, rel=1e-9)
    # (the global damping of 0.02 N s/m lowers Verlet's limit a little below 2 / w)
    assert 2.0 / omega * (1 - 2e-3) <= exact.dt <= 2.0 / omega
    # and the Gershgorin bound covers it
    assert springs.max_angular_frequency(system).omega >= omega * (1 - 1e-12)


def test_implicit_matrix_holds_the_term():
    from deformgl.sim.implicit import assemble

    system, _ = anchored(3)
    x = system.rest_positions
    lin = assemble(system, x, np.zeros_like(x), 0.0, 1e-2)
    base = assemble(dataclasses.replace(system, extra_terms=()), x, np.zeros_like(x), 0.0, 1e-2)
    diff = (lin.hessian - base.hessian).tocsr()
    expected = system.terms[0].stiffness(x)
    assert abs(diff - expected).max() < 1e-12
    assert sp.issparse(diff)


@pytest.mark.parametrize("integrator, backend", [("verlet", "feedback"), ("xpbd", "numpy"), ("xpbd", "fragment")])
def test_backends_without_its_form_refuse_it_in_one_line(ctx, integrator, backend):
    system, _ = anchored(3)
    with pytest.raises(ValueError) as info:
        make_simulation(system, integrator, backend, dt=1e-3, ctx=ctx)
    message = str(info.value)
    assert "rest anchors" in message and "\n" not in message


# A term that couples two nodes: a zero-length tether between node i and its partner p(i) = i ^ 1
# relative to their rest offset, f_i = -k ((x_i - x_p) - (r_i - r_p)); the chunk reads the
# partner's state by node number (term_position, term_vector).
TETHER_GLSL = """
uniform sampler2DArray u_tether_table;  // xyz the rest offset r_i - r_p (m), w the partner (-1: none)
uniform float u_tether_k;               // N/m
void tether_force(inout vec3 f, TermNode n) {
    vec4 t = term_table(u_tether_table, 1, 0, n);
    if (t.w >= 0.0) {
        f -= u_tether_k * ((n.x - term_position(int(t.w))) - t.xyz);
    }
}
#ifdef TERMS_IMPLICIT
void tether_product(inout vec3 q, TermNode n, vec3 y) {
    vec4 t = term_table(u_tether_table, 1, 0, n);
    if (t.w >= 0.0) {
        q += u_tether_k * (y - term_vector(int(t.w)));
    }
}
void tether_diagonal(inout vec3 d, inout vec3 off, inout float held, TermNode n) {
    d += vec3(term_table(u_tether_table, 1, 0, n).w >= 0.0 ? u_tether_k : 0.0);
}
#endif
"""


class Tethers(Term):
    """Zero-length springs (N/m) between node pairs (2m, 2m + 1) about their rest offset."""

    name = "tethers"

    def __init__(self, rest: np.ndarray, k: float) -> None:
        self.rest = np.asarray(rest, np.float64)
        self.k = float(k)
        n = len(self.rest)
        self.partner = np.arange(n) ^ 1
        self.partner[self.partner >= n] = -1

    def add_forces(self, x, v, t, out):
        has = self.partner >= 0
        p = self.partner[has]
        out[has] -= self.k * ((x[has] - x[p]) - (self.rest[has] - self.rest[p]))

    def energy(self, x):
        has = np.flatnonzero(self.partner > np.arange(len(x)))
        d = (x[has] - x[self.partner[has]]) - (self.rest[has] - self.rest[self.partner[has]])
        return 0.5 * self.k * float(np.sum(d * d))

    def stiffness(self, x):
        n = len(self.rest)
        has = np.flatnonzero(self.partner >= 0)
        rows = np.concatenate([3 * has[:, None] + np.arange(3)] * 2).ravel()
        cols = np.concatenate([3 * has[:, None] + np.arange(3), 3 * self.partner[has][:, None] + np.arange(3)]).ravel()
        vals = np.concatenate([np.full(3 * len(has), self.k), np.full(3 * len(has), -self.k)])
        return sp.csr_matrix((vals, (rows, cols)), shape=(3 * n, 3 * n))

    def glsl(self, grid):
        has = self.partner >= 0
        offset = np.where(has[:, None], self.rest - self.rest[np.where(has, self.partner, 0)], 0.0)
        table = np.concatenate([offset, self.partner[:, None].astype(np.float64)], axis=1)
        return GlslTerm("tether", source=TETHER_GLSL, implicit=True, others=True, uniforms={"u_tether_k": self.k},
                        tables=(NodeTable("u_tether_table", table),))


def tethered(n=4, k=300.0):
    system, grid = anchored(n)
    return dataclasses.replace(system, extra_terms=(*system.extra_terms, Tethers(grid.rest_positions, k))), grid


def test_the_tether_matrix_is_minus_the_force_derivative():
    system, _ = tethered(3)
    tethers = system.terms[1]
    rng = np.random.default_rng(3)
    x = system.rest_positions + rng.normal(size=(system.count, 3)) * 0.01
    dx = rng.normal(size=x.shape) * 1e-6
    f0, f1 = np.zeros_like(x), np.zeros_like(x)
    tethers.add_forces(x, x, 0.0, f0)
    tethers.add_forces(x + dx, x, 0.0, f1)
    assert np.abs(f1 - f0 + (tethers.stiffness(x) @ dx.ravel()).reshape(-1, 3)).max() <= 1e-9 * np.abs(f1 - f0).max()


@pytest.mark.parametrize("name", ["semi-implicit", "rk4", "verlet"])
def test_a_coupling_term_runs_on_the_fragment_stages(ctx, name):
    system, _ = tethered()
    dt = 2e-3
    state = start(system, dt)
    ref = reference(system, name, dt, 100, state)
    without = reference(dataclasses.replace(system, extra_terms=system.extra_terms[:1]), name, dt, 100, state)
    assert np.abs(ref.x - without.x).max() > 0.05 * system.spacing
    x, _ = gpu_run(ctx, system, name, dt, 100, state, path="general")
    assert np.abs(x - ref.x).max() <= 1e-3 * system.spacing


def test_a_coupling_term_takes_the_compact_layout_on_the_foundation_pass(ctx):
    system, _ = tethered(13)  # (a grid the blocked layout would take by itself)
    dt = 2e-3
    state = start(system, dt)
    sim = make_simulation(system, "verlet", "fragment", dt=dt, ctx=ctx, state=state, path="foundation")
    try:
        assert sim.block is None
        sim.step(50)
        x = sim.positions().astype(np.float64)
    finally:
        sim.release()
    assert np.abs(x - reference(system, "verlet", dt, 50, state).x).max() <= 1e-3 * system.spacing
    with pytest.raises(ValueError, match="blocked layout cannot read other nodes' state by number, as tether"):
        make_simulation(system, "verlet", "fragment", dt=dt, ctx=ctx, path="foundation", layout="blocked",
                        block=(1, 2, 2))


def test_a_coupling_term_runs_with_implicit_euler(ctx):
    system, _ = tethered(5)
    dt = 1e-2
    state = start(system, dt)
    options = dict(cg_preconditioner="multigrid", cg_tolerance=1e-6, cg_iterations=200, state=state)
    cpu = make_simulation(system, "implicit-euler", "numpy", dt=dt, **options)
    cpu.step(20)
    gpu = make_simulation(system, "implicit-euler", "fragment", dt=dt, ctx=ctx, **options)
    try:
        gpu.step(20)
        x = gpu.positions().astype(np.float64)
    finally:
        gpu.release()
    assert np.abs(x - cpu.positions()).max() <= 1e-3 * system.spacing
