"""The spline cells on the fragment backend (issue 44, item 5): the span pass
(``shaders/terms/spline_span.frag``) against the float64 forces of
:class:`~deformgl.sim.terms.spline.term.SplineCells` at rotated, strained and inverted states
with every treatment of the volumetric strain, and the explicit integrators on the GPU against
the float64 reference step for step, as the springs are matched; what the GPU does not run yet is
refused in one line."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from deformgl.gl.resources import GLOwner
from deformgl.grid.nodes import CompactLayout, layout_uniforms
from deformgl.sim import integrators as I
from deformgl.sim.backends.compact_textures import compact_image, float_texture
from deformgl.sim.limits import dt_limit
from deformgl.sim.simulation import make_simulation
from deformgl.sim.terms import GlslTerm
from deformgl.sim.terms.spline.body import SplineBody
from deformgl.sim.terms.spline.cut import fitted_body, inside_body
from deformgl.sim.terms.spline.tables import span_tables
from deformgl.sim.terms.spline.term import SplineAnchor, SplineCells, spline_system

H = 0.02


def bar(nu: float = 0.45, dilatation: str = "p1", length: float = 0.12) -> SplineBody:
    """A 3-across bar at a grid offset (cut spans at both ends and on every side)."""
    return SplineBody.from_box((0, 0, 0), (length, 0.04, 0.04), H, youngs_modulus=1e6, poissons_ratio=nu,
                               density=1000.0, origin=(-0.007, 0.004, 0.001), dilatation=dilatation)


def gpu_forces(ctx, body: SplineBody, x: np.ndarray) -> np.ndarray:
    form = SplineCells(body).glsl(body.grid)
    layout = CompactLayout.for_grid(body.grid, int(ctx.info["GL_MAX_TEXTURE_SIZE"]))
    with GLOwner(ctx) as owner:
        positions = float_texture(owner, ctx, layout.size, compact_image(layout.size, x))
        span_pass = owner.own(form.prepass(ctx, layout_uniforms(layout.width)))
        return span_pass.forces(positions)


def reference_forces(body: SplineBody, x: np.ndarray) -> np.ndarray:
    out = np.zeros_like(x)
    SplineCells(body).add_forces(x, x * 0.0, 0.0, out)
    return out


@pytest.mark.parametrize("dilatation", ["p1", "p0", "full"])
def test_the_span_pass_matches_float64_on_a_turned_strained_body(ctx, dilatation):
    """Turned by 55 degrees, moved 2 m and strained by 1 mm noise on a 2 cm grid: every node's
    force within 1e-4 of the largest (float32 positions at 2 m carry 1e-7 m)."""
    body = bar(dilatation=dilatation)
    rest = body.rest_positions
    turn = Rotation.from_rotvec([0.3, 0.8, -0.5]).as_matrix()
    x = (rest - rest.mean(0)) @ turn.T + rest.mean(0) + [0.1, -0.3, 2.0]
    x += 1e-3 * np.random.default_rng(1).standard_normal(x.shape)
    ref = reference_forces(body, x)
    got = gpu_forces(ctx, body, x)
    assert np.abs(got - ref).max() <= 1e-4 * np.abs(ref).max()
    # a rigid motion alone: no force (to float32 rounding of the same scale)
    still = gpu_forces(ctx, body, (rest - rest.mean(0)) @ turn.T + rest.mean(0) + [0.1, -0.3, 2.0])
    assert np.abs(still).max() <= 1e-3 * np.abs(ref).max()


def test_an_inverted_body_is_pushed_back_on_the_gpu_as_in_float64(ctx):
    """Mirrored through a plane (every span at det F < 0): the rotation stays proper in both, and
    the forces agree within 1e-4 of the largest."""
    body = bar()
    x = body.rest_positions.copy()
    x[:, 1] = 0.04 - x[:, 1]
    x += 1e-4 * np.random.default_rng(2).standard_normal(x.shape)
    ref = reference_forces(body, x)
    assert np.abs(ref).max() > 0
    assert np.abs(gpu_forces(ctx, body, x) - ref).max() <= 1e-4 * np.abs(ref).max()


def clamped(nu: float = 0.45) -> tuple[SplineBody, object]:
    """The bar under gravity, lightly damped, its control points at x <= 0 held."""
    body = bar(nu)
    system = spline_system(body, gravity=(0.0, -9.81, 0.0), mass_damping=5.0)
    return body, dataclasses.replace(system, fixed=body.rest_positions[:, 0] <= 0.0)


@pytest.mark.parametrize("integrator, fraction, steps", [
    ("semi-implicit", 0.5, 100), ("verlet", 0.5, 100), ("rk4", 0.5, 100),
    # (explicit Euler and midpoint grow without heavy damping: a short run at a small step)
    ("euler", 0.1, 60), ("midpoint", 0.1, 60)])
def test_the_fragment_backend_runs_the_body_as_the_float64_reference(ctx, integrator, fraction, steps):
    """Each explicit integrator on the fragment backend's stages (the span pass before every
    stage, at the stage's state), from a kicked start: positions within 1e-3 h of the float64
    reference step after step (the springs' tolerance, tests/test_term_proof.py; measured 3e-5 h,
    Verlet 5e-4 h: its float32 positions carry the velocity as a difference), while the elastic
    forces move the nodes by 0.3 h (Euler and midpoint: 0.025 h)."""
    body, system = clamped()
    dt = fraction * dt_limit(system, "semi-implicit").dt
    kick = np.random.default_rng(3).normal(size=(body.count, 3)) * 0.02 * (~system.fixed[:, None])
    state = I.initial_state(system, dt, v=kick)
    ref = state
    for k in range(steps):
        ref = I.step(system, integrator, ref, dt, k * dt)
    sim = make_simulation(system, integrator, "fragment", dt=dt, ctx=ctx, state=state)
    try:
        sim.step(steps)
        x = sim.positions().astype(np.float64)
    finally:
        sim.release()
    free = state  # the same run without the body's elasticity: what the term moved
    for k in range(steps):
        free = I.step(dataclasses.replace(system, extra_terms=()), integrator, free, dt, k * dt)
    assert np.abs(ref.x - free.x).max() > 10e-3 * H
    assert np.abs(x - ref.x).max() <= 1e-3 * H


def test_what_the_gpu_does_not_run_is_refused_in_one_line(ctx):
    body, system = clamped()
    for integrator, backend, form in (("semi-implicit", "feedback", "transform-feedback"), ("xpbd", "fragment", "XPBD")):
        with pytest.raises(ValueError, match=f"spline cells have no {form} form yet"):
            make_simulation(system, integrator, backend, dt=1e-4, ctx=ctx)
    with pytest.raises(ValueError, match="spline cells have no implicit-Euler form yet"):
        make_simulation(system, "implicit-euler", "fragment", dt=1e-4, ctx=ctx)
    with pytest.raises(ValueError, match=r"does not model a term with a pass of its own \(spline\)"):
        make_simulation(system, "verlet", "fragment", dt=1e-4, ctx=ctx, path="foundation")
    with pytest.raises(ValueError, match="does not model a term with a pass of its own"):
        make_simulation(system, "verlet", "fragment", dt=1e-4, ctx=ctx, layout="blocked", block=(1, 2, 2))
    points, weights = body.face_points(0, 0.0, [0, 0, 0], [0.12, 0.04, 0.04])
    anchor = SplineAnchor(body, points, weights, 1e9)
    for backend, form in (("feedback", "transform-feedback"), ("xpbd", "XPBD"), ("implicit", "implicit-Euler")):
        assert anchor.refusal(backend) == f"spline anchors have no {form} form yet (the NumPy reference runs them)"


def sampled_ball() -> SplineBody:
    return inside_body(lambda p: np.linalg.norm(p, axis=1) <= 0.05, [-0.05] * 3, [0.05] * 3, H,
                       youngs_modulus=1e4, poissons_ratio=0.3, density=1000.0)


def test_a_body_with_sampled_cut_spans_is_refused_by_the_glsl_form_in_one_line():
    with pytest.raises(ValueError, match=r"holds \d+ Gauss points; the GLSL form takes one 3 x 3 x 3 grid a span "
                                         r"\(deformgl.sim.terms.spline.cut.fitted_body gives one\)"):
        span_tables(sampled_ball())


def test_a_moment_fitted_ball_runs_on_the_gpu_as_in_float64(ctx):
    """A sampled ball's cut spans moment-fitted (one grid of 27 points a span, some of them
    weightless where the fit is the non-negative one): the span pass's forces at a turned,
    strained state within 1e-4 of the largest."""
    body = fitted_body(sampled_ball())
    assert len(body.point_s) == 27 * len(body.span_nodes) and (body.point_weight == 0).any()
    rest = body.rest_positions
    x = rest @ Rotation.from_rotvec([0.2, -0.4, 0.9]).as_matrix().T + 1e-3 * np.random.default_rng(5).standard_normal(rest.shape)
    ref = reference_forces(body, x)
    assert np.abs(gpu_forces(ctx, body, x) - ref).max() <= 1e-4 * np.abs(ref).max()


def test_a_form_that_names_passes_without_running_them_is_refused():
    from deformgl.sim.terms.glsl import pass_terms
    from deformgl.sim.terms.spline.glsl_form import GLSL

    class Bare(SplineCells):
        def glsl(self, grid):
            return GLSL  # (the pack's form: its pass named, no pre-pass to run it)

    with pytest.raises(ValueError, match="names passes of its own but has no pre-pass to run them"):
        pass_terms([Bare(bar())], "fragment", "test", None, prepass=True)


def test_the_span_tables_hold_what_the_shader_reads():
    body = bar()
    t = span_tables(body)
    assert t.nodes.shape == (len(body.span_nodes), 28) and np.array_equal(t.nodes[:, :27], body.span_nodes)
    np.testing.assert_allclose(t.data[:, 12:39].sum(axis=1), body.span_volume, rtol=1e-6)
    # each node is node a of the span centred at its -offset_a neighbour, once
    spans = t.node_spans[:, :27]
    s, a = np.nonzero(spans.T >= 0)
    assert len(s) == 27 * len(body.span_nodes)
    centre = body.span_nodes[spans[a, s].astype(int), 13]
    assert np.array_equal(body.span_nodes[spans[a, s].astype(int), s], a)
    assert np.all(body.grid.ijk[a] - body.grid.ijk[centre] == np.array(list(np.ndindex(3, 3, 3)))[s] - 1)


def test_a_prepass_comes_with_its_samplers():
    with pytest.raises(ValueError, match="a pre-pass and its samplers come together"):
        GlslTerm("thing", source="", prepass_samplers=("u_thing_f",))


# -- the mapping: a detailed mesh drawn through the body's field ---------------------------------

def mapped(ctx, body: SplineBody, x: np.ndarray, vertices: np.ndarray, normals: np.ndarray):
    from deformgl.render.bspline_premap import BSplinePremap

    layout = CompactLayout.for_grid(body.grid, int(ctx.info["GL_MAX_TEXTURE_SIZE"]))
    with GLOwner(ctx) as owner:
        positions = float_texture(owner, ctx, layout.size, compact_image(layout.size, x))
        premap = owner.own(BSplinePremap(ctx, body, layout_uniforms(layout.width), vertices, normals))
        premap.run(positions)
        return premap.read()


def mesh_points(count: int = 300) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(11)
    vertices = rng.uniform([0, 0, 0], [0.12, 0.04, 0.04], (count, 3))
    vertices[:40, 1] = 0.04  # (on the top face)
    normals = rng.normal(size=(count, 3))
    return vertices, normals / np.linalg.norm(normals, axis=1, keepdims=True)


def test_the_mapping_draws_the_field_the_body_was_solved_with(ctx):
    """Mapped vertices against the float64 field at a turned, strained state, 2 m from the origin
    (within 1e-6 m: float32 there carries 1e-7), their normals against cof(F) n (within 1e-4 rad);
    at rest every vertex at its place (the basis reproduces linear functions)."""
    body = bar()
    rest = body.rest_positions
    turn = Rotation.from_rotvec([0.3, 0.8, -0.5]).as_matrix()
    x = (rest - rest.mean(0)) @ turn.T + rest.mean(0) + [0.1, -0.3, 2.0]
    x += 2e-3 * np.random.default_rng(1).standard_normal(x.shape)
    vertices, normals = mesh_points()
    world, normal = mapped(ctx, body, x, vertices, normals)
    np.testing.assert_allclose(world, body.field(vertices, x), rtol=0, atol=1e-6)
    nodes, _, gradients = body.locate(vertices)
    f = np.einsum("vai,vaj->vij", x[nodes], gradients)
    expected = np.einsum("vij,vj->vi", np.linalg.inv(f).transpose(0, 2, 1), normals)
    sine = np.linalg.norm(np.cross(normal, expected), axis=1) / np.linalg.norm(normal, axis=1) / np.linalg.norm(expected, axis=1)
    assert np.all(sine < 1e-4) and np.all(np.einsum("vi,vi->v", normal, expected) > 0)
    still, still_normal = mapped(ctx, body, rest, vertices, normals)
    np.testing.assert_allclose(still, vertices, rtol=0, atol=1e-7)
    np.testing.assert_allclose(still_normal, normals, rtol=0, atol=1e-6)


def test_a_vertex_outside_the_bodys_spans_is_refused_in_one_line(ctx):
    from deformgl.render.bspline_premap import BSplinePremap

    body = bar()
    vertices, normals = mesh_points(5)
    vertices[3] = [0.5, 0.0, 0.0]
    with pytest.raises(ValueError, match=r"^spline mapping: vertex 3 at \[0.5, 0.0, 0.0\] m is more than a node from the body.s spans$"):
        BSplinePremap(ctx, body, layout_uniforms(16), vertices, normals)


# -- held regions: the penalty anchor ---------------------------------------------------------

def anchor_forces(ctx, body: SplineBody, anchor: SplineAnchor, x: np.ndarray) -> np.ndarray:
    form = anchor.glsl(body.grid)
    layout = CompactLayout.for_grid(body.grid, int(ctx.info["GL_MAX_TEXTURE_SIZE"]))
    with GLOwner(ctx) as owner:
        positions = float_texture(owner, ctx, layout.size, compact_image(layout.size, x))
        return owner.own(form.prepass(ctx, layout_uniforms(layout.width))).forces(positions)


@pytest.mark.parametrize("region", ["face", "volume"])
def test_the_anchors_span_pass_matches_float64(ctx, region):
    """The penalty of a clamped face (9 points a span piece) and of a held box of material (27 a
    piece, several pieces a span) at a moved, strained state: within 1e-5 of the largest force."""
    body = bar()
    if region == "face":
        points, weights = body.face_points(0, 0.0, [0, 0, 0], [0.12, 0.04, 0.04])
    else:
        from deformgl.sim.terms.spline.basis import gauss_box

        lo = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.02, 0.0]])
        p, w = gauss_box(lo, lo + [0.01, 0.02, 0.04])
        points, weights = p.reshape(-1, 3), w.ravel()
    anchor = SplineAnchor(body, points, weights, 1e8)
    x = body.rest_positions + [0.003, -0.01, 0.002] + 1e-3 * np.random.default_rng(4).standard_normal((body.count, 3))
    ref = np.zeros_like(x)
    anchor.add_forces(x, x * 0, 0.0, ref)
    assert np.abs(anchor_forces(ctx, body, anchor, x) - ref).max() <= 1e-5 * np.abs(ref).max()


def test_a_penalty_clamped_cantilever_runs_on_the_gpu_as_in_float64(ctx):
    """The bar clamped by a penalty of 30 E / h on its x = 0 face (the accuracy studies' clamp),
    under gravity, semi-implicit Euler at half its dt limit: 100 steps within 1e-3 h of the float64
    reference, the tip sagging many times that."""
    body = bar()
    points, weights = body.face_points(0, 0.0, [0, 0, 0], [0.12, 0.04, 0.04])
    anchor = SplineAnchor(body, points, weights, 30 * 1e6 / H)
    system = spline_system(body, anchors=(anchor,), gravity=(0.0, -9.81, 0.0), mass_damping=5.0)
    dt = 0.5 * dt_limit(system, "semi-implicit").dt
    state = I.initial_state(system, dt)
    ref = state
    for k in range(100):
        ref = I.step(system, "semi-implicit", ref, dt, k * dt)
    sim = make_simulation(system, "semi-implicit", "fragment", dt=dt, ctx=ctx, state=state)
    try:
        sim.step(100)
        x = sim.positions().astype(np.float64)
    finally:
        sim.release()
    assert np.abs(ref.x - state.x).max() > 0.02 * H
    assert np.abs(x - ref.x).max() <= 1e-3 * H
