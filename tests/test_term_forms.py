"""A physics term defined only in the tests — tests/test_term_proof.py's spring from each node to
its rest position, stiffness in N/m — given here its transform-feedback and XPBD forms (issue 43,
item 1: each term declares them, and the backends loop over the terms): its feedback chunk
(``FeedbackTerm``, inline source, float data bit-cast into the integer table) runs on the
transform-feedback backend with every explicit integrator, and its XPBD form (``TermConstraints``:
a vector constraint per node of compliance 1 / (w k), Macklin, Müller & Chentanez 2016, eq. 2-4,
with a pass of its own and a node-sweep chunk) on XPBD in NumPy and on the GPU, each matched to
its float64 reference, with no edit outside the test modules."""

from __future__ import annotations

import dataclasses

import moderngl
import numpy as np
import pytest

from deformgl.gl.es_context import read_texture
from deformgl.gl.programs import Program
from deformgl.gl.resources import GLOwner
from deformgl.grid.nodes import CompactLayout, NodeGrid
from deformgl.sim import integrators as I
from deformgl.sim import springs
from deformgl.sim.backends.compact_textures import compact_image, float_texture
from deformgl.sim.backends.feedback import FeedbackSimulation
from deformgl.sim.integrators import EXPLICIT_INTEGRATORS
from deformgl.sim.simulation import make_simulation
from deformgl.sim.terms import FeedbackTerm, TermConstraints, XpbdChunk, XpbdPasses
from deformgl.sim.xpbd import XpbdSettings, XpbdSolver, constraint_counts
from test_term_proof import RestAnchors, start  # the term's float64 force, energy and stiffness
from test_term_proof import anchored as proof_anchored

# The feedback chunk: the rest position and the weight as float bits in one RGBA32I texel per node.
ANCHOR_FEEDBACK = """
uniform isampler2D u_anchor_nodes;  // xyz rest position (m), w the node's weight, as float bits
uniform float u_anchor_k;           // N/m
void anchor_feedback(inout vec3 f, int i, vec3 xi) {
    vec4 r = intBitsToFloat(texelFetch(u_anchor_nodes, node_slot_texel(i, 1, 0), 0));
    f -= (r.w * u_anchor_k) * (xi - r.xyz);
}
"""

# The XPBD pass: per node one Jacobi update of the vector constraint C = x - rest (compliance
# 1 / (w k)) from the iterate, as the springs' (n_i: the static count + the terms' active ones).
ANCHOR_PASS = """#version 330 core
#include "lib/node_flags.glsl"
uniform sampler2D u_node;            // R inverse mass, G flags, A static constraint count
uniform sampler2D u_p;               // xyz iterate, w the terms' active constraints
uniform sampler2D u_anchor_rest;     // xyz rest position, w weight
uniform sampler2D u_anchor_lambda;   // xyz lambda after the last sweep
uniform float u_anchor_k;            // N/m
uniform float u_h;                   // substep, s
uniform float u_omega;
layout(location = 0) out vec4 o_lambda;
layout(location = 1) out vec4 o_delta;
void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    vec4 node = texelFetch(u_node, texel, 0);
    vec4 r = texelFetch(u_anchor_rest, texel, 0);
    if ((int(node.g) & FLAG_EXISTS) == 0 || !(r.w > 0.0)) {
        o_lambda = vec4(0.0);
        o_delta = vec4(0.0);
        return;
    }
    vec4 p = texelFetch(u_p, texel, 0);
    vec3 lam = texelFetch(u_anchor_lambda, texel, 0).xyz;
    float at = 1.0 / (r.w * u_anchor_k * u_h * u_h);
    vec3 dl = -u_omega * (p.xyz - r.xyz + at * lam) / ((node.a + p.w) * node.r + at);
    o_lambda = vec4(lam + dl, 0.0);
    o_delta = vec4(dl, 0.0);
}
"""

# The node sweep's chunk: the node's correction w_i d_lambda.
ANCHOR_SWEEP = """
uniform sampler2D u_anchor_delta;  // xyz d_lambda of this sweep
void anchor_xpbd(inout vec3 dx, inout float counts, ivec2 texel, int flags, float wi) {
    dx += wi * texelFetch(u_anchor_delta, texel, 0).xyz;
}
"""


class AnchorConstraints(TermConstraints):
    """The anchors as XPBD constraints: per node ``C = x - rest`` (m), compliance ``1 / (w k)``."""

    def __init__(self, anchors: "Anchors", inverse_mass: np.ndarray) -> None:
        self.anchors = anchors
        self.w = np.asarray(inverse_mass, np.float64)

    def static_counts(self):
        return (self.anchors.weight > 0).astype(np.float64)

    def start(self):
        return np.zeros((len(self.w), 3))

    def _at(self, h):
        return 1.0 / (self.anchors.weight * self.anchors.k * h * h)

    def sweep(self, p, multipliers, counts, h, omega):
        lam = multipliers
        at = self._at(h)[:, None]
        dl = -omega * (p - self.anchors.rest + at * lam) / (counts[:, None] * self.w[:, None] + at)
        lam += dl
        return self.w[:, None] * dl

    def residual_terms(self, p, multipliers, h):
        return (p - self.anchors.rest).reshape(-1), (self._at(h)[:, None] * multipliers).reshape(-1)

    def gpu(self, ctx, grid, layout, omega, first_unit):
        return AnchorPasses(ctx, grid, layout, self, omega, first_unit)


class AnchorPasses(GLOwner, XpbdPasses):
    """The anchors' multipliers (ping-pong), their changes and the pass that updates them."""

    def __init__(self, ctx: moderngl.Context, grid: NodeGrid, layout: CompactLayout, constraints: AnchorConstraints,
                 omega: float, first_unit: int) -> None:
        super().__init__(ctx)
        anchors = constraints.anchors
        self.count = grid.count
        self.chunk = XpbdChunk("anchor", "terms/anchor_xpbd.glsl", ("terms/anchor_xpbd.frag",), source=ANCHOR_SWEEP)
        self.samplers = {"u_anchor_rest": first_unit, "u_anchor_lambda": first_unit + 1, "u_anchor_delta": first_unit + 2}
        size = layout.size
        with self.building():
            table = np.concatenate([anchors.rest, anchors.weight[:, None]], axis=1)
            self.rest = float_texture(self, ctx, size, compact_image(size, table))
            self.lambdas = [float_texture(self, ctx, size) for _ in range(2)]
            self.delta = float_texture(self, ctx, size)
            self.program = self.own(Program(ctx, "sim/fullscreen.vert", self.chunk.passes[0],
                                            chunks={self.chunk.passes[0]: ANCHOR_PASS}))
            self.program.set(u_anchor_k=anchors.k, u_omega=float(omega), **self.sweep_uniforms(self.program))
            self.vao = self.own(ctx.vertex_array(self.program.gl, []))
            self.fbos = [self.own(ctx.framebuffer(color_attachments=[self.lambdas[b], self.delta])) for b in range(2)]
            self.clear_fbo = self.own(ctx.framebuffer(color_attachments=[self.lambdas[0]]))
        self.bytes_allocated = 4 * size[0] * size[1] * 16

    def programs(self):
        return [self.program]

    def sweep_uniforms(self, program):
        return {k: v for k, v in self.samplers.items() if k in program.members}

    def clear(self):
        self.clear_fbo.clear(0.0, 0.0, 0.0, 0.0)

    def sweep(self, a, b):
        self.rest.use(self.samplers["u_anchor_rest"])
        self.lambdas[a].use(self.samplers["u_anchor_lambda"])
        self.fbos[b].use()
        self.vao.render(moderngl.TRIANGLES, vertices=3)
        self.delta.use(self.samplers["u_anchor_delta"])

    def read(self, b):
        data = np.frombuffer(read_texture(self.lambdas[b]), dtype=np.float32).reshape(-1, 4)
        return data[: self.count, :3].astype(np.float64)


class Anchors(RestAnchors):
    """test_term_proof's rest anchors (a zero-length spring of stiffness ``weight * k``, N/m, from
    each node to its rest position), with transform-feedback and XPBD forms."""

    name = "feedback anchors"

    def feedback(self, grid):
        table = np.concatenate([self.rest, self.weight[:, None]], axis=1).astype(np.float32).view(np.int32)
        return FeedbackTerm("anchor", "terms/anchor_feedback.glsl", "u_anchor_nodes", table,
                            uniforms={"u_anchor_k": self.k}, source=ANCHOR_FEEDBACK)

    def xpbd(self, inverse_mass):
        return AnchorConstraints(self, inverse_mass)


def anchored(n=4, **options):
    """test_term_proof's anchored lattice, its anchors given the forms above."""
    system, _ = proof_anchored(n, **options)
    rest = system.extra_terms[0]
    return dataclasses.replace(system, extra_terms=(Anchors(rest.rest, rest.k, rest.weight),))


@pytest.mark.parametrize("name", EXPLICIT_INTEGRATORS)
def test_the_feedback_chunk_matches_float64(ctx, name):
    system = anchored()
    dt = 2e-3
    state = start(system, dt)
    ref, without = state, state
    bare = dataclasses.replace(system, extra_terms=())
    for k in range(100):
        ref = I.step(system, name, ref, dt, k * dt)
        without = I.step(bare, name, without, dt, k * dt)
    assert np.abs(ref.x - without.x).max() > 0.05 * system.spacing  # the anchors act
    sim = FeedbackSimulation(ctx, system, name, dt, state=state)
    try:
        assert [f.prefix for f in sim.feedback_terms] == ["anchor"] and len(sim.term_textures) == 1
        sim.step(100)
        x = sim.positions().astype(np.float64)
    finally:
        sim.release()
    assert np.abs(x - ref.x).max() <= 1e-3 * system.spacing


def test_the_xpbd_form_is_the_anchor_force_in_the_limit():
    """A substep solved to convergence is ``M (x - x~) = h^2 f(x)`` with f the springs' and the
    anchors' force as h -> 0: the constraint potential is the anchors' energy."""
    system = anchored(gravity=(0.0, 0.0, 0.0))
    x = system.rest_positions + np.random.default_rng(2).normal(size=(system.count, 3)) * 0.01
    solver = XpbdSolver(system, XpbdSettings(iterations=400))
    assert isinstance(solver.term_constraints[0], AnchorConstraints)
    counts = constraint_counts(system)
    assert np.array_equal(counts - constraint_counts(dataclasses.replace(system, extra_terms=())), np.ones(system.count))
    h = 1e-6
    p, _ = solver.substep(x, np.zeros_like(x), h, 0.0)
    f = springs.forces(system, p, np.zeros_like(p), 0.0)
    free = ~system.fixed
    inertia = system.mass[:, None] * (p - x) / h ** 2
    assert np.abs(inertia - f)[free].max() < 1e-5 * np.abs(f[free]).max()
    assert solver.term_multipliers[0].shape == (system.count, 3)


def test_the_xpbd_passes_match_numpy(ctx):
    system = anchored()
    dt = 1.0 / 60.0
    state = start(system, dt)
    options = dict(iterations=3, substeps=2, state=state)  # (few sweeps: a residual well above float32)
    ref = make_simulation(system, "xpbd", "numpy", dt=dt, **options)
    bare = make_simulation(dataclasses.replace(system, extra_terms=()), "xpbd", "numpy", dt=dt, **options)
    with make_simulation(system, "xpbd", "fragment", dt=dt, ctx=ctx, **options) as gpu:
        assert [type(t) for t in gpu.term_passes] == [AnchorPasses]
        ref.step(10)
        bare.step(10)
        gpu.step(10)
        moved = np.abs(ref.positions() - state.x).max()
        assert np.abs(bare.positions() - ref.positions()).max() > 0.05 * moved  # the anchors act
        assert np.abs(gpu.positions() - ref.positions()).max() <= 1e-4 * moved
        assert gpu.residual == pytest.approx(ref.residual, rel=1e-3)


class CpuOnlyConstraints(AnchorConstraints):
    """The anchors' float64 form without a GPU one (and without a name: the term's is taken)."""

    gpu = TermConstraints.gpu


class CpuOnlyAnchors(Anchors):
    name = "CPU-only anchors"

    def xpbd(self, inverse_mass):
        return CpuOnlyConstraints(self, inverse_mass)


def test_a_form_without_gpu_passes_is_refused_in_one_line(ctx):
    system = anchored()
    cpu_only = dataclasses.replace(system, extra_terms=(CpuOnlyAnchors(system.rest_positions, 30.0, np.ones(system.count)),))
    make_simulation(cpu_only, "xpbd", "numpy", dt=0.01).step(1)  # (the float64 form runs)
    with pytest.raises(ValueError, match=r"^xpbd: CPU-only anchors: no XPBD form on the GPU$"):
        make_simulation(cpu_only, "xpbd", "fragment", dt=0.01, ctx=ctx)


class ShadowingAnchors(Anchors):
    """Anchors whose inline feedback chunk takes a shipped shader's include name."""

    def feedback(self, grid):
        return dataclasses.replace(super().feedback(grid), file="terms/cell_feedback.glsl")


def test_an_inline_chunk_cannot_replace_a_shipped_shader():
    system = anchored()
    shadowing = dataclasses.replace(system, extra_terms=(ShadowingAnchors(system.rest_positions, 30.0, np.ones(system.count)),))
    with pytest.raises(ValueError, match=r"^FeedbackSimulation: a term's inline chunk is named 'terms/cell_feedback.glsl', "
                                         r"a shipped shader's name; give it a name of its own$"):
        FeedbackSimulation(None, shadowing, "rk4", 1e-3)  # (refused before any GL)


def test_a_feedback_form_is_checked_when_made():
    table = np.zeros((4, 8), np.int32)
    form = FeedbackTerm("anchor", "terms/anchor_feedback.glsl", "u_anchor_nodes", table)
    assert form.slots == 2 and form.row_limit(16) == 8 and not form.table.flags.writeable
    image = form.image(4, 2)
    assert image.shape == (2, 8, 4) and image.dtype == np.int32
    with pytest.raises(ValueError, match=r"table of shape \(4, 6\)"):
        FeedbackTerm("anchor", "terms/a.glsl", "u_anchor_nodes", np.zeros((4, 6), np.int32))
    with pytest.raises(ValueError, match="expected \\(N, 4 \\* slots\\) integers"):
        FeedbackTerm("anchor", "terms/a.glsl", "u_anchor_nodes", np.zeros((4, 4), np.float32))
    with pytest.raises(ValueError, match="define 'K' must start with ANCHOR_"):
        FeedbackTerm("anchor", "terms/a.glsl", "u_anchor_nodes", table, defines={"K": 1})
    with pytest.raises(ValueError, match="uniform 'u_k' must start with u_anchor"):
        FeedbackTerm("anchor", "terms/a.glsl", "u_anchor_nodes", table, uniforms={"u_k": 1.0})
    with pytest.raises(ValueError, match="4 nodes do not fit 1 rows of 2"):
        form.image(2, 1)


class BitAnchorPasses(AnchorPasses):
    """The anchors' passes, keeping node bits as the cells' do."""

    def node_bits(self):
        return np.ones(self.count, np.int64)


class BitAnchorConstraints(AnchorConstraints):
    def gpu(self, ctx, grid, layout, omega, first_unit):
        return BitAnchorPasses(ctx, grid, layout, self, omega, first_unit)


class BitAnchors(Anchors):
    name = "bit anchors"

    def xpbd(self, inverse_mass):
        return BitAnchorConstraints(self, inverse_mass)


def test_two_xpbd_forms_with_node_bits_are_refused_naming_both(ctx):
    from deformgl.sim.materials import ElasticMaterial, lattice_system

    grid = NodeGrid(np.zeros(3), 0.1, np.ones((3, 3, 3), bool))
    cells, _ = lattice_system(grid, ElasticMaterial(1e4, 1000.0, poissons_ratio=0.45), fixed=grid.ijk[:, 0] == 0)
    both = dataclasses.replace(cells, extra_terms=(BitAnchors(grid.rest_positions, 30.0, np.ones(grid.count)),))
    with pytest.raises(ValueError, match=r"^xpbd: the cells' volumetric term and bit anchors both keep node bits; "
                                         r"the node data has room for one term's$"):
        make_simulation(both, "xpbd", "fragment", dt=0.01, ctx=ctx)
