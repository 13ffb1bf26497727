"""The fill's surface samples measured against the mesh along lines (deformgl.grid.line_fill) and
the spline body built on them (issue 44, item 2: the material integrated accurately)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from deformgl.grid.fill import fill_cells
from deformgl.grid.line_fill import surface_samples
from deformgl.sim.terms.spline.cut import sample_body, span_samples


def _measured(mesh: trimesh.Trimesh, nodes: int):
    vox, fill = fill_cells(mesh, nodes_along_longest=nodes)
    h, s = vox.spacing, fill.samples
    triangles = (np.asarray(mesh.triangles, np.float64) - vox.origin) / h * s - 0.5
    return vox, fill, surface_samples(triangles, fill.inside, s / 2.0)


def _volume(fill, surface, h: float) -> float:
    _, _, widths, _ = span_samples(fill.samples, fill.inside, surface)
    return float(np.prod(widths, axis=1).sum() * h ** 3)


def _finned_bar() -> trimesh.Trimesh:
    """A 100 x 30 x 30 mm bar and a 2 mm fin 45 mm tall on it, one watertight solid (the union
    of the finned bar's shells, built here as one mesh), off the sample lattice at any grid."""
    vertices = []
    faces = []

    def quad(a, b, c, d):
        n = len(vertices)
        vertices.extend([a, b, c, d])
        faces.extend([(n, n + 1, n + 2), (n, n + 2, n + 3)])

    x0, x1, y0, y1, z0, z1 = -0.05, 0.05, -0.015, 0.015, -0.015, 0.015
    f0, f1, top = 0.00212, 0.00412, 0.06
    quad((x0, y0, z0), (x0, y1, z0), (x1, y1, z0), (x1, y0, z0))          # bottom (-z)
    quad((x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1))          # -y
    quad((x0, y1, z0), (x0, y1, z1), (x1, y1, z1), (x1, y1, z0))          # +y
    quad((x0, y0, z1), (x1, y0, z1), (x1, f0, z1), (x0, f0, z1))          # top, -y of the fin
    quad((x0, f1, z1), (x1, f1, z1), (x1, y1, z1), (x0, y1, z1))          # top, +y of the fin
    quad((x0, f0, z1), (x1, f0, z1), (x1, f0, top), (x0, f0, top))        # fin -y
    quad((x0, f1, z1), (x0, f1, top), (x1, f1, top), (x1, f1, z1))        # fin +y
    quad((x0, f0, top), (x1, f0, top), (x1, f1, top), (x0, f1, top))      # fin top
    for x, sign in ((x0, -1.0), (x1, 1.0)):                               # the two ends: bar and fin
        n = len(vertices)
        vertices.extend([(x, y0, z0), (x, y1, z0), (x, y1, z1), (x, f1, z1), (x, f0, z1), (x, y0, z1), (x, f1, top),
                         (x, f0, top)])
        ends = [(n, n + 1, n + 2), (n, n + 2, n + 3), (n, n + 3, n + 4), (n, n + 4, n + 5),  # the bar's, +x
                (n + 4, n + 3, n + 6), (n + 4, n + 6, n + 7)]                              # the fin's, +x
        faces.extend(ends if sign > 0 else [(a, c, b) for a, b, c in ends])
    mesh = trimesh.Trimesh(np.array(vertices), np.array(faces), process=True)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def test_the_finned_bar_union_is_one_watertight_solid():
    mesh = _finned_bar()
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(0.1 * 0.03 * 0.03 + 0.1 * 0.002 * 0.045, rel=1e-12)


@pytest.mark.parametrize("nodes", [12, pytest.param(16, marks=pytest.mark.slow), 24,
                                   pytest.param(32, marks=pytest.mark.slow), 48])
def test_the_fin_carries_its_volume_within_3_percent_and_the_bar_its_mass_within_half_a_percent(nodes):
    """Issue 44, item 2: the 2 mm fin's volume within 3 % at every resolution from 12 to 48 along
    (the inside test alone: -11 % to +8 %), the body's within 0.5 % of the mesh's."""
    mesh = _finned_bar()
    vox, fill, surface = _measured(mesh, nodes)
    h = vox.spacing
    centre, s, widths, _ = span_samples(fill.samples, fill.inside, surface)
    volume = np.prod(widths, axis=1) * h ** 3
    lo = vox.origin[2] + (centre[:, 2] + s[:, 2] - widths[:, 2] / 2.0) * h
    above = np.clip((lo + widths[:, 2] * h - 0.015) / (widths[:, 2] * h), 0.0, 1.0)  # the share above the bar
    fin = float((above * volume).sum())
    assert fin == pytest.approx(0.1 * 0.002 * 0.045, rel=0.03)
    assert float(volume.sum()) == pytest.approx(mesh.volume, rel=0.005)


@pytest.mark.parametrize("nodes", [8, 9, 10, 13])
def test_a_box_off_the_lattice_is_measured_closer_than_the_inside_test(nodes):
    """A box whose faces fall between sample centres, on no node plane, the material beyond the
    outermost node planes (up to h/4 there) included: every face is normal to an axis, so a box
    on one face is measured exactly; a box on an edge (two faces) is measured along one axis with
    its bundle of 3 x 3 lines across the other (measured: -7.5e-4, 2.0e-5, 8.6e-5, 1.4e-5 at 8, 9,
    10, 13 along; the inside test alone 7.1e-3, -4.6e-4, 5.5e-3, -4.6e-4)."""
    mesh = trimesh.creation.box(extents=(0.1, 0.0313, 0.0437))
    mesh.apply_translation((0.0012, -0.0007, 0.0031))
    vox, fill, surface = _measured(mesh, nodes)
    h = vox.spacing
    measured = abs(_volume(fill, surface, h) / mesh.volume - 1.0)
    assert measured < 1e-3
    assert abs(_volume(fill, None, h) / mesh.volume - 1.0) > 5.0 * measured


def test_the_normals_orientation_does_not_matter():
    """The solid is where the crossings' winding number is not zero: an inverted sphere is measured
    as the sphere (the inside test, a parity vote, does not see the orientation either)."""
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=0.05)
    inverted = mesh.copy()
    inverted.invert()
    _, _, surface = _measured(mesh, 8)
    _, _, flipped = _measured(inverted, 8)
    assert len(surface.index) and np.array_equal(surface.index, flipped.index)
    assert np.allclose(surface.fraction, flipped.fraction, atol=1e-12)
    assert np.any((surface.fraction > 0.01) & (surface.fraction < 0.99))


def test_a_rotated_box_is_measured_to_within_a_few_parts_in_ten_thousand():
    """An oblique box: the lines are exact along one axis and a 3 x 3 bundle across it, and its
    corners' sliver spans keep the inside test (measured: -3.3e-4 and -1.9e-4 at 8 and 13 along;
    the inside test alone is closer here, 1.7e-5 and 1.1e-5, its sample-wide errors cancelling on
    the oblique faces: it is the thin features, above, where it is not)."""
    from trimesh.transformations import rotation_matrix

    mesh = trimesh.creation.box(extents=(0.1, 0.0313, 0.0437))
    mesh.apply_transform(rotation_matrix(0.3, [1.0, 2.0, 3.0]))
    for nodes in (8, 13):
        vox, fill, surface = _measured(mesh, nodes)
        assert abs(_volume(fill, surface, vox.spacing) / mesh.volume - 1.0) < 5e-4


@pytest.mark.parametrize("nodes", [8, pytest.param(13, marks=pytest.mark.slow)])
def test_a_sphere_is_measured_closer_than_the_inside_test(nodes):
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=0.05)
    vox, fill, surface = _measured(mesh, nodes)
    measured = abs(_volume(fill, surface, vox.spacing) / mesh.volume - 1.0)
    assert measured < 2e-3  # (1.4e-5 and 3.9e-5 at 8 and 13; the inside test 2.7e-4 and 8.2e-5)
    assert measured < abs(_volume(fill, None, vox.spacing) / mesh.volume - 1.0)


def test_a_leaky_mesh_keeps_the_inside_test_where_the_lines_disagree():
    """A box with two triangles missing (a hole in two faces): the vote fills it (the voxeliser's
    leaky meshes); the crossings of the lines through the holes do not agree with it, so those
    boxes keep the vote, nothing is NaN, negative or beyond a box plus its reach, and the volume
    is no further off than the vote's (measured: -2.9 %, the vote's -3.7 %)."""
    mesh = trimesh.creation.box(extents=(0.1, 0.04, 0.04))
    mesh.update_faces(np.arange(len(mesh.faces)) > 1)
    vox, fill, surface = _measured(mesh, 12)
    assert np.all(np.isfinite(surface.fraction)) and np.all(surface.fraction >= 0.0)
    assert np.all(surface.fraction <= 1.0 + fill.samples / 2.0)
    exact = 0.1 * 0.04 * 0.04
    assert abs(_volume(fill, surface, vox.spacing) - exact) <= abs(_volume(fill, None, vox.spacing) - exact)


@pytest.mark.slow
def test_measured_boxes_split_on_knot_planes_keep_their_volume_and_the_body_its_mass():
    """Odd samples per cell: a box on a knot plane is split there; the spline body's mass is
    rho times the measured volume (moment fitting keeps it)."""
    mesh = trimesh.creation.box(extents=(0.1, 0.0313, 0.0437))
    mesh.apply_translation((0.0012, -0.0007, 0.0031))
    vox, fill, surface = _measured(mesh, 24)
    assert fill.samples % 2 == 1
    centre, s, widths, _ = span_samples(fill.samples, fill.inside, surface)
    assert np.all(np.abs(s) <= 0.5 + 1e-9)
    assert np.all(np.abs(s) + widths / 2.0 <= 0.5 + 1e-9)  # every box within its span
    body = sample_body(vox.origin, vox.spacing, fill.samples, fill.inside, youngs_modulus=1e5, poissons_ratio=0.3,
                       density=1000.0, surface=surface)
    boxes = float(np.prod(widths, axis=1).sum()) * vox.spacing ** 3
    assert float(body.lumped_mass.sum()) == pytest.approx(1000.0 * boxes, rel=1e-9)
    assert boxes == pytest.approx(mesh.volume, rel=1e-4)  # (measured: 1.2e-5 off)
