"""The lattice on a real mesh against the FEM of the mesh (studies.mesh_accuracy): the
measurement of issue 28, today's figures (docs/ACCURACY.md, section 9)."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.fem


def test_the_meshes_are_made_watertight() -> None:
    from studies.mesh_accuracy import MESHES, repaired_mesh

    for name in MESHES:
        mesh = repaired_mesh(name)
        assert mesh.is_watertight and mesh.volume > 0, name
    # the stored references belong to this repair: another pymeshfix that repaired differently
    # would show here, not as a change of the lattice
    dragon = repaired_mesh("dragon")
    assert len(dragon.vertices) == 4875 and dragon.volume == pytest.approx(468.26e-6, rel=1e-4)


def test_the_lattice_on_the_dragon_is_todays_lattice() -> None:
    """The lattice side at 12 and 16 nodes along against the stored FEM reference: the figures of
    docs/ACCURACY.md section 9 (a change of the lattice on meshes moves them: update both)."""
    from studies.mesh_accuracy import FEM_REFERENCE, LATTICE_FIGURES, lattice_sag, repaired_mesh

    mesh = repaired_mesh("dragon")
    mean, largest, top = FEM_REFERENCE["dragon"]
    for n in (12, 16):
        r = lattice_sag(mesh, n)
        measured = (r.mean / mean, r.largest / largest, r.top / top, r.mass_ratio)
        assert measured == pytest.approx(LATTICE_FIGURES["dragon"][n], abs=2e-3), n
        # issue 28's mass target, met: the cells carry the mesh's own volume
        assert r.mass_ratio == pytest.approx(1.0, abs=0.02)


def test_the_finned_bar_is_held_and_weighed_at_16_along() -> None:
    """The finned bar (its fin thinner than a cell): the region that caught no node before holds
    its base, and the lattice weighs the union of its two shells within 2 %; its sag is today's
    figure of docs/ACCURACY.md section 9 (the fin (h/t)^2 too stiff)."""
    from studies.mesh_accuracy import FEM_REFERENCE, LATTICE_FIGURES, lattice_sag, repaired_mesh

    mesh = repaired_mesh("finned_bar")
    assert mesh.is_watertight and mesh.body_count == 1 and mesh.volume == pytest.approx(99.0e-6, rel=1e-3)
    r = lattice_sag(mesh, 16)
    mean, largest, _ = FEM_REFERENCE["finned_bar"]
    assert r.mass_ratio == pytest.approx(1.0, abs=0.02)
    figures = LATTICE_FIGURES["finned_bar"][16]
    assert (r.mean / mean, r.largest / largest) == pytest.approx(figures[:2], abs=2e-3)


@pytest.mark.slow
def test_the_mesh_fem_against_a_column_under_its_weight() -> None:
    """fem_sag on a slender box column (1 x 10 x 1 cm, its surface in triangles of 4 mm at most,
    13.7k tetrahedra, 20 s) held at its lowest 5 %: its top sinks by the 1D column's
    rho g L^2 / (2 E) over the free length L, within 0.2 % (measured +0.002 %)."""
    import trimesh

    from studies.mesh_accuracy import DENSITY, G, HOLD, YOUNGS_MODULUS, fem_sag

    box = trimesh.creation.box(extents=(0.01, 0.1, 0.01))
    column = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(box.vertices, box.faces, max_edge=0.004))
    free = 0.1 * (1.0 - HOLD)
    assert fem_sag(column).top == pytest.approx(DENSITY * G * free ** 2 / (2.0 * YOUNGS_MODULUS), rel=2e-3)
