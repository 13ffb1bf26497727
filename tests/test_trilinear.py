"""Trilinear transformations in float64 NumPy (Knuth, Kohlhammer & Kuijper, eq. 1-4, 3.3, 4.1, 4.2)."""

import numpy as np
import pytest

from deformgl.errors import InputError
from deformgl.trilinear.transforms import (
    CORNERS, Bend, Box, Helix, Taper, TorusWrap, Trilinear, Twist, apply_coefficients, coefficient_matrix,
    compose, corner_weight_gradients, corner_weights, finite_difference_jacobian, is_linear_coefficients,
    parameter_vector, tangent_affine, transform_normals, trilinear_corners,
)

RNG = np.random.default_rng(20240601)
BOX = Box(np.array([-1.0, -1.0, 0.0]), np.array([1.0, 1.0, 2.0]))


def random_affine(rng, scale=1.0):
    m = np.identity(4)
    m[:3, :3] = rng.normal(size=(3, 3)) * scale
    m[:3, 3] = rng.normal(size=3) * 3
    return m


def bent_corners(rng):
    return CORNERS * rng.uniform(0.5, 2.0, 3) + rng.normal(scale=0.3, size=(8, 3))


# ---- Knuth, Kohlhammer & Kuijper, eq. 1-4 -------------------------------------------------------------------------------------
def test_corner_order_matches_eq1_weights():
    # corner i sits at (i & 1, i >> 1 & 1, i >> 2 & 1): its weight is 1 there and 0 at the others
    assert np.array_equal(corner_weights(CORNERS), np.identity(8))
    u = np.array([[0.2, 0.3, 0.7]])
    x, y, z = u[0]
    expected = [(1 - x) * (1 - y) * (1 - z), x * (1 - y) * (1 - z), (1 - x) * y * (1 - z), x * y * (1 - z),
                (1 - x) * (1 - y) * z, x * (1 - y) * z, (1 - x) * y * z, x * y * z]
    assert np.allclose(corner_weights(u)[0], expected, rtol=0, atol=1e-15)
    assert np.allclose(parameter_vector(u)[0], [x * y * z, y * z, x * z, x * y, z, y, x, 1], rtol=0, atol=1e-15)


def test_eq1_equals_eq4_on_random_cuboids_and_points():
    for _ in range(20):
        corners = RNG.normal(size=(8, 3)) * RNG.uniform(0.1, 10)
        u = RNG.uniform(-0.5, 1.5, (500, 3))  # also outside the unit cube: both are the same polynomial
        eq1 = trilinear_corners(corners, u)
        eq4 = apply_coefficients(coefficient_matrix(corners), u)
        assert np.allclose(eq1, eq4, rtol=0, atol=1e-12 * np.abs(corners).max())


def test_coefficient_matrix_rows_are_eq2():
    p = RNG.normal(size=(8, 3))
    c = coefficient_matrix(p)
    assert c.shape == (3, 8)
    assert np.allclose(c[:, 0], p[7] - p[6] - p[5] + p[4] - p[3] + p[2] + p[1] - p[0])
    assert np.allclose(c[:, 1], p[6] - p[4] - p[2] + p[0])
    assert np.allclose(c[:, 2], p[5] - p[4] - p[1] + p[0])
    assert np.allclose(c[:, 3], p[3] - p[2] - p[1] + p[0])
    assert np.allclose(c[:, 4:], np.stack([p[4] - p[0], p[2] - p[0], p[1] - p[0], p[0]], 1))


def test_affine_cuboid_reproduces_its_matrix_exactly():
    for _ in range(10):
        m = random_affine(RNG)
        t = Trilinear.from_affine(m, BOX)
        p = BOX.from_unit(RNG.uniform(-0.2, 1.2, (300, 3)))
        assert np.allclose(t(p), p @ m[:3, :3].T + m[:3, 3], rtol=0, atol=1e-12)
        assert np.allclose(t.affine_matrix(), m, rtol=0, atol=1e-12)
        assert np.allclose(t.jacobian(p), np.broadcast_to(m[:3, :3], (300, 3, 3)), atol=1e-12)


def test_from_affine_rejects_projective_or_bad_matrices():
    m = np.identity(4)
    m[3, 0] = 0.5
    with pytest.raises(InputError, match="projective"):
        Trilinear.from_affine(m, BOX)
    with pytest.raises(InputError, match="4x4"):
        Trilinear.from_affine(np.identity(3), BOX)
    with pytest.raises(InputError, match="lo < hi"):
        Box(np.zeros(3), np.array([1.0, 0.0, 1.0]))


# ---- the linearity test (3.2) -------------------------------------------------------------------
def test_linearity_test_is_true_for_every_affine_input():
    for scale in (1e-6, 1.0, 1e6):
        for _ in range(10):
            m = random_affine(RNG, scale)
            lo = RNG.normal(size=3) * scale
            box = Box(lo, lo + RNG.uniform(0.1, 3.0, 3) * scale)
            t = Trilinear.from_affine(m, box)
            assert t.is_linear()
            assert bool(is_linear_coefficients(coefficient_matrix(t.corners)))
            assert Trilinear.from_affine(m, box, cells=(3, 2, 4)).is_linear()
    # a collapsed cuboid (all corners equal) is linear too
    assert Trilinear.from_corners(BOX, np.ones((8, 3))).is_linear()


def test_linearity_test_is_false_for_bent_ones():
    for _ in range(10):
        assert not Trilinear.from_corners(BOX, bent_corners(RNG)).is_linear()
    # one corner moved by 1e-6 of the size is detected; the tolerance is relative
    corners = BOX.corners().copy()
    corners[7] += 1e-6 * np.linalg.norm(BOX.size)
    assert not Trilinear.from_corners(BOX, corners).is_linear()
    assert Trilinear.from_corners(BOX, corners).is_linear(rtol=1e-5)
    # a grid whose outer corners form a parallelepiped but whose inside bends is not linear
    grid = Trilinear.from_function(Bend(5.0), BOX, (4, 1, 1)).points.copy()
    grid[:, :, :, :] = Trilinear.from_affine(np.identity(4), BOX, (4, 1, 1)).points
    grid[2, 0, 0, 2] += 0.1
    assert not Trilinear(BOX, grid).is_linear()
    assert not Trilinear.from_function(Twist(0.5), BOX, (2, 2, 2)).is_linear()


# ---- grids (3.3) ---------------------------------------------------------------------------------
def test_grid_interpolates_its_lattice_and_resamples_exactly():
    g = Trilinear.from_function(Twist(1.0), BOX, (3, 4, 5))
    lattice = BOX.from_unit(np.stack(np.meshgrid(*[np.linspace(0, 1, n + 1) for n in (3, 4, 5)],
                                                 indexing="ij"), -1)).reshape(-1, 3)
    assert np.allclose(g(lattice), Twist(1.0)(lattice), rtol=0, atol=1e-12)
    fine = g.resample((6, 8, 10))
    p = BOX.from_unit(RNG.random((400, 3)))
    assert np.allclose(fine(p), g(p), rtol=0, atol=1e-12)
    coarse = g.resample((1, 1, 1))
    assert not np.allclose(coarse(p), g(p), atol=1e-3)


def test_per_cell_coefficients_and_identity():
    g = Trilinear.from_function(Twist(1.0), BOX, (3, 2, 4))
    c = g.coefficients()
    assert c.shape == (3, 2, 4, 3, 8)
    u = RNG.random((50, 3))
    cell = (1, 0, 2)
    inside = (np.array(cell) + u) / np.array(g.cells)
    assert np.allclose(apply_coefficients(c[cell], u), g.at_unit(inside), rtol=0, atol=1e-12)
    ident = Trilinear.identity(BOX, (2, 3, 1))
    p = BOX.from_unit(RNG.random((50, 3)))
    assert np.allclose(ident(p), p, rtol=0, atol=1e-12) and ident.is_linear()


def test_grid_jacobian_matches_finite_differences_inside_cells():
    g = Trilinear.from_function(Bend(2.0), BOX, (4, 4, 4))
    u = (np.floor(RNG.random((200, 3)) * 4) + RNG.uniform(0.2, 0.8, (200, 3))) / 4
    p = BOX.from_unit(u)
    assert np.allclose(g.jacobian(p), finite_difference_jacobian(g, p, 1e-6), rtol=0, atol=1e-6)
    dw = corner_weight_gradients(u)
    h = 1e-7
    for a in range(3):
        e = np.zeros(3)
        e[a] = h
        assert np.allclose(dw[:, a], (corner_weights(u + e) - corner_weights(u - e)) / (2 * h), atol=1e-7)


def test_grid_from_function_reports_its_error_and_exact_cases():
    twist = Trilinear.from_function(Twist(1.0), BOX, (8, 8, 8))
    p = BOX.from_unit(RNG.random((5000, 3)))
    actual = np.linalg.norm(twist(p) - Twist(1.0)(p), axis=1).max()
    assert 0.5 * twist.error < actual <= twist.error * 1.05
    # x (1 + r z) is trilinear: the grid is exact, and so is an affine function
    assert Trilinear.from_function(Taper(0.4), BOX, (2, 2, 2)).error < 1e-13
    assert Trilinear.from_function(lambda q: q @ np.diag([2.0, 1.0, 0.5]) + 1.0, BOX, (3, 3, 3)).error < 1e-13


@pytest.mark.parametrize("f, box", [
    (Twist(1.2), BOX),
    (Bend(3.0), BOX),
    (TorusWrap(4.0, 2.0, 3.0, 1.0), Box(np.zeros(3), np.array([4.0, 2.0, 0.5]))),
])
def test_grid_error_falls_as_h_squared(f, box):
    # the torus wrap is linear in z (the height above the surface): one cell in z is exact
    # the torus wrap is still pre-asymptotic at 4 cells (90 degrees per cell)
    sizes = (8, 16, 32) if isinstance(f, TorusWrap) else (4, 8, 16)
    errors = [Trilinear.from_function(f, box, (n, n, 1 if isinstance(f, TorusWrap) else n)).error
              for n in sizes]
    ratios = [errors[i] / errors[i + 1] for i in range(2)]
    assert all(3.3 < r < 4.4 for r in ratios), (errors, ratios)


def test_bad_functions_and_shapes_are_input_errors():
    with pytest.raises(InputError, match="expected"):
        Trilinear.from_function(lambda q: q[:, :2], BOX, (2, 2, 2))
    with pytest.raises(InputError, match="non-finite"):
        Trilinear.from_function(lambda q: q * np.nan, BOX, (2, 2, 2))
    with pytest.raises(InputError, match="cell counts"):
        Trilinear.from_function(Twist(1.0), BOX, (0, 2, 2))
    with pytest.raises(InputError, match="shape"):
        Trilinear(BOX, np.zeros((1, 2, 2, 3)))


# ---- composition (4.1) ---------------------------------------------------------------------------
def test_composing_two_affine_transforms_is_the_matrix_product():
    for _ in range(10):
        a, b = random_affine(RNG), random_affine(RNG)
        inner = Trilinear.from_affine(b, BOX)
        outer_box = Box.of_points(inner.points.reshape(-1, 3))
        c = compose(Trilinear.from_affine(a, outer_box), inner)
        assert c.cells == (1, 1, 1)
        assert c.is_linear()
        assert np.allclose(c.affine_matrix(), a @ b, rtol=0, atol=1e-10 * np.abs(a @ b).max())


def test_composing_a_bend_with_a_twist_matches_applying_them_in_order():
    twist = Trilinear.from_function(Twist(1.0), BOX, (8, 8, 8))
    outer = Box(np.array([-1.5, -1.5, -0.5]), np.array([1.5, 1.5, 2.5]))
    bend = Trilinear.from_function(Bend(3.0), outer, (8, 8, 8))
    c = compose(bend, twist, estimate_error=True)
    assert c.box is twist.box and c.cells == (8, 8, 8)
    p = BOX.from_unit(RNG.random((20000, 3)))
    actual = np.linalg.norm(c(p) - Bend(3.0)(Twist(1.0)(p)), axis=1).max()
    assert actual <= c.error  # within the stated approximation error
    assert c.error < 0.02 * np.linalg.norm(BOX.size)
    # in the other order the result is a different deformation: order matters
    assert np.linalg.norm(c(p) - Twist(1.0)(Bend(3.0)(p)), axis=1).max() > 10 * c.error


def test_stated_error_carries_the_childs_error_through_the_parents_stretch():
    twist = Trilinear.from_function(Twist(1.0), BOX, (4, 4, 4))
    scale = np.diag([3.0, 3.0, 3.0, 1.0])
    c = compose(Trilinear.from_affine(scale, Box(np.full(3, -2.0), np.full(3, 3.0))), twist, estimate_error=True)
    p = BOX.from_unit(RNG.random((20000, 3)))
    actual = np.linalg.norm(c(p) - 3.0 * Twist(1.0)(p), axis=1).max()
    assert 2.0 * twist.error < actual <= c.error  # about three times the child's own error


def test_composition_takes_the_higher_resolution():
    fine_parent = Trilinear.from_function(Bend(3.0), Box(np.array([-2, -2, -1.0]), np.array([2, 2, 3.0])),
                                          (16, 16, 16))
    coarse_child = Trilinear.from_affine(np.identity(4), BOX)  # covers half of the parent per axis
    c = compose(fine_parent, coarse_child)
    assert c.cells == (8, 8, 8)  # the parent's cells crossed by the child
    p = BOX.from_unit(RNG.random((3000, 3)))
    assert np.allclose(c(p), fine_parent(p), atol=1e-12)  # aligned lattices: exact
    # a linear parent composes exactly at the child's resolution
    twist = Trilinear.from_function(Twist(1.0), BOX, (3, 3, 3))
    lin = compose(Trilinear.from_affine(random_affine(RNG), Box(np.full(3, -3.0), np.full(3, 3.0))), twist)
    assert lin.cells == (3, 3, 3)


def test_helix_and_tangent_affine():
    h = Helix(radius=2.0, pitch=1.0)
    s = np.linspace(0, 10, 50)
    centre, normal, binormal = h.frame(s)
    step = 1e-6
    tangent = (h.frame(s + step)[0] - h.frame(s - step)[0]) / (2 * step)
    assert np.allclose(np.linalg.norm(tangent, axis=1), 1.0, atol=1e-8)  # x is the arc length
    assert np.allclose(np.cross(tangent, normal), binormal, atol=1e-8)
    m = tangent_affine(h, np.array([3.0, 0.0, 0.0]))
    p = np.array([[3.0, 0.0, 0.0], [3.01, 0.02, -0.01]])
    assert np.allclose(m[:3, :3] @ p[0] + m[:3, 3], h(p[:1])[0], atol=1e-12)
    assert np.allclose(m[:3, :3] @ p[1] + m[:3, 3], h(p[1:])[0], atol=1e-3)


# ---- normals (4.2) --------------------------------------------------------------------------------
def test_normals_both_ways_against_finite_difference_jacobian():
    g = Trilinear.from_function(Twist(1.3), BOX, (3, 3, 3))
    u = (np.floor(RNG.random((300, 3)) * 3) + RNG.uniform(0.2, 0.8, (300, 3))) / 3
    p = BOX.from_unit(u)
    n = RNG.normal(size=(300, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    jfd = finite_difference_jacobian(g, p, 1e-6)
    direct = transform_normals(g.jacobian(p), n, "direct")
    tangent = transform_normals(g.jacobian(p), n, "tangent")
    fd_direct = np.einsum("nij,nj->ni", jfd, n)
    fd_tangent = np.einsum("nji,nj->ni", np.linalg.inv(jfd), n)  # J^-T n
    unit = lambda v: v / np.linalg.norm(v, axis=1, keepdims=True)  # noqa: E731
    assert np.allclose(direct, unit(fd_direct), atol=1e-6)
    assert np.allclose(tangent, unit(fd_tangent), atol=1e-6)
    # tangent-frame normals are orthogonal to every deformed tangent; direct ones are not
    t = unit(np.cross(n, RNG.normal(size=(300, 3))))
    deformed_t = np.einsum("nij,nj->ni", jfd, t)
    assert np.abs((tangent * unit(deformed_t)).sum(1)).max() < 1e-6
    assert np.abs((direct * unit(deformed_t)).sum(1)).max() > 1e-2


def test_direct_normals_are_smooth_across_cells_tangent_normals_have_seams():
    """Figure 5: a flat surface (normal z) crossing an x cell border of a bent grid."""
    g = Trilinear.from_function(Bend(1.5), BOX, (4, 4, 4))
    border_x = BOX.lo[0] + 2 * BOX.size[0] / 4
    y = np.linspace(-0.8, 0.8, 9)
    eps = 1e-7
    left = np.stack([np.full(9, border_x - eps), y, np.full(9, 1.1)], 1)
    right = left + [2 * eps, 0, 0]
    nz = np.tile([0.0, 0.0, 1.0], (9, 1))
    tilted = np.tile([0.6, 0.0, 0.8], (9, 1))
    jump = {m: np.abs(transform_normals(g.jacobian(right), nz, m) - transform_normals(g.jacobian(left), nz, m)).max()
            for m in ("direct", "tangent")}
    assert jump["direct"] < 1e-6 and jump["tangent"] > 1e-3
    # with a normal that has an x component, direct normals jump too (J's x column jumps)
    tj = np.abs(transform_normals(g.jacobian(right), tilted, "direct")
                - transform_normals(g.jacobian(left), tilted, "direct")).max()
    assert tj > 1e-3


def test_tangent_normals_keep_orientation_under_reflection():
    m = np.diag([-1.0, 1.0, 1.0, 1.0])
    t = Trilinear.from_affine(m, BOX)
    n = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    out = transform_normals(t.jacobian(np.zeros((2, 3)) + [0, 0, 1]), n, "tangent")
    assert np.allclose(out, [[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    with pytest.raises(InputError, match="normal mode"):
        transform_normals(t.jacobian(np.zeros((1, 3))), n[:1], "sideways")
