"""Spline cells (issue 44): the quadratic B-spline body on the node grid, float64.

The basis (partition of unity, linear precision, gradients), the body's integrals (mass and
volume exact at any grid offset, rigid motions free of force, forces the energy's gradient, the
assembled K the forces' linearisation), the corotational term (rotation invariance, inversion
pushed back), and physics against finite elements (``python -m studies.spline_dilatation``): the
1 x 0.1 x 0.1 m cantilever of docs/ACCURACY.md section 2 within 1 % of the FEM of its ν
(docs/ACCURACY.md section 3's references) at 3 and 5 nodes across (9 across, ν 0.25, 0.45 and
0.49, in the slow run), and the cube column's bulge at ν 0.45 and 0.49."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse.linalg as spl

from deformgl.sim.terms.spline.basis import SPAN_OFFSETS, axis_basis, gauss_box, span_basis
from deformgl.sim.terms.spline.body import DILATATIONS, SplineBody
from deformgl.sim.terms.spline.cut import fitted_body, inside_body, sample_body
from deformgl.sim.terms.spline.term import SplineAnchor, SplineCells, polar_rotations, spline_system
from studies.spline_dilatation import cantilever_ratio, column_ratio

E, RHO, G = 1.0e8, 1000.0, 9.81


def box(across: int = 3, nu: float = 0.25, *, size=(1.0, 0.1, 0.1), origin=None, dilatation: str = "p1") -> SplineBody:
    h = min(size) / (across - 1)
    return SplineBody.from_box([0.0, 0.0, 0.0], size, h, youngs_modulus=E, poissons_ratio=nu, density=RHO,
                               origin=origin, dilatation=dilatation)


# -- the basis ---------------------------------------------------------------------------------

def test_the_basis_is_a_partition_of_unity_with_linear_precision_and_its_gradients():
    s = np.random.default_rng(0).uniform(-0.5, 0.5, (50, 3))
    h = 0.013
    values, gradients = span_basis(s, h)
    np.testing.assert_allclose(values.sum(axis=1), 1.0, atol=1e-14)
    assert values.min() >= 0.0
    nodes = SPAN_OFFSETS * h  # a span's 27 nodes about its centre
    np.testing.assert_allclose(values @ nodes, s * h, atol=1e-15)  # sum X_a N_a(x) = x
    np.testing.assert_allclose(gradients.sum(axis=1), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.einsum("pai,aj->pij", gradients, nodes), np.broadcast_to(np.eye(3), (50, 3, 3)),
                               atol=1e-12)
    eps = 1e-6
    for d in range(3):
        step = np.zeros(3)
        step[d] = eps
        numeric = (span_basis(s + step, h)[0] - span_basis(s - step, h)[0]) / (2 * eps * h)
        np.testing.assert_allclose(gradients[:, :, d], numeric, atol=1e-6)
    # C1 across the knot: node c's function seen from span c (s = 1/2) and from span c + 1 (s = -1/2)
    left, left_slope = axis_basis(np.array(0.5))
    right, right_slope = axis_basis(np.array(-0.5))
    np.testing.assert_allclose(left[1:], right[:2])
    np.testing.assert_allclose(left_slope[1:], right_slope[:2])


def test_gauss_boxes_integrate_their_volume():
    points, weights = gauss_box(np.array([[-0.5, -0.5, -0.5], [0.1, -0.2, 0.0]]), np.array([[0.5, 0.5, 0.5], [0.3, 0.5, 0.5]]))
    np.testing.assert_allclose(weights.sum(axis=1), [1.0, 0.2 * 0.7 * 0.5])
    assert points[1, :, 0].min() > 0.1 and points[1, :, 0].max() < 0.3


# -- the body ----------------------------------------------------------------------------------

@pytest.mark.parametrize("origin", [None, (0.013, -0.02, 0.031), (-0.5, -0.5, -0.5)])
def test_mass_and_volume_are_exact_at_any_grid_offset(origin):
    """The spans hold the box exactly wherever the grid lies: volume and mass to rounding (the
    issue asks 0.5 %), the mass the row sums of the consistent mass."""
    body = SplineBody.from_box([0.0, 0.0, 0.0], [0.3, 0.2, 0.1], 0.05, youngs_modulus=1e5, poissons_ratio=0.3,
                               density=1100.0, origin=None if origin is None else np.array(origin) * 0.05)
    assert body.volume == pytest.approx(0.006, rel=1e-12)
    assert body.lumped_mass.sum() == pytest.approx(1100.0 * 0.006, rel=1e-12)
    assert body.lumped_mass.min() > 0.0
    # the field of the rest positions is the identity (linear precision through the body), on its
    # faces too (a face on a knot plane belongs to the span inside)
    p = np.random.default_rng(1).uniform([0, 0, 0], [0.3, 0.2, 0.1], (40, 3))
    p[:6] = [[0, 0.1, 0.05], [0.3, 0.1, 0.05], [0.15, 0, 0.05], [0.15, 0.2, 0.05], [0.15, 0.1, 0], [0.15, 0.1, 0.1]]
    np.testing.assert_allclose(body.field(p, body.rest_positions), p, atol=1e-14)


def test_a_face_on_a_knot_plane_adds_no_empty_spans():
    """Faces a rounding error off a knot plane (0.087 and 0.107 m with knots there): the spans
    beyond hold nothing and are not built, so no node is left without mass."""
    body = SplineBody.from_box([0, 0, 0.087], [0.03, 0.02, 0.107], 0.01, youngs_modulus=1e4, poissons_ratio=0.3,
                               density=1000.0, origin=[0.005, 0.005, 0.092])
    assert len(body.span_nodes) == 3 * 2 * 2 and body.lumped_mass.min() > 0
    assert body.volume == pytest.approx(0.03 * 0.02 * 0.02, rel=1e-12)
    spline_system(body)  # (every node has a mass)


@pytest.mark.parametrize("dilatation", DILATATIONS)
def test_the_body_is_free_of_rigid_motion_and_its_forces_are_the_energy_gradient(dilatation):
    body = SplineBody.from_box([0.0, 0.0, 0.0], [0.3, 0.2, 0.1], 0.05, youngs_modulus=1e5, poissons_ratio=0.45,
                               density=1000.0, origin=[0.013, -0.02, 0.031], dilatation=dilatation)
    rng = np.random.default_rng(2)
    u = rng.normal(size=(body.count, 3)) * 1e-3
    k = body.assemble()
    f = body.linear_forces(u)
    np.testing.assert_allclose(f.ravel(), -(k @ u.ravel()), atol=1e-12 * np.abs(f).max())
    assert abs(k - k.T).max() <= 1e-14 * abs(k).max()
    scale = np.abs(f).max()
    assert np.abs(body.linear_forces(np.tile([1.0, 2.0, 3.0], (body.count, 1)))).max() < 1e-9 * scale
    assert np.abs(body.linear_forces(np.cross([0.0, 0.0, 1e-3], body.rest_positions))).max() < 1e-9 * scale
    d = rng.normal(size=u.shape) * 1e-7
    _, e_plus = body.span_forces((u + d)[body.span_nodes])
    _, e_minus = body.span_forces((u - d)[body.span_nodes])
    assert (e_plus - e_minus) / 2 == pytest.approx(-(f * d).sum(), rel=1e-6)
    assert body.span_forces(u[body.span_nodes])[1] == pytest.approx(0.5 * u.ravel() @ (k @ u.ravel()), rel=1e-12)
    # the two ways to the sums: each kind of span's matrix, and the stresses at the Gauss points
    by_matrix, e_matrix = body.span_forces(u[body.span_nodes], by_points=False)
    by_points, e_points = body.span_forces(u[body.span_nodes], by_points=True)
    np.testing.assert_allclose(by_matrix, by_points, atol=1e-12 * np.abs(by_points).max())
    assert e_matrix == pytest.approx(e_points, rel=1e-12)


def test_a_uniform_strain_stores_the_continuum_energy():
    """A linear displacement field is reproduced exactly; its energy is V (mu e_dev:e_dev +
    kappa/2 tr(e)^2) with every dilatation (the projection of a constant is the constant)."""
    eps = np.array([[1.0, 0.3, 0.0], [0.3, -0.4, 0.2], [0.0, 0.2, 0.5]]) * 1e-3
    for dilatation in DILATATIONS:
        body = box(3, 0.4, size=(0.3, 0.2, 0.1), origin=[0.01, 0.02, -0.03], dilatation=dilatation)
        u = body.rest_positions @ eps.T
        mu, kappa = body.moduli
        dev = eps - np.trace(eps) / 3 * np.eye(3)
        expected = body.volume * (mu * np.sum(dev * dev) + 0.5 * kappa * np.trace(eps) ** 2)
        assert body.span_forces(u[body.span_nodes])[1] == pytest.approx(expected, rel=1e-10)


def test_bad_bodies_are_refused_in_one_line():
    with pytest.raises(ValueError, match="Poisson's ratio must be in"):
        box(3, 0.5)
    with pytest.raises(ValueError, match="dilatation must be one of p1, p0, full"):
        box(3, dilatation="mean")
    with pytest.raises(ValueError, match="an empty box"):
        SplineBody.from_box([0, 0, 0], [0.1, 0.0, 0.1], 0.05, youngs_modulus=1e5, poissons_ratio=0.3, density=1.0)
    with pytest.raises(ValueError, match="point 0 at .* outside the control grid's spans"):
        box(3).field(np.array([[5.0, 0.0, 0.0]]), box(3).rest_positions)


# -- the corotational term ---------------------------------------------------------------------

def test_the_corotational_forces_follow_a_rotation_and_tend_to_the_linear_ones():
    body = box(3, 0.3, size=(0.3, 0.1, 0.1))
    cells = SplineCells(body)
    rng = np.random.default_rng(3)
    theta = 0.7
    r = np.array([[np.cos(theta), -np.sin(theta), 0.0], [np.sin(theta), np.cos(theta), 0.0], [0.0, 0.0, 1.0]])
    rigid = body.rest_positions @ r.T + [0.3, -1.0, 2.0]
    out = np.zeros_like(rigid)
    cells.add_forces(rigid, rigid * 0, 0.0, out)
    assert np.abs(out).max() < 1e-6 and cells.energy(rigid) < 1e-18
    x = body.rest_positions + rng.normal(size=(body.count, 3)) * 2e-3
    f1, f2 = np.zeros_like(x), np.zeros_like(x)
    cells.add_forces(x, x * 0, 0.0, f1)
    cells.add_forces(x @ r.T, x * 0, 0.0, f2)
    np.testing.assert_allclose(f1 @ r.T, f2, atol=1e-10 * np.abs(f1).max())
    assert cells.energy(x) == pytest.approx(cells.energy(x @ r.T), rel=1e-9)
    u = rng.normal(size=(body.count, 3))
    errors = []
    for scale in (1e-3, 1e-4):  # second order: the gap to the linear forces shrinks as scale^2
        f = np.zeros_like(u)
        cells.add_forces(body.rest_positions + scale * u, u * 0, 0.0, f)
        errors.append(np.abs(f - body.linear_forces(scale * u)).max())
    assert errors[1] < 0.02 * errors[0]
    k = cells.stiffness(x)
    assert abs(k - k.T).max() <= 1e-12 * abs(k).max()
    # at a rigid placement the rotations' own derivative multiplies zero local forces: K is exact
    d = rng.normal(size=u.shape) * 1e-7
    fp, fm = np.zeros_like(u), np.zeros_like(u)
    cells.add_forces(rigid + d, u * 0, 0.0, fp)
    cells.add_forces(rigid - d, u * 0, 0.0, fm)
    kd = (cells.stiffness(rigid) @ d.ravel()).reshape(-1, 3)
    np.testing.assert_allclose(-(fp - fm) / 2, kd, atol=1e-4 * np.abs(kd).max())


def test_an_inverted_span_is_counted_and_pushed_back():
    body = box(3, 0.3, size=(0.3, 0.1, 0.1))
    cells = SplineCells(body)
    assert cells.inversions(body.rest_positions, body.grid) == (0, "")
    x = body.rest_positions.copy()
    x[:, 1] = 0.05 - 0.5 * (x[:, 1] - 0.05)  # squashed through y = 0.05 to half: every span inverted
    count, phrase = cells.inversions(x, body.grid)
    assert count == len(body.span_nodes) and "spline spans inverted (first: the span of node" in phrase
    r = polar_rotations(cells.deformation(x))
    np.testing.assert_allclose(np.linalg.det(r), 1.0)
    f = np.zeros_like(x)
    cells.add_forces(x, x * 0, 0.0, f)
    assert np.sum(f[:, 1] * (x[:, 1] - 0.05)) < 0  # pushed back through the plane, not kept mirrored
    assert cells.energy(x) > 0


def test_the_backends_without_a_form_refuse_the_terms_in_one_line():
    """The fragment backend runs the cells and the anchor (tests/test_spline_gpu.py); implicit
    Euler, transform feedback and XPBD refuse them in one line naming the term."""
    body = box(3)
    cells = SplineCells(body)
    for backend, form in (("implicit", "implicit-Euler"), ("feedback", "transform-feedback"), ("xpbd", "XPBD")):
        assert cells.refusal(backend) == f"spline cells have no {form} form yet (the NumPy reference runs them)"
    assert cells.refusal("numpy") is None and cells.refusal("fragment") is None
    points, weights = body.face_points(0, 0.0, [0, 0, 0], [1.0, 0.1, 0.1])
    anchor = SplineAnchor(body, points, weights, 1e9)
    assert anchor.refusal("fragment") is None
    assert anchor.refusal("xpbd") == "spline anchors have no XPBD form yet (the NumPy reference runs them)"


# -- against finite elements -------------------------------------------------------------------

@pytest.mark.parametrize("across", [3, 5])
def test_the_cantilever_is_within_1_percent_of_fem(across):
    """docs/ACCURACY.md section 2's cantilever (the lattice: 0.81 and 0.94 of FEM at 3 and 5 across),
    its static solve by ``python -m studies.spline_dilatation``."""
    assert cantilever_ratio(across, 0.25) == pytest.approx(1.0, abs=0.01)


@pytest.mark.slow
@pytest.mark.parametrize("nu", [pytest.param(0.25, marks=pytest.mark.soak), 0.45, 0.49])
def test_the_cantilever_at_9_across_is_within_1_percent_of_fem_at_any_nu(nu):
    """At 9 across (10,043 control points, about 30 s a case) against the FEM of its ν (the issue
    asks 2 % at 0.45 and 0.49): no volumetric locking. ν = 1/4 (1.0000 measured; 3 and 5 across
    run in the fast suite) is a soak run, outside CI's time budget."""
    assert cantilever_ratio(9, nu) == pytest.approx(1.0, abs=0.01)


@pytest.mark.parametrize("nu", [0.45, 0.49])
def test_the_column_bulges_as_the_mixed_fem_at_high_nu(nu):
    """The cube column of docs/ACCURACY.md section 3 (where ν shows; the lattice: 1.0102 and 1.0145
    at 9 across): within 2 % at 5 across."""
    assert column_ratio(5, nu) == pytest.approx(1.0, abs=0.02)


def test_the_clamp_penalty_converges():
    """The clamp's penalty beta E / h: ten times stiffer moves the sag by less than 0.5 %."""
    assert cantilever_ratio(3, 0.25, clamp=1e4) / cantilever_ratio(3, 0.25) == pytest.approx(1.0, abs=0.005)


def small_cantilever(nu: float, mass_damping: float):
    """An 8 x 4 x 4 cm cantilever (h = 2 cm, E = 1 MPa: the linear regime) clamped by a penalty of
    30 E / h on its x = 0 face, under gravity: its body, its system, and its end face's mean sag
    (m, downward positive) as a function of node displacements, with the static solve's sag."""
    size = (0.08, 0.04, 0.04)
    body = SplineBody.from_box([0, 0, 0], size, 0.02, youngs_modulus=1e6, poissons_ratio=nu, density=RHO)
    points, weights = body.face_points(0, 0.0, [0, 0, 0], size)
    anchor = SplineAnchor(body, points, weights, 30 * 1e6 / 0.02)
    system = spline_system(body, anchors=(anchor,), gravity=(0.0, -G, 0.0), mass_damping=mass_damping)
    k = system.extra_terms[0].dt_stiffness(body.rest_positions) + anchor.matrix
    f = np.zeros((body.count, 3))
    f[:, 1] = -body.lumped_mass * G
    tip, tip_w = body.face_points(0, size[0], [0, 0, 0], size)

    def sag(u: np.ndarray) -> float:
        return -float(body.field(tip, u)[:, 1] @ tip_w) / tip_w.sum()

    return body, system, sag, sag(spl.spsolve(k.tocsc(), f.ravel()).reshape(-1, 3))


def test_the_numpy_reference_runs_the_body_and_settles_on_its_static_sag():
    """The spline system on the NumPy reference: dt_limit from the term (Lanczos on its mass and
    stiffness), semi-implicit Euler at 0.9 of it, damped, settles within 1 % of the static solve of
    the same penalty (a small, stiff cantilever: the linear regime)."""
    from deformgl.sim.limits import dt_limit
    from deformgl.sim.simulation import make_simulation

    body, system, sag, static = small_cantilever(0.3, 150.0)
    limit = dt_limit(system, "semi-implicit")
    assert 1e-6 < limit.dt < 1e-3
    sim = make_simulation(system, "semi-implicit", "numpy", dt=0.9 * limit.dt)
    sim.step(int(0.12 / sim.dt))
    assert sag(sim.positions() - body.rest_positions) / static == pytest.approx(1.0, abs=0.01)


# -- a body of any shape: spans cut by sampling ------------------------------------------------

def ball(h: float = 0.02, radius: float = 0.05, subdivisions: int = 4) -> SplineBody:
    return inside_body(lambda p: np.linalg.norm(p, axis=1) <= radius, [-radius] * 3, [radius] * 3, h,
                       youngs_modulus=1e4, poissons_ratio=0.3, density=1000.0, subdivisions=subdivisions)


def test_a_sampled_ball_holds_its_volume_and_its_mass():
    """A ball of radius 2.5 h, its spans cut into 4^3 sub-boxes: volume within 1 % (1.0084
    measured; 8^3: 1.0012), the mass rho times the sampled volume exactly, only the nodes whose
    support meets it, the field of the rest positions the identity inside."""
    body = ball()
    volume = 4.0 / 3.0 * np.pi * 0.05 ** 3
    assert body.volume / volume == pytest.approx(1.0, abs=0.01)
    assert ball(subdivisions=8).volume / volume == pytest.approx(1.0, abs=0.002)
    assert body.lumped_mass.sum() == pytest.approx(1000.0 * body.volume, rel=1e-12)
    assert body.lumped_mass.min() > 0 and body.count < 6 ** 3 + 2 * 6 * 6 * 6  # (not the whole dilated box)
    p = np.random.default_rng(4).normal(size=(30, 3))
    p *= 0.045 * np.random.default_rng(5).uniform(0, 1, (30, 1)) / np.linalg.norm(p, axis=1, keepdims=True)
    np.testing.assert_allclose(body.field(p, body.rest_positions), p, atol=1e-14)
    with pytest.raises(ValueError, match="no material inside the box"):
        inside_body(lambda q: np.zeros(len(q), bool), [0, 0, 0], [0.1, 0.1, 0.1], 0.02,
                    youngs_modulus=1e4, poissons_ratio=0.3, density=1.0)


@pytest.mark.slow
def test_the_sampled_balls_slivers_do_not_set_its_dt():
    """The small-cut-cell problem (issue 44, item 5): the ball's lightest control point holds 3e-6
    of the mean mass, yet the explicit dt limit is within 2x of the full box's at the same
    spacing (1.05x measured: a sliver's stiffness shrinks with its mass)."""
    from deformgl.sim.limits import dt_limit

    body = ball()
    assert body.lumped_mass.min() < 1e-4 * body.lumped_mass.mean()
    cube = SplineBody.from_box([-0.05] * 3, [0.05] * 3, 0.02, youngs_modulus=1e4, poissons_ratio=0.3, density=1000.0)
    limits = [dt_limit(spline_system(b, gravity=(0.0, 0.0, 0.0)), "semi-implicit").dt for b in (body, cube)]
    assert 0.5 < limits[0] / limits[1] < 2.0


@pytest.mark.parametrize("integrator", ["semi-implicit", "verlet", "rk4"])
def test_every_explicit_integrator_runs_the_body_at_0_9_of_its_dt_limit(integrator):
    """dt_limit means the same for the spline term as for the springs: each integrator at 0.9 of
    its own limit (the limits differ: RK4's is larger) stays bounded and finite for 300 steps of a
    lightly damped cantilever, the tip below twice its static sag; at 1.1 of it the run grows
    without bound (the limit is the real one, not a safe guess)."""
    import warnings

    from deformgl.sim.limits import dt_limit
    from deformgl.sim.simulation import NumpySimulation, make_simulation

    body, system, sag, static = small_cantilever(0.45, 5.0)
    sim = make_simulation(system, integrator, "numpy", dt=0.9 * dt_limit(system, integrator).dt)
    sim.step(300)
    x = sim.positions()
    assert np.isfinite(x).all()
    assert 0.0 < sag(x - body.rest_positions) / static < 2.0
    over = NumpySimulation(system, integrator, 1.1 * dt_limit(system, integrator).dt)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # (the growth overflows, as it should)
        over.step(300)
        grown = over.positions()
    assert not np.isfinite(grown).all() or np.abs(grown - body.rest_positions).max() > 1.0


@pytest.mark.slow
def test_moment_fitting_keeps_the_mass_and_the_sag_of_a_cut_body():
    """A sampled body's cut spans fitted to one 3 x 3 x 3 grid each (their 27 moments of degree <= 2
    per axis): every node's mass and the body's volume to rounding; the static sag of the section 2
    cantilever, cut by its faces at a grid offset of 0.3 h, within 1e-3 of the sub-box body's
    (1e-4 measured); a body without cut spans is returned as it is."""
    from studies.spline_dilatation import CANTILEVER_FEM, _solve

    size = np.array([1.0, 0.1, 0.1])
    h = 0.05
    sampled = inside_body(lambda p: np.all((p >= 0) & (p <= size), axis=1), [0, 0, 0], size, h,
                          youngs_modulus=E, poissons_ratio=0.25, density=RHO, origin=[-0.3 * h, -0.3 * h, -0.2 * h])
    fitted = fitted_body(sampled)
    assert len(fitted.point_s) == 27 * len(fitted.span_nodes) < len(sampled.point_s)
    np.testing.assert_allclose(fitted.lumped_mass, sampled.lumped_mass, rtol=1e-11, atol=1e-14 * RHO)
    np.testing.assert_allclose(fitted.span_centroids, sampled.span_centroids, atol=1e-12)

    def sag(body: SplineBody) -> float:
        f = np.zeros((body.count, 3))
        f[:, 1] = -body.lumped_mass * G
        u = _solve(body, 0, tuple(size), f, 1e3)
        tip, w = body.face_points(0, 1.0, [0, 0, 0], size)
        return -float(w @ body.field(tip, u)[:, 1]) / w.sum() / (RHO * G / (E * 0.01)) / CANTILEVER_FEM[0.25]

    assert sag(fitted) / sag(sampled) == pytest.approx(1.0, abs=1e-3)
    exact = box(3)
    assert fitted_body(exact) is exact


def test_the_gershgorin_rows_bound_the_assembled_ones_without_assembling():
    """The dt bound's row sums, span by span: at least the assembled K's and within 2x of them."""
    cells = SplineCells(box(3, origin=[-0.013, 0.02, 0.0]))
    k = abs(cells.body.assemble()).tocsr()
    assembled = np.asarray(k.sum(axis=1)).reshape(-1, 3).max(axis=1)
    rows = cells.frequency_terms(cells.body.rest_positions)
    assert np.all(rows >= assembled * (1 - 1e-12)) and np.all(rows <= 2.0 * assembled)


def box_samples(size, h: float, s: int, origin):
    """The inside test of a fill's sample lattice (``s`` a cell edge, cells from ``origin``) on the
    box [0, size], and the box its inside sample boxes make."""
    size, origin = np.asarray(size, float), np.asarray(origin, float)
    n = (np.ceil((size - origin) / h).astype(int) + 1) * s
    idx = np.indices(n).reshape(3, -1).T
    inside = np.all((origin + (idx + 0.5) / s * h >= 0) & (origin + (idx + 0.5) / s * h <= size), axis=1)
    lo, hi = origin + idx[inside].min(0) / s * h, origin + (idx[inside].max(0) + 1) / s * h
    return inside.reshape(n), lo, hi


@pytest.mark.parametrize("s", [5, 6])
def test_a_fills_samples_make_the_body_of_their_material(s):
    """A body from a fill's samples (the lattice's material: s points a cell edge, odd or even):
    full spans one exact grid, cut spans one grid moment-fitted to the sample boxes' exact moments;
    on a box it is the exact body of the box the samples make, span by span (points and weights),
    at a grid offset that cuts every face."""
    h = 0.05
    origin = np.array([-0.3 * h, -0.3 * h, -0.2 * h])
    inside, lo, hi = box_samples([0.4, 0.1, 0.1], h, s, origin)
    body = sample_body(origin, h, s, inside, youngs_modulus=E, poissons_ratio=0.25, density=RHO)
    exact = SplineBody.from_box(lo, hi, h, youngs_modulus=E, poissons_ratio=0.25, density=RHO, origin=origin)
    assert body.count == exact.count and np.array_equal(body.span_nodes, exact.span_nodes)
    np.testing.assert_allclose(body.point_s, exact.point_s, atol=1e-12)
    np.testing.assert_allclose(body.point_weight, exact.point_weight, rtol=1e-9, atol=1e-12 * h ** 3)
    assert body.volume == pytest.approx(inside.sum() * (h / s) ** 3, rel=1e-12)


def test_a_fills_samples_of_a_ball_keep_its_sampled_volume_and_run_on_the_gpu_form():
    from deformgl.sim.terms.spline.tables import span_tables

    h, s, r = 0.02, 8, 0.05
    origin = np.full(3, -0.07)
    n = np.full(3, 7 * s)
    centres = origin + (np.indices(n).reshape(3, -1).T + 0.5) / s * h
    inside = (np.linalg.norm(centres, axis=1) <= r).reshape(n)
    body = sample_body(origin, h, s, inside, youngs_modulus=1e4, poissons_ratio=0.3, density=1000.0)
    assert body.volume == pytest.approx(inside.sum() * (h / s) ** 3, rel=1e-12)
    assert body.lumped_mass.sum() == pytest.approx(1000.0 * body.volume, rel=1e-12)
    assert np.all(np.bincount(body.point_span) == 27)
    span_tables(body)  # (one grid a span: the GLSL form takes it)
    with pytest.raises(ValueError, match="no sample inside the mesh"):
        sample_body(origin, h, s, np.zeros_like(inside), youngs_modulus=1e4, poissons_ratio=0.3, density=1000.0)


@pytest.mark.parametrize("s", [5, 8])
def test_a_cut_bodys_stiffness_has_no_negative_or_zero_modes_but_the_rigid_ones(s):
    """Moment fitting with a negative weight makes a cut span's stiffness indefinite (modes that
    grow at any dt: the dragon blew up at 0.24 s whatever the step); where the exact fit has one the
    non-negative fit is taken: the ball's generalised spectrum (K, lumped M) has exactly its six
    rigid modes at zero, none below, its volume kept to rounding."""
    h, r = 0.02, 0.05
    origin = np.full(3, -0.07)
    n = np.full(3, 7 * s)
    centres = origin + (np.indices(n).reshape(3, -1).T + 0.5) / s * h
    inside = (np.linalg.norm(centres, axis=1) <= r).reshape(n)
    body = sample_body(origin, h, s, inside, youngs_modulus=1e4, poissons_ratio=0.3, density=1000.0)
    assert body.point_weight.min() >= 0.0
    assert body.volume == pytest.approx(inside.sum() * (h / s) ** 3, rel=1e-12)
    k = SplineCells(body).dt_stiffness(body.rest_positions).toarray()
    scale = 1.0 / np.sqrt(np.repeat(body.lumped_mass, 3))
    omega2 = np.linalg.eigvalsh(scale[:, None] * k * scale[None, :])
    assert np.sum(omega2 < 1e-6 * omega2[-1]) == 6 and omega2[0] > -1e-9 * omega2[-1]
