"""Spring systems from grids, cloths and triangle meshes; forces and the frequency bound."""

import numpy as np
import pytest
import trimesh

from deformgl.grid.nodes import NodeGrid
from deformgl.sim.springs import (FLEXION, SHEAR, STRUCTURAL, SpringSystem, cloth, forces, from_grid, from_triangle_mesh,
                                  max_angular_frequency)
from deformgl.sim.scripted import Drag

H = 0.05


def grid_of(occ, origin=(0.1, -0.2, 0.3)):
    return NodeGrid(np.array(origin, float), H, np.asarray(occ, bool))


def pair_set(system, cls=None):
    keep = np.ones(system.spring_count, bool) if cls is None else system.spring_class == cls
    pairs = zip(system.i[keep].tolist(), system.j[keep].tolist())
    return {(min(a, b), max(a, b)) for a, b in pairs}


def expected_grid_pairs(grid):
    """Brute force over all node pairs: the springs from_grid must build, by class."""
    ijk = grid.ijk
    diff = ijk[None, :, :] - ijk[:, None, :]
    a, b = np.nonzero(np.triu(np.ones((grid.count, grid.count), bool), 1))
    dd = diff[a, b]
    sq = (dd ** 2).sum(axis=1)
    absd = np.abs(dd)
    structural = sq == 1
    shear = (sq == 2) & (absd.max(axis=1) == 1)
    axial2 = (sq == 4) & (absd.max(axis=1) == 2)
    mid = (ijk[a] + ijk[b]) // 2
    mid_exists = grid.occupied[mid[:, 0], mid[:, 1], mid[:, 2]]
    flex = axial2 & mid_exists
    as_set = lambda m: set(zip(a[m].tolist(), b[m].tolist()))
    return as_set(structural), as_set(shear), as_set(flex), as_set(axial2 & ~mid_exists)


def test_full_3x3x3_grid_counts_and_rest_lengths():
    s = from_grid(grid_of(np.ones((3, 3, 3))), k_structural=10.0, k_shear=5.0, k_flexion=2.0)
    # structural 3 axes * 2*3*3, shear 3 planes * 2 diagonals * 2*2*3, flexion 3 axes * 1*3*3
    assert s.class_counts() == {"structural": 54, "shear": 72, "flexion": 27}
    assert s.spring_count == 153 == len(pair_set(s))
    for cls, units, k in ((STRUCTURAL, 1.0, 10.0), (SHEAR, np.sqrt(2.0), 5.0), (FLEXION, 2.0, 2.0)):
        m = s.spring_class == cls
        np.testing.assert_allclose(s.rest_length[m], H * units, rtol=1e-12)
        assert np.all(s.stiffness[m] == k)
    assert np.all(np.diff(s.spring_class) >= 0), "structural first, then shear, then flexion"


def test_grid_with_holes_matches_brute_force_and_flexion_never_bridges_a_hole():
    rng = np.random.default_rng(3)
    occ = rng.random((5, 4, 4)) < 0.7
    grid = grid_of(occ)
    s = from_grid(grid, k_structural=1.0, k_shear=2.0, k_flexion=3.0,
                  damping_structural=0.1, damping_shear=0.2, damping_flexion=0.3)
    structural, shear, flex, bridging = expected_grid_pairs(grid)
    assert bridging, "the random grid should contain a hole between two nodes 2 apart"
    assert pair_set(s, STRUCTURAL) == structural
    assert pair_set(s, SHEAR) == shear
    assert pair_set(s, FLEXION) == flex
    assert len(pair_set(s)) == s.spring_count, "each spring once"
    np.testing.assert_array_equal(s.damping, np.array([0.1, 0.2, 0.3])[s.spring_class])


def test_cloth_counts_positions_and_a_zero_stiffness_class_is_not_built():
    nx, nz = 5, 4
    c = cloth(nx, nz, H, k_structural=10.0, k_shear=4.0, k_flexion=1.0, origin=(0.0, 1.0, 0.0))
    assert c.class_counts() == {
        "structural": (nx - 1) * nz + nx * (nz - 1),
        "shear": 2 * (nx - 1) * (nz - 1),
        "flexion": (nx - 2) * nz + nx * (nz - 2)}
    assert np.all(c.rest_positions[:, 1] == 1.0), "a cloth lies in the xz-plane"
    np.testing.assert_allclose(c.rest_positions[1 * nz + 2], [H, 1.0, 2 * H])
    assert c.spacing == H

    no_shear = cloth(nx, nz, H, k_structural=10.0, k_shear=0.0)
    assert no_shear.class_counts() == {"structural": 31, "shear": 0, "flexion": 0}
    assert np.all(no_shear.stiffness > 0)


def test_triangle_mesh_edges_unique():
    mesh = trimesh.creation.icosphere(subdivisions=1)
    s = from_triangle_mesh(mesh.vertices, mesh.faces, stiffness=20.0, damping=0.1, mass=0.02)
    pairs = pair_set(s)
    assert s.spring_count == len(pairs) == len(mesh.edges_unique)
    assert pairs == {tuple(e) for e in np.sort(mesh.edges_unique, axis=1).tolist()}
    assert s.count - s.spring_count + len(mesh.faces) == 2, "Euler characteristic of a sphere"
    length_of = {tuple(e): length for e, length in
                 zip(np.sort(mesh.edges_unique, axis=1).tolist(), mesh.edges_unique_length)}
    expected = [length_of[(min(a, b), max(a, b))] for a, b in zip(s.i.tolist(), s.j.tolist())]
    np.testing.assert_allclose(s.rest_length, expected, rtol=1e-12)
    np.testing.assert_allclose(s.spacing, mesh.edges_unique_length.mean())
    assert np.all(s.spring_class == STRUCTURAL)


def test_triangle_mesh_drops_self_edges_and_rejects_bad_faces():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    s = from_triangle_mesh(v, [[0, 1, 2], [2, 1, 0], [0, 3, 3]], stiffness=1.0)
    assert pair_set(s) == {(0, 1), (1, 2), (0, 2), (0, 3)}
    with pytest.raises(ValueError, match="outside"):
        from_triangle_mesh(v, [[0, 1, 4]], stiffness=1.0)
    with pytest.raises(ValueError, match="shape"):
        from_triangle_mesh(v, [[0, 1]], stiffness=1.0)


def two_nodes(x1, *, k=30.0, c_s=0.4, c=0.05, m=(0.2, 0.5), gravity=(0.0, -9.81, 0.0),
              wind=(0.0, 0.0, 0.0), wind_drag=0.0, rest=0.1):
    return SpringSystem(rest_positions=np.array([[0.0, 0.0, 0.0], x1]), mass=np.array(m),
                        fixed=np.zeros(2, bool), i=np.array([0]), j=np.array([1]),
                        rest_length=np.array([rest]), stiffness=np.array([k]),
                        damping=np.array([c_s]), spring_class=np.array([STRUCTURAL]),
                        velocity_damping=c, gravity=np.array(gravity), wind=np.array(wind),
                        wind_drag=wind_drag)


def test_forces_on_a_stretched_spring_match_the_formula_term_by_term():
    x = np.array([[0.01, 0.02, -0.03], [0.09, 0.07, 0.05]])
    v = np.array([[0.3, -0.1, 0.2], [-0.2, 0.4, 0.1]])
    s = two_nodes(x[1], wind=(2.0, 0.0, -1.0), wind_drag=0.07)
    d = x[0] - x[1]
    length = np.sqrt(d @ d)
    u = d / length
    elastic = 30.0 * (0.1 - length) * u                       # docs/EQUATIONS.md F_j
    spring_damp = -0.4 * ((v[0] - v[1]) @ u) * u
    per_node = (s.mass[:, None] * [0.0, -9.81, 0.0] + 0.07 * (np.array([2.0, 0.0, -1.0]) - v)
                - 0.05 * v)
    expected = per_node + np.array([1.0, -1.0])[:, None] * (elastic + spring_damp)
    np.testing.assert_allclose(forces(s, x, v, 0.0), expected, rtol=1e-13, atol=1e-15)
    assert length > 0.1 and elastic @ d < 0, "a stretched spring pulls node i toward j"


def test_drag_force_follows_its_target_in_time():
    s = two_nodes([0.1, 0.0, 0.0], c_s=0.0, c=0.0, gravity=(0.0, 0.0, 0.0))
    x = s.rest_positions.copy()
    drag = Drag(node=1, target=lambda t: [0.1 + t, 0.0, 0.0], stiffness=50.0)
    f = forces(s, x, np.zeros((2, 3)), 0.25, (drag,))
    np.testing.assert_allclose(f, [[0.0, 0.0, 0.0], [50.0 * 0.25, 0.0, 0.0]], atol=1e-12)


def test_zero_length_spring_gives_finite_forces():
    s = two_nodes([0.0, 0.0, 0.0], gravity=(0.0, 0.0, 0.0), c=0.0)
    f = forces(s, s.rest_positions.copy(), np.array([[1.0, 0, 0], [0, 0, 0]]), 0.0)
    assert np.all(np.isfinite(f))
    np.testing.assert_array_equal(f, 0.0)


def test_rest_state_has_exactly_zero_force():
    s = from_grid(grid_of(np.ones((3, 3, 2))), k_structural=40.0, k_shear=10.0, k_flexion=3.0,
                  damping_structural=0.5, velocity_damping=0.1, gravity=(0.0, 0.0, 0.0))
    np.testing.assert_array_equal(forces(s, s.rest_positions, np.zeros((s.count, 3)), 0.0), 0.0)


def stiffness_matrix(system):
    """-dF/dx at rest by central differences (gravity and damping off in the callers)."""
    x0 = system.rest_positions
    v = np.zeros_like(x0)
    eps = 1e-7
    cols = []
    for n in range(x0.size):
        dx = np.zeros(x0.size)
        dx[n] = eps
        dx = dx.reshape(x0.shape)
        cols.append(-(forces(system, x0 + dx, v, 0.0) - forces(system, x0 - dx, v, 0.0)).ravel()
                    / (2 * eps))
    return np.array(cols).T


def highest_frequency(system):
    free = np.repeat(~system.fixed, 3)
    k = stiffness_matrix(system)[np.ix_(free, free)]
    w = 1.0 / np.sqrt(np.repeat(system.mass, 3)[free])
    return float(np.sqrt(np.linalg.eigvalsh(w[:, None] * k * w[None, :]).max()))


def test_max_angular_frequency_bounds_the_linearised_spectrum():
    rng = np.random.default_rng(5)
    grid = grid_of(np.ones((3, 3, 3)))
    mass = rng.uniform(0.01, 0.05, grid.count)
    fixed = grid.ijk[:, 1] == 2
    s = from_grid(grid, k_structural=50.0, k_shear=20.0, k_flexion=5.0, mass=mass, fixed=fixed,
                  gravity=(0.0, 0.0, 0.0))
    bound = max_angular_frequency(s)
    true_w = highest_frequency(s)
    assert true_w <= bound.omega
    # Gershgorin-type bounds are loose by up to about 2 with unequal masses (here 0.47)
    assert true_w > bound.omega / 3, "a useful bound, not a vacuous one"
    ksum = np.array([s.stiffness[(s.i == n) | (s.j == n)].sum() for n in range(s.count)])
    ratio = np.where(fixed, -1.0, 2 * ksum / mass)
    assert bound.node == int(np.argmax(ratio)) and not fixed[bound.node]
    np.testing.assert_allclose(bound.omega, np.sqrt(ratio.max()), rtol=1e-12)
    at_node = (s.i == bound.node) | (s.j == bound.node)
    assert at_node[bound.spring] and s.stiffness[bound.spring] == s.stiffness[at_node].max()


def test_max_angular_frequency_is_tight_for_two_equal_free_masses():
    s = two_nodes([0.1, 0.0, 0.0], k=30.0, m=(0.2, 0.2), c_s=0.0, c=0.0, gravity=(0, 0, 0))
    bound = max_angular_frequency(s)
    np.testing.assert_allclose(bound.omega, np.sqrt(2 * 30.0 / 0.2), rtol=1e-12)
    np.testing.assert_allclose(highest_frequency(s), bound.omega, rtol=1e-6)
    assert bound.spring == 0


def test_spring_system_validates_and_is_read_only():
    s = two_nodes([0.1, 0.0, 0.0])
    with pytest.raises(ValueError):
        s.mass[0] = 1.0
    with pytest.raises(ValueError, match="positive mass"):
        two_nodes([0.1, 0.0, 0.0], m=(0.0, 1.0))
    with pytest.raises(ValueError, match="itself"):
        SpringSystem(rest_positions=np.zeros((2, 3)), mass=np.ones(2), fixed=np.zeros(2, bool),
                     i=np.array([1]), j=np.array([1]), rest_length=np.ones(1),
                     stiffness=np.ones(1), damping=np.zeros(1), spring_class=np.zeros(1))
